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

import time


from csvout import write_rows
from h_max_diagnosis import harder_half, held_out_rung, rung_parser

from ftc_verify.analysis.moments.sampled_cover import map_split, probe_box
from ftc_verify.analysis.moments.sampled_proof import split_rate, subbox_stable


def main() -> None:
    parser = rung_parser(__doc__)
    parser.add_argument("rule", choices=("rate", "map"))
    parser.add_argument("--max", type=int, default=30)
    args = parser.parse_args()
    rung = held_out_rung(args.seed, args.hu, args.f)
    loop, h, parts, worst = rung.loop, rung.h, rung.parts, rung.worst
    chain = loop.chain
    full = chain.rate_max - chain.rate_min
    free = [r for r in chain.rate_indices if full[r] > 0]
    lo, hi, top = probe_box(loop, h, rung.box, worst)
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
        lo, hi = harder_half(lo, hi, rule(loop, h, lo, hi), worst)
    row = {"seed": args.seed, "hu": args.hu, "f": args.f, "rule": args.rule, "proved": proved, "depth": depth,
           "cpu_s": round(time.process_time() - t0, 1)}
    print(" ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    if args.out:
        write_rows(args.out, [row])


if __name__ == "__main__":
    main()
