#!/usr/bin/env python
"""A cover of the rate box by sub-box proofs of the one-period map alone (no clock
certificates), issue 31 item 2: how many sub-boxes the map proofs need at ``h = a (1 -
F)`` below the worst vertex's float64 crossing ``a`` of a held-out ``n = 4, m = 3`` loop
(``h_max_diagnosis.the_loop``).

Depth first from the whole box; a sub-box is proved by
``sampled_proof.subbox_stable`` (the envelope, then the second-order form with the
eigenpair enclosure and the cone certificates) or halved along
``sampled_proof.split_rate``; it stops at ``CAP`` proofs tried or when a sub-box's
midpoint has a float64 radius >= 1. ``--eigen-only``: the cone certificates of
``sampled_second`` and ``sampled_taylor`` left out (what the enclosure alone covers,
and faster); ``--no-eigen``: the enclosure left out (the proofs before round 14).
``--hu HU``: as the ``h_max`` refinement runs it instead, on the conditioned loop
(``sampled_conditioned.conditioned``) at ``h = HU (1 - F)``, ``HU`` the default
bracket's proved-unstable end. One CSV row per run: the verdict, proofs tried, leaves,
the share of the box's volume they cover, the deepest split and CPU s.

    python benchmarks/map_cover.py SEED F CAP [--eigen-only | --no-eigen] [--hu HU] [--out FILE.csv]
    python benchmarks/map_cover.py 31 1e-3 4000 --eigen-only
    python benchmarks/map_cover.py 13 1.06e-2 4000 --hu 0.6022096970393988
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from csvout import write_rows
from h_max_diagnosis import bracket_crossing, the_loop

from ftc_verify.analysis.moments import sampled_eigen, sampled_proof, sampled_second, sampled_taylor
from ftc_verify.analysis.moments.sampled import spectral_radius
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.rigorous import precision


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("seed", type=int)
    parser.add_argument("f", type=float)
    parser.add_argument("cap", type=int)
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--eigen-only", action="store_true")
    group.add_argument("--no-eigen", action="store_true")
    parser.add_argument("--hu", type=float, default=None)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    if args.eigen_only:
        sampled_second.certify_second_order = lambda *a, **k: False  # type: ignore[assignment]
        sampled_taylor._certify = lambda *a, **k: False  # type: ignore[assignment]
    if args.no_eigen:
        sampled_eigen.eigen_stable = lambda *a, **k: False  # type: ignore[assignment]
    loop = the_loop(4, 3, args.seed)
    if args.hu is not None:
        loop = conditioned(loop)
    chain = loop.chain
    h = (bracket_crossing(loop) if args.hu is None else args.hu) * (1 - args.f)
    with precision(64):
        parts = sampled_proof.MapParts.build(loop, h)
    t0 = time.process_time()
    stack = [(np.array(chain.rate_min, dtype=float), np.array(chain.rate_max, dtype=float), 0)]
    tried = leaves = deepest = 0
    volume = 0.0
    verdict = "covered"
    while stack:
        if tried >= args.cap:
            verdict = "cap reached"
            break
        lo, hi, depth = stack.pop()
        tried += 1
        if tried % 100 == 0:
            print(f"{tried} tried, {leaves} proved ({volume:.3f} of the box), {len(stack)} open, depth {deepest}, "
                  f"{time.process_time() - t0:.0f} CPU s", flush=True)
        if sampled_proof.subbox_stable(loop, h, parts, lo, hi):
            leaves += 1
            volume += 2.0 ** -depth
            continue
        if spectral_radius(loop, h, 0.5 * (lo + hi)) >= 1.0:
            verdict = "midpoint radius >= 1"
            break
        r = sampled_proof.split_rate(loop, h, lo, hi)
        mid = 0.5 * (lo[r] + hi[r])
        upper, lower = hi.copy(), lo.copy()
        upper[r] = mid
        lower[r] = mid
        stack.append((lo, upper, depth + 1))
        stack.append((lower, hi, depth + 1))
        deepest = max(deepest, depth + 1)
    proofs = "eigen only" if args.eigen_only else "no eigen" if args.no_eigen else "all"
    row = {"seed": args.seed, "f": args.f, "hu": args.hu, "proofs": proofs, "verdict": verdict, "tried": tried,
           "leaves": leaves, "volume": round(volume, 4), "deepest": deepest, "cpu_s": round(time.process_time() - t0, 1)}
    print(" ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    if args.out:
        write_rows(args.out, [row])


if __name__ == "__main__":
    main()
