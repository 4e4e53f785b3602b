r"""Instability of the sampled loop at a period so long that its one-period map
overflows float64.

At a long period an unstable loop's second moments grow by :math:`e^{\lambda h}` per
period (:math:`\lambda > 0` the growth rate of the moments with the input held): on the
paper's loop at :math:`h = 10^4` the entries of :math:`T` are near :math:`10^{8688}`,
and the float64 map of :mod:`ftc_verify.analysis.moments.sampled` is ``inf``
(:func:`~ftc_verify.analysis.moments.sampled.spectral_radius` returns ``inf``), so
neither its eigenvalues nor the proofs of
:mod:`~ftc_verify.analysis.moments.sampled_proof`, which start from a float64 map,
can be used.

**The map in Arb.** Arb's numbers have an unbounded exponent: the ball
:math:`\mathbf T \ni T = \mathcal P e^{\mathcal L h} \mathcal R` at one rate array is
formed exactly as in the proofs at ordinary periods
(:func:`~ftc_verify.analysis.moments.sampled_proof.ball_one_period_map`: the numbers
as written, the period as written, :math:`e^{\mathcal L h}` by Arb's
``arb_mat.exp`` -- Taylor series with a bounded remainder, then scaling and squaring)
once the float64 ball exponential overflows. Squaring :math:`s` times widens the
relative radii by a factor that grows like a power of :math:`h` (not like
:math:`e^{h}`, as stepping through the period would): at :math:`h = 10^4`, 64 bits
leave relative radii near :math:`10^{-18}`.

**Scaled into float range.** :math:`\mathbf T_e = 2^{-e} \mathbf T` is exact (a power
of two) and has the same eigenvectors; :math:`e` is chosen from the magnitude of the
largest entry and the float64 spectral radius :math:`\rho_e` of the scaled midpoint so
that :math:`\rho_e \in [2, 4)`. The Collatz-Wielandt argument of
:func:`~ftc_verify.analysis.moments.sampled_proof.prove_unstable` on
:math:`\mathbf T_e` (a positive semidefinite stack :math:`X \succ 0` with
:math:`\mathbf T_e(X) - X \succ 0` proved in ball arithmetic; :math:`T` and
:math:`T_e` map the cone of positive semidefinite stacks to itself) gives
:math:`\rho(T_e) > 1`, hence

.. math::

    \rho(T) = 2^{e} \rho(T_e) > 2^{e} \ge 1 \qquad (e \ge 0),

and the loop is not mean-square stable at that rate array -- for the numbers as
written. Only a point of the box is needed for instability, as at ordinary periods.

A period the user wrote is the ball of every decimal that reads as it (radius
:math:`10^{-12}` at :math:`10^4`); a dynamic controller's :math:`(\Phi_c, \Gamma_c)` is one
Arb exponential of that ball times :math:`[[A_c, B_c], [0, 0]]`
(:func:`~ftc_verify.analysis.moments.sampled_proof.ball_resets`), whose radius then grows
with :math:`\|A_c\| h`: the observer of ``paper_observer.toml`` at :math:`h = 10^4`
stays "undecided" (its map's radii :math:`10^{15}` times its entries; with the resets at
the exact float period the proof goes through at 128 bits, radii :math:`10^{-10}`).

**The stable side.** A loop whose map stays finite is decided by the ordinary proofs:
the float64 ball arithmetic of :mod:`~ftc_verify.analysis.moments.fast_balls` bounds
every underflow (its :math:`\eta` terms), so moments that underflow at a long period
cannot turn a proof wrong, only wider. A map that overflows while the loop is stable
(entries above :math:`10^{308}` with :math:`\rho(T) < 1`) is left ``undecided``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...model.system import Matrix
from ..rigorous import PRECISION_BITS, Ball, midpoint, precision
from .sampled import SampledLoop

__all__ = ["OverflowProof", "scaled_map", "prove_overflow_unstable", "overflow_verdict"]


@dataclass(frozen=True)
class OverflowProof:
    """A proved :math:`\\rho(T) > 2^{e}` at one rate array (module docstring).

    Attributes
    ----------
    exponent : int
        :math:`e \\ge 0`: the radius is proved above :math:`2^{e}`.
    log10_radius : float
        The float estimate of :math:`\\log_{10} \\rho(T)` (not proved; for the report).
    bits : int
        Arb's working precision of the proof.
    """

    exponent: int
    log10_radius: float
    bits: int

    @property
    def text(self) -> str:
        """The lower bound in words: ``2^e (about 10^k)``."""
        return f"2^{self.exponent} (about 1e{self.exponent * math.log10(2.0):.0f})"


def _log2_magnitude(T: Any) -> float | None:
    """:math:`\\log_2` of the largest entry magnitude of the Arb matrix ``T`` (float, an
    estimate), ``None`` when an entry is not finite or all are zero."""
    import flint

    top = flint.arb(0)
    for x in T.entries():
        if not x.is_finite():
            return None
        top = top.max(abs(x.mid()))
    if top.is_zero():
        return None
    return float((top.log() / flint.arb(2).log()).mid())


def scaled_map(T: Ball) -> tuple[Ball, Matrix, int] | None:
    """``(T_e, mid, e)``: :math:`2^{-e} \\mathbf T` (exact), its float64 midpoint, and
    :math:`e` with the float spectral radius of ``mid`` in :math:`[2, 4)`; ``None`` when
    :math:`\\mathbf T` has a non-finite entry or its scaled midpoint has no finite
    dominant eigenvalue."""
    import flint

    k = _log2_magnitude(T.value)
    if k is None or not math.isfinite(k):
        return None
    e = math.floor(k)
    for _ in range(2):  # the largest entry first, then the spectral radius of the scaled map
        Ts = Ball(T.value * flint.arb(2) ** (-e))
        mid = midpoint(Ts)
        if not np.all(np.isfinite(mid)):
            return None
        rho = float(np.max(np.abs(np.linalg.eigvals(mid))))
        if not (math.isfinite(rho) and rho > 0.0):
            return None
        shift = math.floor(math.log2(rho)) - 1
        if shift == 0:
            return Ts, mid, e
        e += shift
    return None


def prove_overflow_unstable(loop: SampledLoop, h: float, rates: Matrix) -> OverflowProof | None:
    """A proof that the sampled loop at period ``h`` is not mean-square stable at the rate
    array ``rates`` when its map overflows float64 (module docstring), at 64 bits, then
    at :data:`~ftc_verify.analysis.rigorous.PRECISION_BITS`; ``None`` when neither
    proves it (or :math:`e < 0`: not an overflow, the ordinary proofs apply)."""
    from .sampled_proof import ball_one_period_map, prove_unstable

    rates = np.asarray(rates, dtype=float)
    for bits in (64, PRECISION_BITS):
        with precision(bits):
            scaled = scaled_map(ball_one_period_map(loop, h, rates, rates))
            if scaled is None:
                continue
            Ts, mid, e = scaled
            if e < 0:
                return None
            if prove_unstable(Ts, mid, loop.states, loop.r):
                rho = float(np.max(np.abs(np.linalg.eigvals(mid))))
                return OverflowProof(e, e * math.log10(2.0) + math.log10(rho), bits)
    return None


def overflow_verdict(loop: SampledLoop, h: float, rates: Matrix) -> Any:
    """The :class:`~ftc_verify.analysis.moments.sampled_proof.BoxVerdict` ``"not stable"``
    at ``rates`` when :func:`prove_overflow_unstable` proves it, else ``None`` (the caller
    keeps its ``"undecided"``)."""
    from .sampled_proof import BoxVerdict

    proof = prove_overflow_unstable(loop, h, rates)
    if proof is None:
        return None
    return BoxVerdict("not stable", f"spectral radius > {proof.text} proved at {loop.chain.rate_text(rates)} "
                      f"(Arb ball arithmetic at {proof.bits} bits: the one-period map overflows float64)", 1,
                      np.asarray(rates, dtype=float))
