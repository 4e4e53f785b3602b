r"""A proved upper bound of the probability of ever leaving the safe envelope.

The envelope is given by constraints :math:`(H_{s,k})_s, L_k`: the loop leaves it when
:math:`|H_{s_t,k}\,\xi_t|_2 \ge L_k` for some :math:`t \ge 0` and some :math:`k`, with
:math:`\xi` the closed-loop state of :class:`~ftc_verify.analysis.closedloop.ClosedLoop`
and :math:`s_t` the joint (true, FDI, phase) state.

**The supermartingale.** Let :math:`V(\xi, s) = \xi^T P_s \xi` be a certificate of the
loop's :math:`H_\infty` LMI (Theorem 3.2, paper eq. (12); Lemma 4.1, eq. (16), for the
norm-bounded :math:`\Delta`), proved for every rate of the box
(:mod:`ftc_verify.analysis.lmi`): its block of state :math:`s` is negative definite, and
by the Schur complement this says, for every :math:`\xi, w`, every generator :math:`Q`
of the box and every :math:`\|\Delta\| \le 1` (also time-varying, since the inequality
holds pointwise),

.. math::

    \mathcal L V(\xi, s) + |z|^2 - g\,|w|^2
    = \xi^T\Bigl(A_{s,\Delta}^T P_s + P_s A_{s,\Delta} + \sum_{s'} q_{ss'} P_{s'}\Bigr)\xi
      + 2\,\xi^T P_s B_{w,s} w + |C_{z,s}\xi|^2 - g|w|^2 \le 0,
    \qquad g = \gamma^2 .

Let :math:`w` be any disturbance with :math:`\int_0^\infty |w|^2 \le E` (deterministic,
or adapted to the loop's past) and :math:`R_t = E - \int_0^t |w|^2 \ge 0` what is left of
that budget. Then :math:`M_t = V(\xi_t, s_t) + g R_t` has, by Dynkin's formula for the
piecewise-deterministic jump process :math:`(\xi_t, s_t)`, the drift
:math:`\mathcal L V - g|w_t|^2 \le -|z_t|^2 \le 0`: :math:`M` is a nonnegative local
supermartingale, hence (Fatou) a supermartingale. Ville's maximal inequality gives,
for every level :math:`c > 0`,

.. math::

    P\Bigl(\sup_{t \ge 0} V(\xi_t, s_t) \ge c\Bigr) \le P\Bigl(\sup_t M_t \ge c\Bigr)
    \le \frac{E[M_0]}{c} = \frac{\sum_s p_{0,s}\, x_0^T P_s x_0 + g E}{c},

with :math:`p_0` the initial distribution of the joint state. With :math:`E = 0` a
mean-square-stability certificate (Theorem 3.1, eq. (4): :math:`\mathcal L V \le 0`)
suffices on a nominal loop; on an uncertain loop Lemma 4.1's certificate is used (its
leading block is :math:`\mathcal L V` for every :math:`\Delta`).

**The level.** If :math:`P_s - H_{s,k}^T H_{s,k} / \mu_{s,k} \succ 0` then
:math:`|H_{s,k}\xi|^2 < \mu_{s,k} V(\xi, s)` for :math:`\xi \ne 0`, so leaving the envelope
implies :math:`V > L_k^2 / \mu_{s,k}`. The smallest such :math:`\mu` is
:math:`\lambda_{max}(H_{s,k} P_s^{-1} H_{s,k}^T)` (the largest value of :math:`|H\xi|^2` on
:math:`\{V \le 1\}`): the level set :math:`\{V < c\}`, :math:`c = \min_{s,k} L_k^2 /
\mu_{s,k}`, lies inside the envelope, and

.. math::

    P(\text{leave the envelope}) \le \frac{\sum_s p_{0,s}\, x_0^T P_s x_0 + g E}{c}.

The bound does not change when :math:`(P, g)` is scaled, and is invariant under a
change of state coordinates (with :math:`H` and :math:`x_0` transformed alike).

**Which P.** Two candidates, the smaller proved bound is kept: the certificate the
analysis proves (:func:`~ftc_verify.analysis.lmi_analysis.hinf_gamma`,
:func:`~ftc_verify.analysis.lmi_analysis.mes_lmi`: the smallest certified :math:`\gamma`,
resp. a mean-square certificate, or one passed in), and the answer of a semidefinite
program over the same LMI blocks that minimises the bound itself (``_optimised``): with
the level normalised, :math:`[[P_s, H^T], [H, \kappa L^2 I]] \succeq 0` (so
:math:`c \ge 1/\kappa`), minimise :math:`\sum_s p_{0,s} x_0^T P_s x_0 + g E`, linear in
:math:`(P, \lambda, g)`. The :math:`|z|^2` term of the :math:`H_\infty` block is not
needed by the argument; the small :math:`\kappa` makes :math:`P` large, so it costs
little. The loop must be certified by the analysis first.

**The proof.** The certificate is proved again on ``loop`` by
:func:`~ftc_verify.analysis.lmi.check_certificate` (every block at every vertex of the
rate box and every :math:`P_s`, in ball arithmetic); :math:`P_s` is formed from the
conditioned answer exactly as there; each :math:`\mu_{s,k}` is a float rounded up until
:math:`P_s - H^T H/\mu \succ 0` is proved
(:func:`~ftc_verify.analysis.rigorous.proven_positive_definite`); :math:`x_0^T P_s x_0`,
the level and the quotient are balls, and the reported value is the quotient's upper end
rounded up to a float. No bound is returned (``value`` ``None`` with the reason) when the
certificate is not proved, when the loop that runs is sampled (a controller ``period``:
the continuous-time certificate does not cover the sampled loop) or when the bound is
not below 1.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..analysis.closedloop import ClosedLoop
from ..analysis.conditioning import conditioning_transform
from ..analysis.conic import Rows, affine_bmat, scalar_variable, svec_index, sym_variable, unit_rows
from ..analysis.lmi import block_specs, check_certificate, lyapunov_block
from ..analysis.lmi_analysis import LMIResult, hinf_gamma, mes_lmi
from ..analysis.solvers import solve_conic
from ..analysis.rigorous import ball, precision, proven_positive_definite
from ..errors import FTCError, ValidationError
from ..model.system import Matrix

__all__ = ["UpperBound", "envelope_upper_bound"]

#: Relative steps by which a float :math:`\lambda_{max}` is raised until the level is proved.
LEVEL_STEPS = (1e-10, 1e-6, 1e-3, 1e-1)
#: Normalisation of the level in the bound-minimising program (``_optimised``).
OPTIMISE_KAPPA = 1e-4
#: Margin of its blocks (in the conditioned coordinates, with ``P`` of order ``1/kappa``).
OPTIMISE_MARGIN = 1e-6
#: Largest program (variables x blocks x block entries) the bound is optimised on.
OPTIMISE_ENTRIES = 5e7


@dataclass(frozen=True)
class UpperBound:
    """A proved upper bound of the probability of ever leaving the envelope
    (:func:`envelope_upper_bound`).

    Attributes
    ----------
    value : float or None
        The bound (module docstring), or ``None`` when no sound bound below 1 was
        produced (``reason`` says why).
    reason : str
        Why ``value`` is ``None``, or what the bound rests on.
    level : float or None
        A proved lower end of the level :math:`c` whose set :math:`\\{V < c\\}` lies
        inside the envelope.
    start : float or None
        A proved upper end of :math:`E[V(x_0, s_0)]`.
    gamma : float or None
        The :math:`\\gamma` of the certificate used (:math:`g = \\gamma^2` multiplies the
        energy); ``None`` for a Theorem 3.1 certificate. When :math:`P` was chosen to
        minimise the bound, :math:`(P, \\gamma^2)` carry the program's scale (module
        docstring), so this is not the loop's attenuation level.
    disturbance_energy : float
        :math:`E`, the bound on :math:`\\int |w|^2`.
    condition : str
        The certificate's LMI (``theorem-3.1``, ``theorem-3.2``, ``lemma-4.1``; empty
        when none was proved).
    solver : str
        The solver that produced the candidate certificate.
    tolerance : float
        Relative width of the ball of the bound (its upper end is ``value``).
    proof : str
        What was proved, in ball arithmetic.
    """

    value: float | None
    reason: str
    level: float | None = None
    start: float | None = None
    gamma: float | None = None
    disturbance_energy: float = 0.0
    condition: str = ""
    solver: str = ""
    tolerance: float = math.inf
    proof: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``upper_bound`` of the risk report)."""
        return {"value": self.value, "reason": self.reason, "level": self.level, "start": self.start,
                "gamma": self.gamma, "disturbance_energy": self.disturbance_energy, "condition": self.condition,
                "solver": self.solver, "tolerance": None if math.isinf(self.tolerance) else self.tolerance,
                "proof": self.proof}


