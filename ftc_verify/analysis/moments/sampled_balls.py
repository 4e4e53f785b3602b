"""Ball matrices for the sampled loop's proofs: the joint generator over a box of rates.

:func:`generator_coefficients` writes the generator of :mod:`ftc_verify.model.chain` as
``base + sum_r rate_r coef_r`` exactly; :func:`ball_generator` encloses it over a box of
rates, :func:`envelope_generator` is its upper envelope (off-diagonal entries at the top
of the box, the diagonal from the bottom: :mod:`ftc_verify.analysis.moments.sampled_proof`);
:func:`ball_kron` and :func:`ball_block_diag` assemble ball matrices.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...model.chain import JointChain
from ...model.system import Matrix
from ..exact import Literals
from ..rigorous import Ball

__all__ = ["generator_coefficients", "ball_generator", "envelope_generator", "ball_kron", "ball_block_diag",
           "as_float"]


def _flint() -> Any:
    import flint

    return flint


def generator_coefficients(chain: JointChain) -> tuple[Matrix, tuple[tuple[tuple[int, ...], Matrix], ...]]:
    """``(base, ((idx, coef), ...))``: :math:`Q(r) = base + \\sum_{idx} r_{idx}\\, coef_{idx}`
    exactly (:mod:`ftc_verify.model.chain`: the generator is affine in every rate).

    The coefficients are read from the generator of the same chain on the box ``[0, 1]``
    (at 0 and at each unit rate): their off-diagonal entries are integers (the number of
    phases, or 1), the diagonal minus their row sums -- exact in floating point. ``base``
    holds the off-diagonal entries at rate 0 (the fault rates ``alpha`` as written) and
    a zero diagonal (a ball row sum is formed where it is used)."""
    m = chain.m
    ones, zeros = np.ones((m, m)), np.zeros((m, m))
    fa = (zeros, ones) if chain.has_false_alarms else (None, None)
    wide = dataclasses.replace(chain, beta_min=zeros, beta_max=ones, false_alarm_min=fa[0], false_alarm_max=fa[1])
    base = wide.generator(np.zeros(chain.rate_shape))
    S = chain.n_states
    off = ~np.eye(S, dtype=bool)
    coefs = []
    for idx in chain.rate_indices:
        e = np.zeros(chain.rate_shape)
        e[idx] = 1.0
        coef = np.where(off, wide.generator(e) - base, 0.0)
        if not np.array_equal(coef, np.round(coef)):  # pragma: no cover - structure of chain.py
            raise AssertionError("generator coefficients are not integers")
        coef[np.diag_indices(S)] = -coef.sum(axis=1)
        coefs.append((idx, coef))
    return np.where(off, base, 0.0), tuple(coefs)


def _terms(chain: JointChain, lo: Matrix, hi: Matrix, literals: Literals | None) -> tuple[list[list[Any]], ...]:
    """Off-diagonal entries of the generator at the rates ``lo`` and ``hi`` as balls, from
    :meth:`~ftc_verify.model.chain.JointChain.generator_terms`: the fault rates
    ``alpha`` and the box's ends enclosed as written (:func:`ftc_verify.analysis.exact.enclose`:
    the decimal text of a number read from the system file; a rate the analysis chose,
    such as a sub-box's split point, exact)."""
    from ..exact import enclose

    flint = _flint()
    S = chain.n_states
    low = [[flint.arb(0) for _ in range(S)] for _ in range(S)]
    up = [[flint.arb(0) for _ in range(S)] for _ in range(S)]
    for s, t, coef, kind, index in chain.generator_terms():
        if kind == "alpha":
            a = float(chain.alpha[index])
            if a != 0.0:
                v = coef * enclose(a, literals)
                low[s][t] += v
                up[s][t] += v
        else:
            low[s][t] += coef * enclose(float(lo[index]), literals, computed_exact=True)
            up[s][t] += coef * enclose(float(hi[index]), literals, computed_exact=True)
    return low, up


def _assemble_generator(off: list[list[Any]], diag_from: list[list[Any]]) -> Ball:
    flint = _flint()
    S = len(off)
    out = flint.arb_mat(S, S)
    for s in range(S):
        total = flint.arb(0)
        for t in range(S):
            if t != s:
                out[s, t] = off[s][t]
                total += diag_from[s][t]
        out[s, s] = -total
    return Ball(out)


def ball_generator(chain: JointChain, lo: Matrix, hi: Matrix, literals: Literals | None = None) -> Ball:
    """The joint generator as a ball matrix containing :math:`Q(r)` for every rate array
    ``r`` with ``lo <= r <= hi`` (every entry is affine and non-decreasing in each rate:
    the union of its balls at both ends; the diagonal is minus the ball row sum, so every
    row sums to an enclosure of zero). ``literals``: the system file's numbers as
    written (``_terms``)."""
    low, up = _terms(chain, lo, hi, literals)
    S = chain.n_states
    both = [[low[s][t].union(up[s][t]) for t in range(S)] for s in range(S)]
    return _assemble_generator(both, both)


def envelope_generator(chain: JointChain, lo: Matrix, hi: Matrix, literals: Literals | None = None) -> Ball:
    """The upper envelope of the generator over ``[lo, hi]``: off-diagonal entries at
    the rates ``hi``, the diagonal minus the row sums at ``lo`` (a ball matrix; rows sum
    to at least 0). Used by ``envelope_stable`` (module docstring)."""
    low, up = _terms(chain, lo, hi, literals)
    return _assemble_generator(up, low)


def as_float(a: Any) -> Matrix:
    """``a`` as a float64 array."""
    return np.asarray(a, dtype=float)


def ball_kron(A: Ball, B: Ball) -> Ball:
    """Kronecker product of two ball matrices."""
    flint = _flint()
    (p, q), (r, t) = A.shape, B.shape
    a, b = A.value, B.value
    out = flint.arb_mat(p * r, q * t)
    for i in range(p):
        for j in range(q):
            aij = a[i, j]
            for k in range(r):
                for m in range(t):
                    out[i * r + k, j * t + m] = aij * b[k, m]
    return Ball(out)


def ball_block_diag(blocks: Sequence[Ball]) -> Ball:
    """The block-diagonal ball matrix of ``blocks``."""
    flint = _flint()
    rows = sum(b.shape[0] for b in blocks)
    cols = sum(b.shape[1] for b in blocks)
    out = flint.arb_mat(rows, cols)
    r0 = c0 = 0
    for b in blocks:
        v = b.value
        for i in range(b.shape[0]):
            for j in range(b.shape[1]):
                out[r0 + i, c0 + j] = v[i, j]
        r0 += b.shape[0]
        c0 += b.shape[1]
    return Ball(out)
