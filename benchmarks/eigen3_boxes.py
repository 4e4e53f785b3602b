#!/usr/bin/env python
"""The two eigenpair enclosures of a sub-box's one-period map side by side (issue 31,
item 2): on a held-out ``n = 4, m = 3`` loop at ``h = HU (1 - F)`` (conditioned as the
refinement runs it, ``h_max_diagnosis.held_out_rung``), sub-boxes at the worst vertex
given by the exponents ``k1,...,k6`` (``2^-ki`` of rate ``i``'s range): the second-order
form with the enclosure of ``sampled_eigen`` (bound, reach) against the third-order form
with the moving enclosure of ``sampled_eigen3`` (bound, reach), with the float64 radius at
the corner and the CPU seconds of each form and bound; one CSV row per sub-box.

    python benchmarks/eigen3_boxes.py 13 0.6022096970393988 9e-4 4,4,4,4,4,4 2,2,2,4,4,2 [--out FILE.csv]
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from csvout import write_rows
from h_max_diagnosis import held_out_rung, rung_parser

from ftc_verify.analysis.moments.cubic_balls import cubic_terms
from ftc_verify.analysis.moments.quad_balls import quad_map
from ftc_verify.analysis.moments.sampled import spectral_radius
from ftc_verify.analysis.moments.sampled_eigen import eigen_radius_bound, enclosure_reach
from ftc_verify.analysis.moments.sampled_eigen3 import cubic_radius_bound
from ftc_verify.analysis.moments.sampled_taylor import _rates_affine
from ftc_verify.analysis.rigorous import precision


def _vertex_box(rung: Any, exponents: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    chain = rung.loop.chain
    lo, hi = np.array(chain.rate_min, dtype=float), np.array(chain.rate_max, dtype=float)
    for r, k in zip(chain.free_rate_indices, exponents):
        w = (chain.rate_max[r] - chain.rate_min[r]) * 2.0 ** -k
        if rung.worst[r] == chain.rate_min[r]:
            hi[r] = lo[r] + w
        else:
            lo[r] = hi[r] - w
    return lo, hi


def main() -> None:
    parser = rung_parser(__doc__)
    parser.add_argument("boxes", nargs="+", help="exponents k1,...,k6 per sub-box")
    args = parser.parse_args()
    rung = held_out_rung(args.seed, args.hu, args.f)
    loop = rung.loop
    res, modes, lift, h = rung.parts.floats
    rows: list[dict[str, Any]] = []
    for text in args.boxes:
        lo, hi = _vertex_box(rung, tuple(int(k) for k in text.split(",")))
        with precision(64):
            found = _rates_affine(loop, lo, hi)
            t0 = time.process_time()
            form = quad_map(res, modes, found[0], found[1], h, lift)
            t1 = time.process_time()
            second = eigen_radius_bound(form, loop.states, loop.r)
            t2 = time.process_time()
            terms = cubic_terms(res, modes, found[0], found[1], h, lift)
            t3 = time.process_time()
            moving = cubic_radius_bound(terms, loop.states, loop.r)
            t4 = time.process_time()
        corner = np.where(np.abs(rung.worst - lo) <= np.abs(rung.worst - hi), lo, hi)
        row = {"seed": args.seed, "f": args.f, "box": text, "corner_rho": spectral_radius(loop, rung.h, corner),
               "second_bound": second, "second_reach": enclosure_reach(form), "moving_bound": moving.top,
               "moving_reach": moving.reach, "second_form_s": round(t1 - t0, 2), "second_bound_s": round(t2 - t1, 2),
               "third_form_s": round(t3 - t2, 2), "moving_bound_s": round(t4 - t3, 2)}
        rows.append(row)
        print(" ".join(f"{k} {v:.6g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()), flush=True)
    if args.out:
        write_rows(args.out, rows)


if __name__ == "__main__":
    main()