def _finite_matrix(value: Any, name: str, cols: int) -> Matrix:
    try:
        M = np.atleast_2d(np.asarray(value, dtype=float))
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected a real matrix, got {type(value).__name__}") from None
    if M.ndim != 2 or M.shape[1] != cols or not np.all(np.isfinite(M)):
        raise ValidationError(f"{name}: expected a finite matrix with {cols} columns (the loop's states), "
                              f"got shape {M.shape}")
    return M


def _checked_constraints(loop: ClosedLoop, constraints: Sequence[tuple[Sequence[Any], float]]
                         ) -> list[tuple[list[Matrix], float]]:
    """``(H_s per joint state, L)`` validated (ValidationError naming the entry)."""
    out = []
    if len(constraints) == 0:
        raise ValidationError("constraints: at least one (H, limit) pair is needed")
    for k, item in enumerate(constraints):
        try:
            Hs, limit = item
        except (TypeError, ValueError):
            raise ValidationError(f"constraints[{k}]: expected a pair (H per joint state, limit)") from None
        if len(Hs) != loop.chain.n_states:
            raise ValidationError(f"constraints[{k}]: expected one H per joint state ({loop.chain.n_states}), "
                                  f"got {len(Hs)}")
        if isinstance(limit, bool) or not isinstance(limit, (int, float, np.floating)) or not (
                math.isfinite(limit) and limit > 0):
            raise ValidationError(f"constraints[{k}]: the limit must be a finite number > 0, got {limit!r}")
        out.append(([_finite_matrix(H, f"constraints[{k}] H[{s}]", loop.n) for s, H in enumerate(Hs)],
                    float(limit)))
    return out


