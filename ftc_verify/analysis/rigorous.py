r"""Rigorous arithmetic for certificates: ball matrices and proofs of positive definiteness.

A float64 computation can say "negative definite" about a matrix that is not, when the
rounding error of forming it (or of its eigenvalues) is larger than its smallest
eigenvalue -- which is what physical units and ill-conditioned realisations produce.
This module proves such claims instead, with Arb's ball arithmetic (``python-flint``,
the FLINT/Arb bindings on PyPI: every real is a midpoint and a radius that provably
contains the exact value, at a chosen precision).

* :class:`Ball` wraps an ``arb_mat`` with the operators the LMI blocks of
  :mod:`ftc_verify.analysis.lmi` use (``+``, ``-``, ``@``, ``.T``, scalar products) and
  :func:`ball_bmat` is their ``bmat``, so the *same* block functions build the blocks
  for the solver, for the float check and for the rigorous check. Float inputs convert
  exactly (a float is a dyadic rational).
* :func:`proven_positive_definite` proves that every symmetric matrix inside a ball
  matrix :math:`M` is positive definite. Derivation: take any float matrix :math:`C`
  (a preconditioner) and the float Cholesky factor :math:`L` of the midpoint of
  :math:`C^T M C`; form :math:`E = L^{-1} C^T M C L^{-T}` in ball arithmetic (with
  :math:`L^{-1}` a float matrix, exact input). If :math:`\|E - I\|_F < 1` is proved,
  :math:`E \succ 0` (its eigenvalues lie in :math:`(0, 2)`), so :math:`E` and hence
  :math:`G = C L^{-T}` are nonsingular, and by Sylvester's law of inertia
  :math:`M = G^{-T} E G^{-1} \succ 0`. No step trusts a float result: the floats only
  choose :math:`G`; a bad choice makes the proof fail, never lie. Two rounds (the
  second on the midpoint of :math:`E`) handle matrices whose float Cholesky is
  inaccurate.
* :func:`proven_not_psd` proves that a ball matrix has a direction :math:`v` with
  :math:`v^T M v < 0` (the float eigenvector of the smallest eigenvalue, then the
  quadratic form in ball arithmetic).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from ..interrupts import deferred_signals
from ..model.system import Matrix

__all__ = ["PRECISION_BITS", "Ball", "ball", "ball_bmat", "precision", "proven_positive_definite",
           "proven_positive_definite_cholesky", "proven_not_psd", "midpoint", "tight_solve", "LU_RADIUS"]

#: Working precision (bits) of the rigorous checks; enclosures of products of float data
#: are then tight to about 1e-38 relative, far below any margin a certificate can have.
PRECISION_BITS = 128


def _flint() -> Any:
    import flint

    return flint


@contextlib.contextmanager
def precision(bits: int = PRECISION_BITS) -> Iterator[None]:
    """Arb's working precision for the duration of the block (restored after)."""
    with _flint().ctx.workprec(bits):
        yield


class Ball:
    """A ball matrix (``flint.arb_mat``) with numpy-like operators (module docstring)."""

    __array_ufunc__ = None  # numpy defers ``ndarray @ Ball`` to __rmatmul__

    def __init__(self, value: Any) -> None:
        self.value = value

    @property
    def shape(self) -> tuple[int, int]:
        return (self.value.nrows(), self.value.ncols())

    @property
    def T(self) -> Ball:
        return Ball(self.value.transpose())

    def _coerce(self, other: Any) -> Any:
        if isinstance(other, Ball):
            return other.value
        if isinstance(other, _flint().arb):
            return other
        arr = np.asarray(other, dtype=float)
        if arr.ndim == 0:
            return _flint().arb(float(arr))
        return _to_arb(arr)

    def __add__(self, other: Any) -> Ball:
        return Ball(self.value + self._coerce(other))

    __radd__ = __add__

    def __neg__(self) -> Ball:
        return Ball(-self.value)

    def __sub__(self, other: Any) -> Ball:
        return Ball(self.value - self._coerce(other))

    def __rsub__(self, other: Any) -> Ball:
        return Ball(self._coerce(other) - self.value)

    def __mul__(self, other: Any) -> Ball:
        if isinstance(other, _flint().arb):
            return Ball(self.value * other)
        if isinstance(other, Ball) or np.ndim(other) != 0:
            raise TypeError("Ball * matrix: use @")
        return Ball(self.value * self._coerce(other))

    __rmul__ = __mul__

    def __matmul__(self, other: Any) -> Ball:
        return Ball(self.value * self._coerce(other))

    def __rmatmul__(self, other: Any) -> Ball:
        return Ball(self._coerce(other) * self.value)


def _to_arb(M: Matrix) -> Any:
    M = np.atleast_2d(np.asarray(M, dtype=float))
    if not np.all(np.isfinite(M)):
        raise ValueError("non-finite entry in a matrix given to the rigorous check")
    return _flint().arb_mat(M.tolist()) if M.size else _flint().arb_mat(M.shape[0], M.shape[1])


def ball(M: Matrix | Ball) -> Ball:
    """The exact ball of a float matrix (radius 0)."""
    return M if isinstance(M, Ball) else Ball(_to_arb(M))


