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


def ball_generator(chain: JointChain, lo: Matrix, hi: Matrix) -> Ball:
    """The joint generator as a ball matrix containing :math:`Q(r)` for every rate array
    ``r`` with ``lo <= r <= hi`` (:func:`generator_coefficients`; the diagonal is minus
    the ball row sum, so every row sums to an enclosure of zero)."""
    flint = _flint()
    base, coefs = generator_coefficients(chain)
    S = chain.n_states
    Q = [[flint.arb(float(base[s, t])) for t in range(S)] for s in range(S)]
    for idx, coef in coefs:
        rate = flint.arb(float(lo[idx])).union(flint.arb(float(hi[idx])))
        for s, t in zip(*np.nonzero(coef)):
            if s != t:
                Q[s][t] += int(coef[s, t]) * rate
    out = flint.arb_mat(S, S)
    for s in range(S):
        total = flint.arb(0)
        for t in range(S):
            if t != s:
                out[s, t] = Q[s][t]
                total += Q[s][t]
        out[s, s] = -total
    return Ball(out)


def envelope_generator(chain: JointChain, lo: Matrix, hi: Matrix) -> Ball:
    """The upper envelope of the generator over ``[lo, hi]``: off-diagonal entries at
    the rates ``hi``, the diagonal minus the row sums at ``lo`` (a ball matrix; rows sum
    to at least 0). Used by ``_envelope_stable`` (module docstring)."""
    flint = _flint()
    base, coefs = generator_coefficients(chain)
    S = chain.n_states
    upper = [[flint.arb(float(base[s, t])) for t in range(S)] for s in range(S)]
    lower = [[flint.arb(float(base[s, t])) for t in range(S)] for s in range(S)]
    for idx, coef in coefs:
        for s, t in zip(*np.nonzero(coef)):
            if s != t:
                upper[s][t] += int(coef[s, t]) * flint.arb(float(hi[idx]))
                lower[s][t] += int(coef[s, t]) * flint.arb(float(lo[idx]))
    out = flint.arb_mat(S, S)
    for s in range(S):
        total = flint.arb(0)
        for t in range(S):
            if t != s:
                out[s, t] = upper[s][t]
                total += lower[s][t]
        out[s, s] = -total
    return Ball(out)


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
