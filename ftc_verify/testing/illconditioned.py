r"""Closed loops in badly chosen coordinates, with exact references: the peer family.

A loop whose joint modes are all identical, :math:`(A, B_w, C_z)` in every mode, has
second moments that evolve as those of the LTI system (the chain only relabels the
mass), so its spectral abscissa is :math:`2\,\alpha(A)` and its stochastic
:math:`H_\infty` norm is the LTI norm of :math:`C_z(sI - A)^{-1}B_w`, which SLICOT's
``ab13dd`` computes to high accuracy (:func:`control.linfnorm`). :func:`identical_mode_loop`
draws such a loop with a chosen norm in well-conditioned coordinates, then moves it to
the coordinates :math:`x' = S x` with :math:`S = D\,M`: :math:`D` diagonal (the change of
units, entries log-uniform with the given condition) and :math:`M` a non-orthogonal
similarity of the given condition (:math:`U \operatorname{diag}(\sigma) V^T`, random
orthogonal :math:`U, V`, singular values log-spaced). The transformed loop has the same
norm and abscissa; only its numerics changed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hypothesis import strategies as st

from ..analysis.closedloop import ClosedLoop
from ..model.system import JointChain, Matrix

__all__ = ["PeerLoop", "identical_mode_loop", "similarity", "two_mode_chain", "peer_loops"]


@dataclass(frozen=True, eq=False)
class PeerLoop:
    """A drawn loop, its well-conditioned original and the similarity between them."""

    loop: ClosedLoop
    original: ClosedLoop
    S: Matrix
    seed: int
    diagonal_condition: float
    transform_condition: float

    @property
    def abscissa(self) -> float:
        """The exact second-moment abscissa, ``2 max Re eig(A)`` (from the original)."""
        return 2.0 * float(np.max(np.linalg.eigvals(self.original.A[0]).real))

    def reference_norm(self) -> float:
        """SLICOT ``ab13dd`` (via :func:`control.linfnorm`) on the original coordinates."""
        import control

        A, B, C = self.original.A[0], self.original.Bw[0], self.original.Cz[0]
        sys = control.ss(A, B, C, np.zeros((C.shape[0], B.shape[1])))
        return float(control.linfnorm(sys, tol=1e-12)[0])


def two_mode_chain() -> JointChain:
    """The joint chain of the paper's example (m = 2): rates do not matter for identical modes."""
    return JointChain(np.array([[-0.5, 0.5], [0.8, -0.8]]), np.array([[0.0, 2.0], [3.0, 0.0]]),
                      np.array([[0.0, 3.0], [4.0, 0.0]]))


def similarity(rng: np.random.Generator, n: int, diagonal_condition: float, transform_condition: float) -> Matrix:
    """``S = D M`` of the module docstring."""
    def orthogonal() -> Matrix:
        Q, R = np.linalg.qr(rng.standard_normal((n, n)))
        return Q * np.sign(np.diag(R))[None, :]

    d = np.exp(rng.uniform(0.0, np.log(diagonal_condition), n)) if diagonal_condition > 1 else np.ones(n)
    if n > 1 and diagonal_condition > 1:
        d[0], d[-1] = 1.0, diagonal_condition  # the condition exactly as asked
    sv = np.exp(np.linspace(0.0, np.log(transform_condition), n)) if n > 1 else np.ones(1)
    return d[:, None] * ((orthogonal() * sv[None, :]) @ orthogonal().T)


def identical_mode_loop(seed: int, n: int, *, norm: float = 1.0, diagonal_condition: float = 1.0,
                        transform_condition: float = 1.0, inputs: int = 1, outputs: int = 1,
                        chain: JointChain | None = None) -> PeerLoop:
    """A stable identical-mode loop with LTI :math:`H_\\infty` norm about ``norm``, drawn
    from ``numpy.random.default_rng(seed)``, moved by :func:`similarity` (module docstring)."""
    rng = np.random.default_rng(seed)
    chain = two_mode_chain() if chain is None else chain
    A = rng.standard_normal((n, n))
    A = A - (np.max(np.linalg.eigvals(A).real) + rng.uniform(0.2, 1.5)) * np.eye(n)
    B = rng.standard_normal((n, inputs))
    C = rng.standard_normal((outputs, n))
    import control  # scale C so that the norm is the one asked for

    base = float(control.linfnorm(control.ss(A, B, C, np.zeros((outputs, inputs))), tol=1e-10)[0])
    C = C * (norm / base)
    S = similarity(rng, n, diagonal_condition, transform_condition)
    S_inv = np.linalg.inv(S)
    count = chain.n_states

    def make(a: Matrix, b: Matrix, c: Matrix) -> ClosedLoop:
        return ClosedLoop(chain, (a,) * count, (b,) * count, (c,) * count, ((),) * count, "peer family")

    original = make(A, B, C)
    moved = make(S @ A @ S_inv, S @ B, C @ S_inv)
    return PeerLoop(moved, original, S, seed, float(diagonal_condition), float(transform_condition))


@st.composite
def peer_loops(draw: st.DrawFn, *, max_n: int = 6, max_norm: float = 800.0, max_diagonal_condition: float = 1e6,
               max_transform_condition: float = 1e4, abscissa: float | None = None) -> PeerLoop:
    """Hypothesis strategy: :func:`identical_mode_loop` with a drawn seed, ``n`` in
    ``2..max_n``, norm log-uniform in ``[0.1, max_norm]`` and both conditions log-uniform
    up to their maxima. With ``abscissa`` given, the original is shifted so that the
    true second-moment abscissa is exactly that (in exact arithmetic), and moved again.

    Examples
    --------
    >>> from hypothesis import given, settings
    >>> @settings(max_examples=3, deadline=None)
    ... @given(peer_loops(max_n=3))
    ... def test_abscissa(p):
    ...     assert p.abscissa < 0
    >>> test_abscissa()
    """
    seed = draw(st.integers(0, 2**32 - 1))
    n = draw(st.integers(2, max_n))
    norm = 10.0 ** draw(st.floats(-1.0, float(np.log10(max_norm))))
    dc = 10.0 ** draw(st.floats(0.0, float(np.log10(max_diagonal_condition))))
    tc = 10.0 ** draw(st.floats(0.0, float(np.log10(max_transform_condition))))
    p = identical_mode_loop(seed, n, norm=norm, diagonal_condition=dc, transform_condition=tc)
    if abscissa is None:
        return p
    from dataclasses import replace

    A0 = p.original.A[0] + 0.5 * (abscissa - p.abscissa) * np.eye(n)
    S_inv = np.linalg.inv(p.S)
    count = len(p.loop.A)
    original = replace(p.original, A=(A0,) * count, source=None)
    moved = replace(p.loop, A=(p.S @ A0 @ S_inv,) * count, source=None)
    return PeerLoop(moved, original, p.S, seed, dc, tc)
