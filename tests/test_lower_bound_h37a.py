"""``float_gain``'s mean-square stability test by one Lyapunov solve (issue 37, item 3):
it refuses exactly the loops whose second-moment generator has an eigenvalue in the
closed right half plane (compared with the eigenvalues on shifted copies of the paper's loop)."""

from __future__ import annotations

import numpy as np

from ftc_verify.analysis.lower_bound import float_gain
from ftc_verify.analysis.moments.stability import second_moment_matrix


def test_float_gain_refuses_exactly_the_loops_that_are_not_mean_square_stable(paper_loop) -> None:
    loop = paper_loop.nominal()
    Q = loop.chain.generator(loop.chain.rate_min)
    n = loop.n
    base = float(np.max(np.linalg.eigvals(second_moment_matrix(loop.A, Q)).real))
    for shift in (-1.0, -0.4, -0.05, 0.05, 0.4):  # the abscissa moves by 2 * shift (A + c I: X -> 2c X)
        A = [a + (shift - base / 2) * np.eye(n) for a in loop.A]
        abscissa = float(np.max(np.linalg.eigvals(second_moment_matrix(A, Q)).real))
        assert abs(abscissa - 2 * shift) < 1e-9
        found = float_gain(A, loop.Bw, loop.Cz, Q)
        assert (found is None) == (abscissa >= 0), shift
        if found is not None:
            assert found[0] > 0 and np.isfinite(found[0])
