"""mono13: the monotonicity reduction combined with the present sub-box proofs, counted.

A branch and bound over the rate box at ``h = a (1 - f)`` (``mono13_signs.Setup``): on
each sub-box the present proof (``sampled_proof.subbox_stable``, rigorous) first; where
it fails, the best-case monotonicity test of ``mono13_signs.box_test`` (float64, sampled
Perron vectors, envelope ``J+-``: NOT a proof) for every rate still wide; each rate whose
sign it decides is fixed at the face where the radius is larger and the face is
processed instead; when none is decided the sub-box is halved along
``sampled_proof.split_rate``'s rate. Prints the counts of both kinds of test and their
CPU: an estimate of what a rigorous monotonicity test would need, with the present
proofs doing the rest.

    python benchmarks/mono13_reduce.py 31 1e-3 400
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from mono13_signs import Setup, box_test, perron

from ftc_verify.analysis.moments import sampled_proof as sp
from ftc_verify.analysis.rigorous import precision


def reduce_box(s: Setup, cap: int) -> dict[str, float]:
    with precision(64):
        parts = sp.MapParts.build(s.loop, s.h)
    rng = np.random.default_rng(0)
    count = {"proofs": 0, "proved": 0, "tests": 0, "reduced rates": 0, "splits": 0, "proof_cpu": 0.0, "test_cpu": 0.0}
    queue = [(s.lo.copy(), s.hi.copy())]
    while queue:
        if count["proofs"] + count["tests"] >= cap:
            count["left"] = len(queue)
            return count
        lo, hi = queue.pop()
        t = time.process_time()
        ok = sp.subbox_stable(s.loop, s.h, parts, lo, hi)
        count["proof_cpu"] += time.process_time() - t
        count["proofs"] += 1
        if ok:
            count["proved"] += 1
            continue
        if np.array_equal(lo, hi):
            count["failed point"] = 1
            return count
        t = time.process_time()
        _, res = box_test(s, lo, hi, rng, rand=8)
        count["test_cpu"] += time.process_time() - t
        count["tests"] += 1
        decided = [idx for idx, (_, _, env) in res.items() if env > 0 and hi[idx] > lo[idx]]
        if decided:
            lo, hi = lo.copy(), hi.copy()
            mid = 0.5 * (lo + hi)
            for idx in decided:  # the face where the radius is larger
                if derivative_sign(s, mid, idx) > 0:
                    lo[idx] = hi[idx]
                else:
                    hi[idx] = lo[idx]
            count["reduced rates"] += len(decided)
            queue.append((lo, hi))
            continue
        idx = sp.split_rate(s.loop, s.h, lo, hi)
        if idx is None:
            count["unsplittable"] = 1
            return count
        cut = 0.5 * (lo[idx] + hi[idx])
        a_hi, b_lo = hi.copy(), lo.copy()
        a_hi[idx], b_lo[idx] = cut, cut
        queue += [(lo, a_hi), (b_lo, hi)]
        count["splits"] += 1
    count["left"] = 0
    return count


def derivative_sign(s: Setup, rates: np.ndarray, idx: tuple[int, ...]) -> float:
    """The sign of ``d rho / d beta_idx`` at ``rates`` (the decided sign of the sub-box)."""
    _, x, y = perron(s.map(rates))
    Gp, Gm = s.parts(dict(s.free)[idx])
    return float(np.sign(y @ s.J(s.generator(rates), Gp - Gm) @ x))


if __name__ == "__main__":
    seed, f, cap = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
    setup = Setup(seed, f)
    load, c0 = os.getloadavg()[0], time.process_time()
    out = reduce_box(setup, cap)
    print(f"seed {seed} f {f} load {load:.2f}: " + ", ".join(
        f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}" for k, v in out.items())
        + f"; total {time.process_time() - c0:.1f} CPU s", flush=True)