def ball_bmat(rows: Sequence[Sequence[Any]]) -> Ball:
    """:func:`numpy.block` for rows mixing :class:`Ball` and float matrices."""
    flint = _flint()
    parts = [[ball(e) if not isinstance(e, Ball) else e for e in row] for row in rows]
    heights = [row[0].shape[0] for row in parts]
    widths = [e.shape[1] for e in parts[0]]
    out = flint.arb_mat(sum(heights), sum(widths))
    r0 = 0
    for row, h in zip(parts, heights):
        c0 = 0
        for e, w in zip(row, widths):
            v = e.value
            for r in range(h):
                for c in range(w):
                    out[r0 + r, c0 + c] = v[r, c]
            c0 += w
        r0 += h
    return Ball(out)


def midpoint(M: Ball) -> Matrix:
    """Float midpoints of a ball matrix."""
    rows, cols = M.shape
    return np.array(M.value.mid().tolist(), dtype=float).reshape(rows, cols)


def _frobenius_below_one(F: Any) -> bool:
    """Proves ``||F||_F < 1`` for a ball matrix ``F``."""
    flint = _flint()
    total = flint.arb(0)
    for e in F.entries():
        total += e * e
    return bool(total < 1)


def proven_positive_definite(M: Ball, precond: Matrix | Ball | None = None, *, rounds: int = 2) -> bool:
    """``True`` only if every symmetric matrix in the ball ``M`` is positive definite
    (module docstring); ``precond`` is the optional float congruence ``C`` (a float
    matrix, or its exact :class:`Ball`)."""
    n = M.shape[0]
    if n == 0:
        return True
    C = None if precond is None else ball(precond)
    E = M if C is None else (C.T @ M @ C)
    eye = np.eye(n)
    for _ in range(rounds):
        mid = midpoint(E)
        mid = 0.5 * (mid + mid.T)
        if not np.all(np.isfinite(mid)):
            return False
        d = np.sqrt(np.abs(np.diag(mid)))
        if np.any(d == 0) or not np.all(np.isfinite(1.0 / d)):
            return False
        try:  # Cholesky of the Jacobi-scaled midpoint (scaling by 1/d is part of the float G)
            L = np.linalg.cholesky(mid / d[:, None] / d[None, :])
            G = np.linalg.inv(L).T / d[:, None]  # G = D^-1 L^-T
        except np.linalg.LinAlgError:
            return False
        if not np.all(np.isfinite(G)):
            return False
        Gb = ball(G)
        E = Gb.T @ E @ Gb
        if _frobenius_below_one((E - eye).value):
            return True
    return False


def proven_positive_definite_cholesky(M: Ball) -> bool:
    r"""``True`` only if every symmetric matrix in the ball ``M`` is positive definite,
    by a Cholesky factorisation run in ball arithmetic at the working precision (lower
    triangle only): every pivot :math:`d_k = M_{kk} - \sum_{j<k} L_{kj}^2` encloses the
    pivot of every symmetric matrix in the ball, and all of them positive is positive
    definiteness. Needs no float preconditioner, so it decides matrices whose scales
    float64 cannot hold (a direction of :math:`10^{60}` beside one of 1) when the working
    precision can."""
    n = M.shape[0]
    a = M.value
    flint = _flint()
    L = [[flint.arb(0)] * n for _ in range(n)]
    for k in range(n):
        d = a[k, k] - sum((L[k][j] * L[k][j] for j in range(k)), flint.arb(0))
        if not d > 0:
            return False
        root = d.sqrt()
        L[k][k] = root
        for i in range(k + 1, n):
            L[i][k] = (a[i, k] - sum((L[i][j] * L[k][j] for j in range(k)), flint.arb(0))) / root
    return True


def proven_not_psd(M: Ball) -> bool:
    """``True`` only if some ``v`` has ``v' M v < 0`` for every matrix in the ball ``M``."""
    mid = midpoint(M)
    mid = 0.5 * (mid + mid.T)
    if not np.all(np.isfinite(mid)):
        return False
    w, V = np.linalg.eigh(mid)
    if w[0] >= 0:
        return False
    v = ball(V[:, :1])
    q = (v.T @ M @ v).value[0, 0]
    return bool(q < 0)


#: A ball solve's enclosure is accepted from plain interval LU when every radius is at most
#: this times the largest midpoint (below float64's half unit in the last place, 2**-53: a
#: float read off the enclosure moves by at most one unit in the last place).
LU_RADIUS = 2.0 ** -56


def tight_solve(G: Any, b: Any) -> Any:
    """``G^{-1} b`` enclosed by FLINT: first by interval LU (``algorithm="lu"``: about 4x
    faster than FLINT's default, which adds a preconditioned solve, at these sizes), kept
    when its radii are at most :data:`LU_RADIUS` relative to the largest entry; otherwise
    (LU's intervals grew, or a pivot contained zero) by the default algorithm. Either way
    a rigorous enclosure of the exact solution. ``None`` when FLINT cannot prove ``G``
    nonsingular. Call inside a precision block."""
    with contextlib.suppress(ZeroDivisionError, ValueError), deferred_signals():
        x = G.solve(b, algorithm="lu")
        entries = x.entries()
        top = max((float(abs(e.mid())) for e in entries), default=0.0)
        if all(e.is_finite() and float(e.rad()) <= LU_RADIUS * top for e in entries):
            return x
    try:
        with deferred_signals():  # a signal handled inside solve() came out as a ZeroDivisionError
            return G.solve(b)
    except (ZeroDivisionError, ValueError):
        return None
