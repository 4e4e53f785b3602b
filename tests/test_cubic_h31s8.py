"""The cubic clock certificate (:mod:`ftc_verify.analysis.moments.sampled_cubic`) checked
independently of the code that builds and proves it: the flow condition written out
from its definition against the Gram blocks the proof checks, the jump and node
conditions in float, a real cover (:func:`~ftc_verify.analysis.moments.sampled_cover.cover_h_max`)
whose period the independent sub-box proof confirms, and a real half-box certificate."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_clock import frame_scale, time_unit
from ftc_verify.analysis.moments.sampled_conditioned import conditioned
from ftc_verify.analysis.moments.sampled_cover import cover_h_max
from ftc_verify.analysis.moments.sampled_cubic import CubicCertificate, box_specs, cubic_stable, piece_blocks
from ftc_verify.analysis.moments.sampled_proof import box_verdict
from ftc_verify.controllers.files import load_controller
from ftc_verify.model.files import load_system

ROOT = Path(__file__).resolve().parents[1]
PAPER_UNSTABLE = 0.0843  # above the paper loop's float64 crossing 0.08426 (h31c)
TS = (0.0, 0.13, 0.37, 0.5, 0.71, 0.94, 1.0)


def _paper() -> SampledLoop:
    return conditioned(SampledLoop.build(load_system(ROOT / "examples" / "paper.toml"),
                                         load_controller(ROOT / "examples" / "paper_gains.toml")))


def _flow_condition(A: np.ndarray, Yk: list[np.ndarray], Yk1: list[np.ndarray], C: list[np.ndarray],
                    W: list[np.ndarray], s: int, q: np.ndarray, delta: float, t: float) -> np.ndarray:
    """``F_s(t)`` from its definition, written out here: ``dY_s/dtau + A^T Y_s + Y_s A +
    sum_{r != s} q_sr (Y_r - Y_s)`` at ``tau = tau_k + t delta`` for ``Y_r(t) = Y_r^k + t
    (Y_r^{k+1} - Y_r^k) + t (1 - t) C_r + t^2 (1 - t) W_r``."""
    Y = [a + t * (b - a) + t * (1 - t) * c + t * t * (1 - t) * w for a, b, c, w in zip(Yk, Yk1, C, W)]
    dY = (Yk1[s] - Yk[s] + (1 - 2 * t) * C[s] + (2 * t - 3 * t * t) * W[s]) / delta
    out = dY + A.T @ Y[s] + Y[s] @ A
    for r, v in enumerate(q):
        if r != s:
            out = out + float(v) * (Y[r] - Y[s])
    return np.asarray(out)


def _check_identity(loop: SampledLoop, cert: CubicCertificate) -> float:
    """The largest relative mismatch of ``-F(t)`` (written out) against ``t sigma_1(t) +
    (1 - t) sigma_2(t)`` from the blocks the proof checks, over every piece, row vertex
    and ``t`` of :data:`TS`; asserts on the way that every block is positive definite
    and ``-F(t)`` too (float), every node, and the jump ``J^T Y(0) J < Y(h)``."""
    unit, D = time_unit(loop), frame_scale(loop, cert.h)
    frame = D[:, None] * D[None, :]  # the program's frame: Y' = D Y D, A' = unit D^-1 A D
    nodes = [[y * frame for y in row] for row in cert.nodes]
    curvs = [[y * frame for y in row] for row in cert.curvatures]
    cubics = [[y * frame for y in row] for row in cert.cubics]
    delta = cert.h / (cert.pieces * unit)
    worst = 0.0
    for i, (s, point) in enumerate(box_specs(loop, cert.lo, cert.hi)):
        A = loop.flow[s] * unit / D[:, None] * D[None, :]
        q = np.asarray(loop.chain.row_generator(s, point), dtype=float) * unit
        for k in range(cert.pieces):
            M2, M1 = (np.block(M) for M in piece_blocks(A, nodes[k], nodes[k + 1], curvs[k], cubics[k], s, list(q),
                                                         1.0 / delta, cert.grams[k][i]))
            assert np.linalg.eigvalsh(0.5 * (M1 + M1.T))[0] > 0 and np.linalg.eigvalsh(0.5 * (M2 + M2.T))[0] > 0
            d = len(A)
            for t in TS:
                V = np.vstack([np.eye(d), t * np.eye(d)])
                rhs = t * (V.T @ M1 @ V) + (1 - t) * (V.T @ M2 @ V)
                P = -_flow_condition(A, nodes[k], nodes[k + 1], curvs[k], cubics[k], s, q, delta, t)
                assert np.linalg.eigvalsh(0.5 * (P + P.T))[0] > 0
                worst = max(worst, float(np.abs(P - rhs).max() / np.abs(P).max()))
    for row in cert.nodes:
        for y in row:
            assert np.linalg.eigvalsh(y)[0] > 0
    P = loop.restriction()
    for s, R in enumerate(loop.resets(cert.h)):
        J = R @ P
        assert np.linalg.eigvalsh(cert.nodes[-1][s] - J.T @ cert.nodes[0][s] @ J)[0] > 0
    return worst


def test_found_certificate_satisfies_its_identity_written_out() -> None:
    """``-F(t) = t sigma_1(t) + (1 - t) sigma_2(t)`` to float rounding at seven ``t`` in
    ``[0, 1]`` on every piece and row vertex, ``F`` written out from the flow condition
    (not from :func:`~ftc_verify.analysis.moments.sampled_cubic.cubic_parts`); a
    mismatch of ``0.5 t^3 C_2`` (the coefficient ``C_1 = P_3 + C_2`` halved in the
    code) is of the size of ``-F`` itself."""
    loop = _paper()
    cert = cubic_stable(loop, 0.08, 2)
    assert cert is not None and cert.proved and cert.pieces == 2
    assert _check_identity(loop, cert) < 1e-9


def test_half_box_certificate_proved() -> None:
    """A real certificate on the lower half of the box in every rate (the sub-boxes a
    cover makes), proved in ball arithmetic, close to the crossing (3e-3 below 0.0843),
    and its identity checked as above."""
    loop = _paper()
    lo, hi = loop.chain.rate_min.copy(), loop.chain.rate_max.copy()
    idx = list(loop.chain.rate_indices)
    hi[idx] = 0.5 * (lo[idx] + hi[idx])
    cert = cubic_stable(loop, PAPER_UNSTABLE * (1 - 3e-3), 2, lo, hi)
    assert cert is not None and cert.proved
    assert np.array_equal(cert.lo, lo) and np.array_equal(cert.hi, hi)
    assert _check_identity(loop, cert) < 1e-9


def test_real_cover_confirmed_by_the_sub_box_proof() -> None:
    """``cover_h_max`` with the real certificates from a 4 % bracket: the period it
    proves is closer to the unstable end than the bracket's stable end, and the sub-box
    proof (no clock certificate) confirms it stable there."""
    loop = _paper()
    hu = PAPER_UNSTABLE
    got = cover_h_max(loop, 0.96 * hu, hu, 60000, 1e-3)
    assert got.h_max is not None and 0.96 * hu < got.h_max < hu and got.boxes >= 1
    assert box_verdict(loop, got.h_max, max_boxes=64, max_seconds=float("inf")).verdict == "stable"