def _checked_start(loop: ClosedLoop, x0: Any, energy: float, initial: Sequence[float] | None,
                   start: tuple[int, int]) -> tuple[Matrix, float, Matrix]:
    """``(x0, E, p0)`` validated; an ``x0`` of the plant's states gets a zero controller state."""
    x = np.asarray(x0, dtype=float).reshape(-1)
    n_plant = loop.n if loop.n_plant is None else loop.n_plant
    if x.size == n_plant and n_plant < loop.n:
        x = np.concatenate([x, np.zeros(loop.n - n_plant)])
    if x.size != loop.n or not np.all(np.isfinite(x)):
        raise ValidationError(f"x0: expected {loop.n} finite numbers (the loop's state) or {n_plant} (the "
                              f"plant's), got {np.asarray(x0).tolist()}")
    if isinstance(energy, bool) or not isinstance(energy, (int, float, np.floating)) or not (
            math.isfinite(energy) and energy >= 0):
        raise ValidationError(f"disturbance_energy: expected a finite number >= 0, got {energy!r}")
    if initial is None:
        p0 = np.zeros(loop.chain.n_states)
        p0[loop.chain.start_state(start)] = 1.0
    else:
        p0 = np.asarray(initial, dtype=float).reshape(-1)
        if p0.size != loop.chain.n_states or np.any(~np.isfinite(p0)) or np.any(p0 < 0) or p0.sum() > 1 + 1e-12:
            raise ValidationError(f"initial: expected {loop.chain.n_states} probabilities (one per joint state) "
                                  f"summing to 1, got {p0.tolist()}")
    return x, float(energy), p0


def _certificate(loop: ClosedLoop, energy: float, given: LMIResult | None,
                 solver: str | None) -> LMIResult:
    """The analysis' certificate for the bound (module docstring, "Which P")."""
    wanted = {"lemma-4.1"} if loop.uncertain else (
        {"theorem-3.2", "lemma-4.1"} if energy > 0 else {"theorem-3.1", "theorem-3.2", "lemma-4.1"})
    if given is not None and given.condition in wanted and given.certified:
        return given
    if loop.uncertain:
        return hinf_gamma(loop, robust=True, solver=solver)
    if energy > 0:
        return hinf_gamma(loop, robust=False, solver=solver)
    return mes_lmi(loop, solver=solver)


