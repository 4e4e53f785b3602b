"""How large the analysis LMIs are: decision variables and the memory estimate checked
before any work, for the route that will run (the SDP of
:mod:`ftc_verify.analysis.lmi_analysis`, or the Riccati candidate of
:mod:`ftc_verify.analysis.bounded_real`)."""

from __future__ import annotations

from ..limits import check_memory
from .closedloop import ClosedLoop

__all__ = ["LMI_BYTES_PER_NONZERO", "BALL_BYTES", "RICCATI_FIRST_SIZE", "RICCATI_FIRST_STATES", "SDP_FALLBACK_LIMIT",
           "lmi_memory_estimate", "check_size", "riccati_memory_estimate", "check_lmi_memory", "decision_size",
           "sdp_fallback_refusal"]

#: Peak memory per estimated nonzero of the LMI data, cvxpy compile plus Clarabel solve
#: (measured: n = 30, m = 2 took +580 MB for 3.9e5 estimated nonzeros; n = 20, m = 3
#: +365 MB for 3.6e5).
LMI_BYTES_PER_NONZERO = 1600

#: Bytes of one ball (``arb``) entry in the memory estimate of the Riccati route, with
#: FLINT's bookkeeping (an allowance for a 128-bit midpoint, its radius and the headers).
BALL_BYTES = 128

#: ``route="auto"``: above this many decision variables the Riccati candidate comes first
#: (:doc:`/performance`: n = 16, m = 2, 545: SDP 1.1 s, candidate 1.35 s; n = 32, m = 2: 300 s, 3.4 s),
#: when the loop also has at least :data:`RICCATI_FIRST_STATES` states.
RICCATI_FIRST_SIZE = 800
#: ``route="auto"``: the Riccati candidates come first only from this many states on. The SDP's
#: cost grows with the block size (about ``n``), not with the number of joint states: random
#: n = 12, m = 4 with uncertainty (1,249 variables, seed 5321), in CPU seconds: Theorem 3.2 SDP
#: 1.5 s (26.605) against the candidate's 10.5 s (27.445); Lemma 4.1 SDP 11.1 s (28.144)
#: against 8.6 s (28.895); n = 16, m = 3 (seed 5331): Theorem 3.2 SDP 2.2 s (35.121) against
#: 8.3 s (35.279), Lemma 4.1 SDP 20.1 s (36.118) against 12.0 s (36.410).
RICCATI_FIRST_STATES = 20
#: ``route="auto"``: above this many decision variables an SDP is not started when the
#: Riccati candidate (or, for Theorem 3.1, the certified gammas' ``P``) gave no certificate
#: (:func:`sdp_fallback_refusal`). Measured SDP costs: n = 32, m = 2 (2,113 variables) 297 s
#: and 2.1 GB; random n = 48, m = 3 (10,585 variables, seed 5100) had not finished after
#: 10 min at 3.4 GB. The bound is on the problem's size, so the same input always takes the
#: same route: a refused fallback is reported as such ("no certificate"), never a hang.
SDP_FALLBACK_LIMIT = 2200


def lmi_memory_estimate(loop: ClosedLoop, *, robust: bool) -> float:
    """Bytes the LMI stage of ``loop`` needs: blocks x (block size)^2 x (variables per
    entry) nonzeros times :data:`LMI_BYTES_PER_NONZERO`."""
    n, modes = loop.n, len(loop.A)
    extra = max((sum(ch.E.shape[1] for ch in chans) if robust else 0) + Bw.shape[1] + Cz.shape[0]
                for chans, Bw, Cz in zip(loop.channels, loop.Bw, loop.Cz))
    blocks = sum(len(loop.chain.row_rate_points(s)) for s in range(loop.chain.n_states))
    return float(blocks * (n + extra) ** 2 * (2 * n + modes) * LMI_BYTES_PER_NONZERO)


def check_size(loop: ClosedLoop, robust: bool, condition: str) -> None:
    """:func:`~ftc_verify.limits.check_memory` of :func:`lmi_memory_estimate` for the ``condition``'s LMIs."""
    check_memory(lmi_memory_estimate(loop, robust=robust),
                 f"the {condition} LMIs of a loop with n = {loop.n} and {len(loop.A)} joint states",
                 hint="reduce the problem, or run the exact spectral test alone (analyze --no-lmi)")


def riccati_memory_estimate(loop: ClosedLoop) -> float:
    """Bytes the Riccati route of :func:`~ftc_verify.analysis.lmi_analysis.hinf_gamma` needs (no SDP): the GMRES Krylov
    basis of :func:`~ftc_verify.analysis.bounded_real.coupled_lyapunov` (61 stacks of
    ``modes`` dense ``n x n`` matrices, and as much again for the Schur forms and
    iterates) and the ball matrices of one LMI block of
    :func:`~ftc_verify.analysis.lmi.check_certificate` at a time (a few copies of
    ``(n + extra)^2`` balls of :data:`BALL_BYTES` each)."""
    n, modes = loop.n, len(loop.A)
    extra = max(Bw.shape[1] + Cz.shape[0] + sum(ch.E.shape[1] for ch in chans)
                for Bw, Cz, chans in zip(loop.Bw, loop.Cz, loop.channels))
    return float(2 * 61 * modes * n * n * 8 + 4 * (n + extra) ** 2 * BALL_BYTES)


def check_lmi_memory(loop: ClosedLoop) -> None:
    """Raise :class:`~ftc_verify.errors.MemoryLimitError` before any work when the largest
    LMI problem of :func:`~ftc_verify.analysis.analyze.analyze` would not fit in memory,
    estimated for the route that will run: above :data:`RICCATI_FIRST_SIZE` decision
    variables and from :data:`RICCATI_FIRST_STATES` states on both programs go by the Riccati candidates first (:func:`riccati_memory_estimate`,
    with the uncertainty channels' columns; the SDP fallback is checked by
    :func:`~ftc_verify.analysis.lmi_analysis.hinf_gamma` before it is built), otherwise by the SDP."""
    if decision_size(loop.nominal(), robust=False) > RICCATI_FIRST_SIZE and loop.n >= RICCATI_FIRST_STATES:
        check_memory(riccati_memory_estimate(loop),
                     f"the Riccati candidates of Theorem 3.2 and Lemma 4.1 for a loop with n = {loop.n} and "
                     f"{len(loop.A)} joint states",
                     hint="reduce the problem, or run the exact spectral test alone (analyze --no-lmi)")
        return
    check_size(loop, loop.uncertain, "Lemma 4.1" if loop.uncertain else "Theorem 3.2")


def sdp_fallback_refusal(loop: ClosedLoop, robust: bool, condition: str) -> str:
    """Why the ``condition``'s SDP of ``loop`` is not started as a fallback: ``""`` (it is)
    up to :data:`SDP_FALLBACK_LIMIT` decision variables, else the sentence the result's
    message carries (the size, the limit, how to run it anyway)."""
    size = decision_size(loop, robust=robust)
    if size <= SDP_FALLBACK_LIMIT:
        return ""
    return (f"; the {condition} SDP fallback was not started: {size:,} decision variables, above "
            f"SDP_FALLBACK_LIMIT = {SDP_FALLBACK_LIMIT:,} (minutes to hours and gigabytes at this size; "
            f"hinf_gamma(..., route='sdp') runs it)")


def decision_size(loop: ClosedLoop, *, robust: bool) -> int:
    """Number of scalar decision variables of the analysis LMIs (for solver choice)."""
    n = loop.n
    count = len(loop.A) * n * (n + 1) // 2 + 1
    if robust:
        count += sum(len(c) for c in loop.channels)
    return count
