"""The second-order certificate of ``sampled_second`` on anisotropic sub-boxes at the worst
vertex (round 13, ``benchmarks/results/mono13.md``): for each width spec ``k1,...,k6`` (the
sub-box spans ``2^-k`` of each free rate's range from the worst vertex into the box) the
float64 relative slack of the first- and second-order moving certificates with the exact
map at the sub-box's vertices and 20 random points, and whether the rigorous check
(``certify_second_order``, Perron mix 0.05) proves it.

    python benchmarks/mono13_vertex_boxes.py SEED F SPEC [SPEC ...]
    python benchmarks/mono13_vertex_boxes.py 13 1e-3 6,4,7,10,10,7 5,3,6,9,9,6
"""

from __future__ import annotations

import itertools
import math
import sys
import time

import numpy as np

from h_max_diagnosis import _relative_slack, bracket_crossing, the_loop

from ftc_verify.analysis.moments import sampled_proof as sp
from ftc_verify.analysis.moments.quad_balls import pairs, quad_map
from ftc_verify.analysis.moments.sampled import one_period_map, rate_points
from ftc_verify.analysis.moments.sampled_balls import generator_coefficients
from ftc_verify.analysis.moments.sampled_bracket import worst_vertex
from ftc_verify.analysis.moments.sampled_second import certify_second_order, second_order_choices
from ftc_verify.analysis.moments.sampled_taylor import _rates_affine, float_choices, left_perron
from ftc_verify.analysis.rigorous import precision


def test(loop, h, parts, v, free, inward, ks, rng) -> None:
    """One width spec: print the slacks and the rigorous verdict."""
    chain = loop.chain
    full = chain.rate_max - chain.rate_min
    lo, hi = v.copy(), v.copy()
    for idx, k in zip(free, ks):
        other = v[idx] + inward[idx] * 2.0 ** -k * full[idx]
        lo[idx], hi[idx] = min(v[idx], other), max(v[idx], other)
    found = _rates_affine(loop, lo, hi)
    res, modes, lift, hh = parts.floats
    t = time.process_time()
    form = quad_map(res, modes, found[0], found[1], hh, lift)
    Tc, Tl, Tq, _ = form
    S = loop.states
    choice, w = float_choices(Tc, list(Tl), S, loop.r, 0.05), left_perron(Tc)
    second = second_order_choices(Tc, Tl, Tq, choice[0], np.stack(choice[1]), w)
    Y0, Yl, Yq = choice[0], np.stack(choice[1]), second[0]
    prs = pairs(len(free))
    worst = dict.fromkeys(("first", "second"), math.inf)
    pts = [np.array(c) for c in itertools.product((-1.0, 1.0), repeat=len(free))]
    for d in pts + [rng.uniform(-1, 1, len(free)) for _ in range(20)]:
        rates = 0.5 * (lo + hi)
        for k, idx in enumerate(free):
            rates[idx] += 0.5 * d[k] * (hi[idx] - lo[idx])
        T = one_period_map(loop, h, rates, scaled=True)
        mu = np.array([d[x] * d[y] for x, y in prs])
        for name, Y in {"first": Y0 + d @ Yl, "second": Y0 + d @ Yl + mu @ Yq}.items():
            worst[name] = min(worst[name], _relative_slack(loop, Y, T @ Y))
    with precision(64):
        ok = certify_second_order(loop, form, 0.05)
    print(ks, " ".join(f"{k} {x:.2e}" for k, x in worst.items()), "proved", ok,
          f"{time.process_time() - t:.2f} CPU s", flush=True)


def main() -> None:
    seed, f = int(sys.argv[1]), float(sys.argv[2])
    loop = the_loop(4, 3, seed)
    chain = loop.chain
    h = bracket_crossing(loop) * (1 - f)
    rho, v = worst_vertex(loop, h, list(rate_points(chain)))
    v = np.asarray(v, float)
    with precision(64):
        parts = sp.MapParts.build(loop, h)
    full = chain.rate_max - chain.rate_min
    free = [idx for idx, _ in generator_coefficients(chain)[1] if full[idx] > 0]
    inward = {idx: (-1.0 if v[idx] == chain.rate_max[idx] else 1.0) for idx in free}
    print("margin", 1 - rho, "free", free)
    rng = np.random.default_rng(0)
    for spec in sys.argv[3:]:
        test(loop, h, parts, v, free, inward, [int(x) for x in spec.split(",")], rng)


if __name__ == "__main__":
    main()