def _optimised(loop: ClosedLoop, checked: list[tuple[list[Matrix], float]], x: Matrix, energy: float,
               p0: Matrix, condition: str) -> LMIResult | None:
    r"""A candidate certificate of ``condition`` chosen to minimise the bound (module
    docstring, "Which P"): on the conditioned loop, the blocks of
    :func:`~ftc_verify.analysis.lmi.lyapunov_block` (on the conic variables of
    :mod:`~ftc_verify.analysis.conic`) with a margin, :math:`P_s \succeq` margin,
    :math:`\lambda, g \ge 0` and the level normalised, :math:`[[P_s, H^T], [H, \kappa L^2
    I]] \succeq 0` (so :math:`L^2/\lambda_{max}(H P_s^{-1} H^T) \ge 1/\kappa`), minimising
    :math:`\sum_s p_{0,s} x_0^T P_s x_0 + g E`. :math:`\kappa = 10^{-4}` makes
    :math:`P` large, so the :math:`|z|^2` term of the :math:`H_\infty` block (not needed
    by the supermartingale) costs little. ``None`` when the program is too large or not
    solved; the answer is proved like any other (:func:`_proved`)."""
    robust = condition == "lemma-4.1"
    target = loop if robust else loop.nominal()
    sim = conditioning_transform(target)
    cl = sim.apply(target)
    n, S = cl.n, cl.chain.n_states
    per_p = n * (n + 1) // 2
    lam_at = np.cumsum([0] + [len(c) if robust else 0 for c in cl.channels]) + S * per_p
    gi = int(lam_at[-1])
    K = gi + (0 if condition == "theorem-3.1" else 1)
    specs = block_specs(cl)
    if K * max(len(specs), 1) * (n + 8) ** 2 > OPTIMISE_ENTRIES:
        return None
    P = [sym_variable(n, s * per_p, K) for s in range(S)]
    lam = [[scalar_variable(int(lam_at[s]) + k, K) for k in range(int(lam_at[s + 1] - lam_at[s]))] for s in range(S)]
    g = None if condition == "theorem-3.1" else scalar_variable(gi, K)
    rows, every = Rows(K), np.arange(K).astype(int)
    for spec in specs:
        M = lyapunov_block(cl, spec, P, lam[spec.s] if robust else None, g, affine_bmat)
        rows.lmi(M + OPTIMISE_MARGIN * np.eye(M.shape[0]), every)
    for s in range(S):
        rows.lmi(-P[s] + OPTIMISE_MARGIN * np.eye(n), every)
    for Hs, limit in checked:
        for s, H in enumerate(Hs):
            if np.any(H):
                Ht = H @ sim.T
                rows.lmi(-affine_bmat([[P[s], Ht.T], [Ht, OPTIMISE_KAPPA * limit ** 2 * np.eye(H.shape[0])]]), every)
    if gi < K or robust:
        rows.nonneg(unit_rows(K, range(S * per_p, K)), np.zeros(K - S * per_p))
    xc = (sim.T_inv @ x)[None, :]
    cost = sum(float(p) * (xc @ P[s] @ xc.T).lin[0, 0] for s, p in enumerate(p0) if p > 0)
    c = np.zeros(K) + np.asarray(cost, dtype=float)
    if gi < K:
        c[gi] += energy
    outcome, sol = solve_conic(rows.problem(c), "clarabel")
    if sol is None:
        return None
    r, cidx, w = svec_index(n)
    Pv = []
    for s in range(S):
        M = np.zeros((n, n))
        M[r, cidx] = sol[s * per_p:(s + 1) * per_p] / w
        M[cidx, r] = M[r, cidx]
        Pv.append(M)
    lv = tuple(tuple(float(v) for v in sol[int(lam_at[s]):int(lam_at[s + 1])]) for s in range(S)) if robust else None
    gamma = None if gi >= K else math.sqrt(max(float(sol[gi]), 0.0))
    return LMIResult(condition, "candidate", gamma, "clarabel", outcome.status, 0.0, outcome.seconds, None,
                     tuple(sim.lyapunov_back(p) for p in Pv), lv, "P chosen to minimise the bound",
                     similarity=sim, P_conditioned=tuple(Pv))


