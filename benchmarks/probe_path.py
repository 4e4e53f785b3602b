#!/usr/bin/env python
"""The hardest path below a rung's probe, issue 31 item 2: from the sub-box the ``h_max``
cover reaches first at ``COVER_DEPTH`` halvings (``sampled_cover.probe_box`` of the whole
box, at the worst vertex's corner) of a held-out ``n = 4, m = 3`` loop
(``h_max_diagnosis.the_loop``, conditioned as the refinement runs it) at ``h = HU (1 -
F)``, halve the harder half (the worst vertex's) by a split rule until the map's proof
(``sampled_proof.subbox_stable``) holds: ``rate`` is ``sampled_proof.split_rate``,
``map`` is ``sampled_cover.map_split`` (the cover's rule for map proofs). One line per
sub-box: its depth, widths relative to the box, proved or not; one CSV row per run.

    python benchmarks/probe_path.py SEED HU F {rate,map} [--max 30] [--out FILE.csv]
    python benchmarks/probe_path.py 13 0.6022096970393988 1.083e-2 map
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from csvout import write_rows
from h_max_diagnosis import the_loop

from ftc_verify.analysis.moments.sampled import rate_points
from ftc_verify.analysis.moments.sampled_bracket import worst_vertex
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_cover import map_split, probe_box
from ftc_verify.analysis.moments.sampled_proof import MapParts, split_rate, subbox_stable
from ftc_verify.analysis.rigorous import precision


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("seed", type=int)
    parser.add_argument("hu", type=float)
    parser.add_argument("f", type=float)
    parser.add_argument("rule", choices=("rate", "map"))
    parser.add_argument("--max", type=int, default=30)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    loop = conditioned(the_loop(4, 3, args.seed))
    chain = loop.chain
    h = args.hu * (1 - args.f)
    with precision(64):
        parts = MapParts.build(loop, h)
    worst = worst_vertex(loop, args.hu, rate_points(chain))[1]
    full = chain.rate_max - chain.rate_min
    free = [r for r in chain.rate_indices if full[r] > 0]
    box = (np.array(chain.rate_min, dtype=float), np.array(chain.rate_max, dtype=float), 0)
    lo, hi, top = probe_box(loop, h, box, worst)
    rule = split_rate if args.rule == "rate" else map_split
    t0 = time.process_time()
    proved = False
    depth = top
    for depth in range(top, top + args.max):
        proved = subbox_stable(loop, h, parts, lo, hi)
        widths = " ".join(f"{float((hi[r] - lo[r]) / full[r]):.4g}" for r in free)
        print(f"depth {depth}: widths {widths}: {'proved' if proved else 'not proved'}", flush=True)
        if proved:
            break
        r = rule(loop, h, lo, hi)
        mid = 0.5 * (lo[r] + hi[r])
        lo, hi = lo.copy(), hi.copy()
        if abs(worst[r] - lo[r]) <= abs(worst[r] - hi[r]):
            hi[r] = mid
        else:
            lo[r] = mid
    row = {"seed": args.seed, "hu": args.hu, "f": args.f, "rule": args.rule, "proved": proved, "depth": depth,
           "cpu_s": round(time.process_time() - t0, 1)}
    print(" ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    if args.out:
        write_rows(args.out, [row])


if __name__ == "__main__":
    main()
