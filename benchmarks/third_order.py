#!/usr/bin/env python
"""The one-period map's remainder on a sub-box, second- against third-order forms, issue
31 item 2: on the sub-box ``EXTRA`` halvings (``sampled_cover.map_split``, the harder
half) below the ``h_max`` cover's probe of a held-out ``n = 4, m = 3`` loop
(``h_max_diagnosis.the_loop``, conditioned) at ``h = HU (1 - F)``: the remainder of
``quad_balls.quad_map`` and of ``cubic_balls.cubic_map`` (largest entry and row sum),
the sum of the absolute values of the map's true third-order coefficients (a least
squares fit of all monomials up to degree four to ``POINTS`` dense float maps), the
largest error of each form's polynomial part at those points, the eigenpair enclosure's
bound with each remainder, and CPU s per form. One CSV row.

    python benchmarks/third_order.py SEED HU F EXTRA [--points 700] [--out FILE.csv]
    python benchmarks/third_order.py 13 0.6022096970393988 1.083e-2 6
"""

from __future__ import annotations

import itertools
import time

import numpy as np
import scipy.linalg

from csvout import write_rows
from h_max_diagnosis import harder_half, held_out_rung, rung_parser

from ftc_verify.analysis.moments.cubic_balls import cubic_map
from ftc_verify.analysis.moments.quad_balls import pairs, quad_map
from ftc_verify.analysis.moments.sampled_cover import map_split, probe_box
from ftc_verify.analysis.moments.sampled_eigen import eigen_radius_bound
from ftc_verify.analysis.moments.sampled_taylor import _rates_affine
from ftc_verify.analysis.rigorous import precision


def main() -> None:
    parser = rung_parser(__doc__)
    parser.add_argument("extra", type=int)
    parser.add_argument("--points", type=int, default=700)
    args = parser.parse_args()
    rung = held_out_rung(args.seed, args.hu, args.f)
    loop, h, parts, worst = rung.loop, rung.h, rung.parts, rung.worst
    chain = loop.chain
    lo, hi, _ = probe_box(loop, h, rung.box, worst)
    for _ in range(args.extra):
        lo, hi = harder_half(lo, hi, map_split(loop, h, lo, hi), worst)
    full = chain.rate_max - chain.rate_min
    widths = [float((hi[r] - lo[r]) / full[r]) for r in chain.rate_indices if full[r] > 0]
    res, modes, lift, hb = parts.floats
    with precision(64):
        found = _rates_affine(loop, lo, hi)
        assert found is not None
        q, D = found
        t0 = time.process_time()
        quad = quad_map(res, modes, q, D, hb, lift)
        t1 = time.process_time()
        tight = cubic_map(res, modes, q, D, hb, lift)
        t2 = time.process_time()
    assert quad is not None and tight is not None
    K = D.shape[0]
    eye = np.eye(modes[0].shape[0] // q[0].shape[0])

    def exact(d: np.ndarray) -> np.ndarray:
        G = modes[0] + np.kron((q[0] + np.tensordot(d, D, 1)).T, eye)
        return res[0] @ scipy.linalg.expm(G * float(hb[0][0, 0])) @ lift[0]

    rng = np.random.default_rng(1)
    X = rng.uniform(-1, 1, (args.points, K))
    mons = [m for deg in range(5) for m in itertools.combinations_with_replacement(range(K), deg)]
    A = np.array([[np.prod(x[list(m)]) for m in mons] for x in X])
    maps = [exact(x) for x in X]
    coef = np.linalg.lstsq(A, np.array([T.ravel() for T in maps]), rcond=None)[0]
    third = np.abs(coef[[len(m) == 3 for m in mons]]).sum(axis=0).max()
    errors = []
    for form in (quad, tight):
        Tc, Tl, Tq, _ = form
        worst_err = 0.0
        for x, T in zip(X, maps):
            mu = np.array([x[a] * x[b] for a, b in pairs(K)])
            worst_err = max(worst_err, float(np.abs(T - Tc - np.tensordot(x, Tl, 1) - np.tensordot(mu, Tq, 1)).max()))
        errors.append(worst_err)
    row = {"seed": args.seed, "f": args.f, "extra": args.extra, "widths": " ".join(f"{w:.4g}" for w in widths),
           "quad_rad_max": float(quad[3].max()), "cubic_rad_max": float(tight[3].max()),
           "quad_rad_row": float(quad[3].sum(axis=1).max()), "cubic_rad_row": float(tight[3].sum(axis=1).max()),
           "true_third_sum": float(third), "quad_err": errors[0], "cubic_err": errors[1],
           "quad_bound": eigen_radius_bound(quad, loop.states, loop.r),
           "cubic_bound": eigen_radius_bound(tight, loop.states, loop.r),
           "quad_cpu_s": round(t1 - t0, 2), "cubic_cpu_s": round(t2 - t1, 2)}
    print(" ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    if args.out:
        write_rows(args.out, [row])


if __name__ == "__main__":
    main()