def _proved(loop: ClosedLoop, result: LMIResult) -> tuple[bool, str, list[Matrix], Any, float | None]:
    """Prove ``result`` again on ``loop``: ``(ok, note, P conditioned, similarity, g)``."""
    if result.P is None:
        return False, result.message or f"no certificate ({result.outcome})", [], None, None
    P = list(result.P if result.P_conditioned is None else result.P_conditioned)
    sim = result.similarity if result.P_conditioned is not None else None
    g = None if result.condition == "theorem-3.1" or result.gamma is None else float(result.gamma) ** 2
    target = loop.nominal() if result.condition != "lemma-4.1" else loop
    lam = result.multipliers if result.condition == "lemma-4.1" else None
    cert = check_certificate(target, result.condition, P, lam, g, similarity=sim)
    return cert.ok, cert.proved if cert.ok else cert.reason, [0.5 * (p + p.T) for p in P], sim, g


def _level(Pb: Any, Pc: Matrix, T: Matrix, H: Matrix, limit: float) -> Any:
    """A ball whose lower end bounds the level ``L^2 / mu`` of one ``(s, k)`` from below
    (``None`` when ``H = 0``: never reached; ``False`` when no ``mu`` was proved)."""
    import flint

    if not np.any(H):
        return None
    HT = H @ T  # H P^-1 H' = (H T) Pc^-1 (H T)'
    mu = float(np.linalg.eigvalsh(HT @ np.linalg.solve(Pc, HT.T))[-1])
    if not (math.isfinite(mu) and mu > 0):
        return False
    Hb = ball(H)
    G = Hb.T @ Hb
    for step in LEVEL_STEPS:
        mu_up = mu * (1.0 + step) + 1e-300
        if proven_positive_definite(Pb - G * (1 / flint.arb(mu_up)), T):
            return flint.arb(limit) ** 2 / flint.arb(mu_up)
    return False


def _fail(reason: str, energy: float, result: LMIResult | None = None) -> UpperBound:
    return UpperBound(None, reason, disturbance_energy=energy,
                      condition="" if result is None else result.condition,
                      solver="" if result is None else result.solver)


def _unsampled(loop: ClosedLoop, period: float | None) -> str:
    """Why the continuous certificate does not cover the loop that runs ('' when it does)."""
    own = None if loop.source is None else getattr(loop.source[1], "period", None)
    h = period if period is not None else own
    if h is None:
        return ""
    return (f"the loop that runs is sampled (period {h:g}): the continuous-time certificate does not cover "
            "the sampled-data loop, so no bound is claimed")


def envelope_upper_bound(
    loop: ClosedLoop,
    constraints: Sequence[tuple[Sequence[Any], float]],
    *,
    x0: Any,
    disturbance_energy: float,
    initial: Sequence[float] | None = None,
    start: tuple[int, int] = (0, 0),
    period: float | None = None,
    certificate: LMIResult | None = None,
    solver: str | None = None,
) -> UpperBound:
    r"""A proved upper bound of :math:`P(|H_{s_t,k}\xi_t|_2 \ge L_k` for some
    :math:`t \ge 0`, some :math:`k)` (module docstring), sound for every rate of the box.

    Parameters
    ----------
    loop : ClosedLoop
        The continuous-time closed loop (:func:`~ftc_verify.analysis.closedloop.closed_loop`).
    constraints : sequence of (sequence of arrays, float)
        Per constraint, ``H_s`` for every joint state (``r x n`` each) and the limit
        :math:`L > 0`.
    x0 : array
        Initial state: ``loop.n`` numbers, or the plant's ``n_plant`` (zero controller state).
    disturbance_energy : float
        :math:`E \ge 0`, a bound on :math:`\int_0^\infty |w|^2 dt` (0: no disturbance).
    initial : sequence of float, optional
        Initial distribution of the joint state (one probability per state of
        ``loop.chain.states``); default: the state ``start`` (true, fdi), 0-based.
    start : (int, int)
        The initial joint mode when ``initial`` is not given (default ``(0, 0)``).
    period : float, optional
        The controller's sampling period when the loop runs sampled (also read from the
        loop's controller): then no bound is claimed.
    certificate : LMIResult, optional
        A certified analysis answer of this loop to use (it is proved again); default: the
        analysis is run.
    solver : str, optional
        Solver for the analysis (default: the analysis' order).

    Returns
    -------
    UpperBound
        ``value`` the bound, or ``None`` with ``reason``.

    Raises
    ------
    ValidationError
        A constraint, ``x0``, ``disturbance_energy`` or ``initial`` is malformed (naming it).
    """
    checked = _checked_constraints(loop, constraints)
    x, energy, p0 = _checked_start(loop, x0, disturbance_energy, initial, start)
    why = _unsampled(loop, period)
    if why:
        return _fail(why, energy)
    try:
        result = _certificate(loop, energy, certificate, solver)
    except FTCError as exc:
        return _fail(f"the analysis produced no certificate: {exc}", energy)
    first = _attempt(loop, checked, x, energy, p0, result)
    if first.value is None and first.reason.startswith("the loop is not certified"):
        return first
    try:
        candidate = _optimised(loop, checked, x, energy, p0, result.condition)
    except FTCError:
        candidate = None
    if candidate is None:
        return first
    second = _attempt(loop, checked, x, energy, p0, candidate)
    if second.value is not None and (first.value is None or second.value < first.value):
        return second
    return first


