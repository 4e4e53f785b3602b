#!/usr/bin/env python
"""Sub-boxes at the worst vertex proved by the eigenpair enclosure (``sampled_eigen``)
and by the cone certificates before it (``sampled_second``), issue 31 item 2.

For a held-out ``n = 4, m = 3`` loop (``h_max_diagnosis.the_loop``, the draw of
``h_max_heldout.py``) at ``h = a (1 - F)`` below the worst vertex's float64 crossing
``a``, each width spec ``k1,...,k6`` (or one ``k`` for all six rates) is the sub-box
spanning ``2^-k`` of each free rate's range from the worst vertex into the box. One
row per spec: the eigenpair enclosure's proved bound of the radius over the sub-box
(empty when none), whether the cone certificates (Perron mix 0.05, then the shifted
one) prove it, and the CPU seconds of the second-order form and of each proof.

    python benchmarks/eigen_boxes.py SEED F SPEC [SPEC ...] [--out FILE.csv]
    python benchmarks/eigen_boxes.py 13 1e-3 6 5 4 3 3,3,3,5,5,3 2,2,2,8,8,2
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from csvout import write_rows
from h_max_diagnosis import bracket_crossing, the_loop

from ftc_verify.analysis.moments import sampled_proof as sp
from ftc_verify.analysis.moments.quad_balls import quad_map
from ftc_verify.analysis.moments.sampled import rate_points
from ftc_verify.analysis.moments.sampled_balls import generator_coefficients
from ftc_verify.analysis.moments.sampled_bracket import worst_vertex
from ftc_verify.analysis.moments.sampled_eigen import eigen_radius_bound
from ftc_verify.analysis.moments.sampled_second import certify_second_order
from ftc_verify.analysis.moments.sampled_taylor import _rates_affine
from ftc_verify.analysis.rigorous import precision


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("seed", type=int)
    parser.add_argument("f", type=float)
    parser.add_argument("specs", nargs="+")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    loop = the_loop(4, 3, args.seed)
    chain = loop.chain
    h = bracket_crossing(loop) * (1 - args.f)
    rho, v = worst_vertex(loop, h, list(rate_points(chain)))
    v = np.asarray(v, dtype=float)
    with precision(64):
        parts = sp.MapParts.build(loop, h)
    full = chain.rate_max - chain.rate_min
    free = [idx for idx, _ in generator_coefficients(chain)[1] if full[idx] > 0]
    print(f"seed {args.seed}, h = a (1 - {args.f:g}), margin at the worst vertex {1 - rho:.3g}")
    rows = []
    for spec in args.specs:
        ks = [int(x) for x in spec.split(",")] if "," in spec else [int(spec)] * len(free)
        lo, hi = v.copy(), v.copy()
        for idx, k in zip(free, ks):
            other = v[idx] + (-1.0 if v[idx] == chain.rate_max[idx] else 1.0) * 2.0 ** -k * full[idx]
            lo[idx], hi[idx] = min(v[idx], other), max(v[idx], other)
        found = _rates_affine(loop, lo, hi)
        res, modes, lift, hb = parts.floats
        t0 = time.process_time()
        form = quad_map(res, modes, found[0], found[1], hb, lift)
        t1 = time.process_time()
        with precision(64):
            top = eigen_radius_bound(form, loop.states, loop.r)
            t2 = time.process_time()
            cone = certify_second_order(loop, form, 0.05) or certify_second_order(loop, form, shifted=True)
            t3 = time.process_time()
        rows.append({"seed": args.seed, "f": args.f, "widths": "/".join(f"2^-{k}" for k in ks),
                     "eigen_bound": "" if top is None else f"{top:.7f}",
                     "eigen_proved": top is not None and top < 1.0, "cone_proved": cone,
                     "form_cpu": round(t1 - t0, 3), "eigen_cpu": round(t2 - t1, 3), "cone_cpu": round(t3 - t2, 3)})
        r = rows[-1]
        print(f"{r['widths']:>40}  eigen {r['eigen_bound'] or 'none':>10} {r['eigen_proved']!s:>5}  "
              f"cone {cone!s:>5}  CPU form {r['form_cpu']:.2f} s, eigen {r['eigen_cpu']:.2f} s, "
              f"cone {r['cone_cpu']:.2f} s", flush=True)
    if args.out:
        write_rows(args.out, rows)


if __name__ == "__main__":
    main()
