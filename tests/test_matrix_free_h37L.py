"""The matrix-free spectral stage of large loops (issue 37 item 6): the warm-started
eigenpair and the first-order vertex ascent, on a loop small
enough for dense eigenvalues to be the reference (the large-loop route forced by
lowering ``DENSE_LIMIT``)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from box_systems import three_mode_loop

from ftc_verify.analysis.moments import stability
from ftc_verify.analysis.moments.matrix_free import (ASCENT_STEPS, MomentOperator, linearised_ascent,
                                                     matrix_free_eigenpair)
from ftc_verify.analysis.moments.stability import spectral_abscissa


def vertex_of(loop):
    chain = loop.chain

    def vertex(bits):
        b = np.zeros(chain.rate_shape)
        for idx, up in zip(chain.rate_indices, bits):
            b[idx] = chain.rate_max[idx] if up else chain.rate_min[idx]
        return b

    return vertex


def test_eigenpair_is_the_dense_abscissa_and_an_eigenvector_warm_start_or_not():
    loop = three_mode_loop().nominal()
    vertex = vertex_of(loop)
    first, last = vertex((False,) * 6), vertex((True,) * 6)
    mu, X = matrix_free_eigenpair(loop, first)
    assert X is not None and mu == pytest.approx(spectral_abscissa(loop, first), rel=1e-9)
    op = MomentOperator.build(loop, first)
    assert np.linalg.norm(op.apply(op.vec(X)) - mu * op.vec(X)) <= 1e-8 * np.linalg.norm(op.vec(X))
    assert min(np.linalg.eigvalsh(x)[0] for x in X) >= -1e-8  # the Perron eigenvector: PSD (trace 1)
    warm, _ = matrix_free_eigenpair(loop, last, start=X)
    assert warm == pytest.approx(spectral_abscissa(loop, last), rel=1e-9)


def test_linearised_ascent_values_are_dense_values_and_climb():
    loop = three_mode_loop().nominal()
    vertex = vertex_of(loop)
    widths = [float(loop.chain.rate_max[i] - loop.chain.rate_min[i]) for i in loop.chain.rate_indices]
    found = linearised_ascent(loop, vertex, widths)
    assert found is not None and 1 <= len(found) <= ASCENT_STEPS
    for bits, mu in found.items():
        assert mu == pytest.approx(spectral_abscissa(loop, vertex(bits)), rel=1e-9)
    every = {bits: spectral_abscissa(loop, vertex(bits)) for bits in itertools.product((False, True), repeat=6)}
    best = max(found.values())
    assert best >= every[(False,) * 6]
    assert best == pytest.approx(max(every.values()), rel=1e-9)  # this loop's worst vertex is found


def test_mean_square_stability_takes_the_ascent_above_the_dense_limit(monkeypatch):
    loop = three_mode_loop().nominal()
    dense = stability.mean_square_stability(loop)
    monkeypatch.setattr(stability, "DENSE_LIMIT", 50)
    large = stability.mean_square_stability(loop)
    assert large.verdict == dense.verdict == "stable"
    assert not large.exhaustive and large.vertices_evaluated <= ASCENT_STEPS
    assert large.spectral_abscissa <= dense.spectral_abscissa + 1e-9
    assert large.spectral_abscissa == pytest.approx(dense.spectral_abscissa, rel=1e-6)