def _attempt(loop: ClosedLoop, checked: list[tuple[list[Matrix], float]], x: Matrix, energy: float, p0: Matrix,
             result: LMIResult) -> UpperBound:
    """The bound from one candidate certificate, after proving it (:func:`_proved`)."""
    ok, note, Pc, sim, g = _proved(loop, result)
    if not ok:
        return _fail(f"the loop is not certified ({result.condition}: {note}); no bound is claimed", energy, result)
    if energy > 0 and g is None:
        return _fail("a disturbance needs an H-infinity certificate; only Theorem 3.1 was given", energy, result)
    return _bound(loop, checked, x, energy, p0, result, Pc, sim, g, note)


def _bound(loop: ClosedLoop, checked: list[tuple[list[Matrix], float]], x: Matrix, energy: float, p0: Matrix,
           result: LMIResult, Pc: list[Matrix], sim: Any, g: float | None, note: str) -> UpperBound:
    """The quotient of the module docstring in ball arithmetic, from a proved certificate."""
    import flint

    T = np.eye(loop.n) if sim is None else sim.T
    S_inv = np.eye(loop.n) if sim is None else sim.T_inv
    gamma = None if g is None else math.sqrt(g)
    with precision():
        S = ball(S_inv)
        Pb = [S.T @ ball(p) @ S for p in Pc]  # the certificate check_certificate proved
        xb = ball(x.reshape(-1, 1))
        v0 = flint.arb(0)
        for s, p in enumerate(p0):
            if p > 0:
                v0 += flint.arb(float(p)) * (xb.T @ Pb[s] @ xb).value[0, 0]
        level: Any = None
        for Hs, limit in checked:
            for s, H in enumerate(Hs):
                c = _level(Pb[s], Pc[s], T, H, limit)
                if c is False:
                    return _fail(f"the level of constraint H[{s}] was not proved", energy, result)
                if c is not None:
                    level = c if level is None else level.min(c)
        if level is None:
            return UpperBound(0.0, "every H is zero: the envelope cannot be left", None, float(v0.upper()), gamma,
                              energy, result.condition, result.solver, 0.0, note)
        num = v0 + (flint.arb(g) * flint.arb(energy) if g is not None and energy > 0 else flint.arb(0))
        quotient = num / flint.arb(float(np.nextafter(float(level.lower()), -math.inf)))
        value = float(np.nextafter(float(quotient.upper()), math.inf))
        width = float(quotient.rad()) / max(float(quotient.mid()), 1e-300)
    c_low = float(np.nextafter(float(level.lower()), -math.inf))
    v_up = float(np.nextafter(float(v0.upper()), math.inf))
    if not value < 1.0:
        return UpperBound(None, f"the bound {value:.6g} is not below 1 (start value {v_up:.6g}, level {c_low:.6g}):"
                          " no information", c_low, v_up, gamma, energy, result.condition, result.solver, width, note)
    how = "P chosen to minimise the bound" if result.outcome == "candidate" else "the analysis' P"
    basis = ("Ville's inequality on V + gamma^2 (remaining energy), V of the certified "
             f"{result.condition} answer ({how}), over the rate box, for the continuous-time controller")
    return UpperBound(value, basis, c_low, v_up, gamma, energy, result.condition, result.solver, width, note)
