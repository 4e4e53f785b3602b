r"""Output feedback that minimises the certified gamma itself: nonsmooth BFGS on the bounded-real level.

The objective is the quantity the core certifies for an output-feedback loop whose robust
gamma Lemma 4.1 does not certify: Theorem 3.2's nominal :math:`H_\infty` level over the
whole rate box,

.. math::

    f(\mathcal K) = \sqrt{g^\star(\mathcal K)}, \qquad
    g^\star = \min\{\, g : P_s \succeq 0,\; M_b(P, g; \mathcal K) \preceq 0
              \text{ for every block } b \,\},

with :math:`M_b` the block of :func:`~ftc_verify.analysis.lmi.lyapunov_block` (the bounded
real lemma of the joint chain's jump system, imposed at every vertex of the rates in its
generator row, :func:`~ftc_verify.analysis.lmi.block_specs`) and
:math:`A_s = \bar A_{0i} + \bar B_{0i}\mathcal K_j \bar C_i`
(:mod:`ftc_verify.analysis.closedloop`). For a fixed controller this is the coupled
bounded-real lemma, the LMI form of the coupled Riccati inequalities
:math:`A_s^T P_s + P_s A_s + \sum_t q_{st} P_t + C_s^T C_s + g^{-1} P_s B_s B_s^T P_s \prec 0`;
its optimum is the smallest level those certify on the box. It is one convex program in
:math:`(P, g)`, compiled once with the controller blocks as parameters (cvxpy DPP) and
re-solved for each controller.

**Gradient** (derived here). With duals :math:`Z_b \succeq 0` of the blocks, the
Lagrangian is :math:`g + \sum_b \langle Z_b, M_b\rangle - \ldots`; where the optimum is
unique and strictly complementary, the envelope theorem gives
:math:`dg^\star = \sum_b \langle Z_b, \partial M_b\rangle`. Only the top-left block
:math:`A_s^T P_s + P_s A_s` of :math:`M_b` depends on :math:`\mathcal K`, and
:math:`\langle Z, dA^T P + P\,dA\rangle = 2 \operatorname{tr}(Z P\, dA)`, so with
:math:`Z_b^{11}` the top-left part of :math:`Z_b` (state ``s`` of block ``b``)

.. math::

    \nabla_{A_s} g^\star = 2 \sum_{b \ni s} P_s Z_b^{11}, \qquad
    \nabla_{\mathcal K_j} g^\star = \sum_{s = (i, j, p)} \bar B_{0i}^T\, \nabla_{A_s} g^\star\, \bar C_i^T,
    \qquad \nabla f = \nabla g^\star / (2 f).

:math:`f` is nonsmooth where the optimal duals are not unique (several active vertices,
a multiple worst direction), smooth almost everywhere elsewhere: the setting of Lewis and
Overton's BFGS with a weak Wolfe line search, which HIFOO uses for fixed-order
:math:`H_\infty` design. :func:`minimise_gamma` runs
:func:`~ftc_verify.synthesis.descent.bfgs` from several starts (the certified
controllers of the other routes and seeded perturbations of the best one), each block
scaled back onto :math:`\|\mathcal K_j\|_2 \le k_{max}` after every trial step; a
controller whose program is infeasible (not stabilising on the box) has
:math:`f = \infty`, which the line search treats as too long a step.

Nothing here certifies: the caller hands the answer to the core analysis.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ..analysis.closedloop import closed_loop
from ..analysis.lmi import block_specs, lyapunov_block
from ..claimtext import upper_text
from ..controllers.controller import Controller
from ..limits import cpu_clock
from ..model.system import FTCSystem, Matrix
from .descent import Parametrisation, bfgs
from .results import SolverCalls

__all__ = ["HINF_SECONDS", "PERTURBED_STARTS", "FIRST_SHARE", "RESTART_RTOL", "NominalGamma", "minimise_gamma", "hinf_route",
           "within_bound"]

#: CPU seconds (:func:`~ftc_verify.limits.cpu_clock`) after which :func:`minimise_gamma` begins no new start.
HINF_SECONDS = 40.0
#: Seeded perturbations of the best start added to the starts.
PERTURBED_STARTS = 2
#: Share of the budget the first (best) start may use; the others split the rest.
FIRST_SHARE = 0.6
#: A BFGS restart that gains less than this (relative) ends the descent from a start.
RESTART_RTOL = 1e-3


class NominalGamma:
    """``f(theta)`` and its gradient (module docstring) for the controllers of order
    ``order`` of ``system``; ``calls`` logs every solve."""

    def __init__(self, system: FTCSystem, order: int, calls: SolverCalls) -> None:
        import cvxpy as cp

        self.par = Parametrisation.build(system, order)
        self.calls = calls
        r, c = self.par.shape
        self.K = [cp.Parameter((r, c)) for _ in range(system.m)]
        zero = self.par.controller(np.zeros(self.par.size), "probe")
        loop = closed_loop(system, zero).nominal()
        chain = system.chain
        A = tuple(self.par.A0[i] + self.par.B0[i] @ self.K[j] @ self.par.Cbar[i] for i, j in chain.joint_modes)
        loop = replace(loop, A=A)
        n = loop.n
        self.P = [cp.Variable((n, n), symmetric=True) for _ in range(chain.n_states)]
        self.g = cp.Variable(nonneg=True)
        self.specs = block_specs(loop)
        self.blocks = []
        for spec in self.specs:
            M = lyapunov_block(loop, spec, self.P, None, self.g, cp.bmat)
            self.blocks.append(0.5 * (M + M.T) << 0)
        self.problem = cp.Problem(cp.Minimize(self.g), self.blocks + [p >> 0 for p in self.P])
        self.n = n

    def __call__(self, theta: Matrix) -> tuple[float, Matrix]:
        """``(f, grad f)``; ``(inf, 0)`` when the program gives no point."""
        for Kp, Kj in zip(self.K, self.par.blocks(theta)):
            Kp.value = Kj
        out = self.calls.run(self.problem)
        g = self.g.value
        if not out.solved or g is None or not math.isfinite(float(g)) or float(g) <= 0:
            return math.inf, np.zeros(self.par.size)
        f = math.sqrt(float(g))
        r, c = self.par.shape
        grad = np.zeros((self.par.system.m, r, c))
        for spec, con in zip(self.specs, self.blocks):
            Z = con.dual_value
            P = self.P[spec.s].value
            if Z is None or P is None:
                return math.inf, np.zeros(self.par.size)
            gA = 2.0 * np.asarray(P) @ np.asarray(Z)[:self.n, :self.n]
            grad[spec.fdi] += self.par.B0[spec.true].T @ gA @ self.par.Cbar[spec.true].T
        return f, grad.ravel() / (2.0 * f)


def within_bound(controller: Controller, k_max: float | None) -> bool:
    """Every block ``[[Ac_j, Bc_j], [Cc_j, Dc_j]]`` of ``controller`` has spectral norm at
    most ``k_max`` (a start the descent can use as it is; always true without a bound)."""
    if k_max is None:
        return True
    return all(float(np.linalg.norm(np.block([[a, b], [c, d]]), 2)) <= k_max
               for a, b, c, d in zip(controller.Ac, controller.Bc, controller.Cc, controller.Dc))


def _tangent(par: Parametrisation, theta: Matrix, fg: tuple[float, Matrix], k_max: float | None,
             ) -> tuple[float, Matrix]:
    r"""``(f, g)`` with, for every block on the gain bound, the part of ``g`` along the
    bound's outward normal removed when ``-g`` points outward: the normal of
    :math:`\|K\|_2` at a simple top singular value is :math:`u_1 v_1^T`, and
    :math:`\langle g_j, u_1 v_1^T\rangle < 0` means a descent step leaves the ball (then
    undone by the projection, so the search would stall on the bound)."""
    f, g = fg
    if k_max is None or not math.isfinite(f):
        return f, g
    blocks, grads = par.blocks(theta), par.blocks(g)
    out = []
    for K, G in zip(blocks, grads):
        U, sv, Vt = np.linalg.svd(K)
        if sv[0] >= k_max * (1.0 - 1e-9):
            normal = np.outer(U[:, 0], Vt[0])
            slope = float(np.sum(G * normal))
            if slope < 0:
                G = G - slope * normal
        out.append(G)
    return f, par.theta(out)


def _tangent_of(par: Parametrisation, fun: _Watched, k_max: float | None, theta: Matrix) -> tuple[float, Matrix]:
    """:func:`_tangent` of ``fun(theta)``."""
    return _tangent(par, theta, fun(theta), k_max)


def _bounded(par: Parametrisation, theta: Matrix, k_max: float | None) -> Matrix:
    """Each block scaled back onto ``||K_j||_2 <= k_max``."""
    if k_max is None:
        return theta
    out = []
    for K in par.blocks(theta):
        norm = float(np.linalg.norm(K, 2))
        out.append(K * (k_max / norm) if norm > k_max else K)
    return par.theta(out)


class _Watched:
    """``fun`` with a deadline (after it every value is ``inf``, which ends
    :func:`~ftc_verify.synthesis.descent.bfgs` at its next line search) and the best
    finite point evaluated so far."""

    def __init__(self, fun: NominalGamma, deadline: float) -> None:
        self.fun, self.deadline = fun, deadline
        self.best: tuple[float, Matrix] = (math.inf, np.zeros(0))

    def __call__(self, theta: Matrix) -> tuple[float, Matrix]:
        if cpu_clock() > self.deadline:
            return math.inf, np.zeros(theta.size)
        f, g = self.fun(theta)
        if f < self.best[0]:
            self.best = (f, np.array(theta, dtype=float))
        return f, g


def minimise_gamma(system: FTCSystem, order: int, starts: Sequence[tuple[str, Matrix]], calls: SolverCalls, *,
                   k_max: float | None = None, seed: int = 0, max_iter: int = 300,
                   budget_seconds: float | None = None) -> list[dict[str, Any]]:
    """BFGS on :class:`NominalGamma` from each start (``(name, theta)``, best first) and from
    :data:`PERTURBED_STARTS` perturbations (relative size 1e-3) of the first one drawn from
    ``numpy.random.default_rng(seed)``. From each start BFGS is restarted (a fresh
    inverse Hessian) where its line search ended, until a restart gains less than
    :data:`RESTART_RTOL` relative or its share of ``budget_seconds`` (CPU seconds,
    :func:`~ftc_verify.limits.cpu_clock`, so that a loaded machine does not cut the descent short) is spent (the first
    start :data:`FIRST_SHARE`, each later one an equal part of what is left; its best point
    kept; ``None``: :data:`HINF_SECONDS` as the module holds it when called). Returns one row per start: ``name``, ``theta``, ``gamma`` (the program's value,
    not certified; ``inf`` when none), ``start_gamma``, ``seconds`` (wall); best first."""
    if not starts:
        return []
    fun = NominalGamma(system, order, calls)
    par = fun.par
    rng = np.random.default_rng(seed)
    first = np.asarray(starts[0][1], dtype=float)
    every = list(starts) + [(f"{starts[0][0]} perturbed {k} (seed {seed})",
                             first * (1.0 + 1e-3 * rng.standard_normal(first.size))) for k in range(PERTURBED_STARTS)]
    rows: list[dict[str, Any]] = []
    deadline = cpu_clock() + (HINF_SECONDS if budget_seconds is None else budget_seconds)
    for k, (name, theta) in enumerate(every):
        t0, wall0 = cpu_clock(), time.perf_counter()
        if rows and t0 > deadline:
            break
        share = FIRST_SHARE if k == 0 and len(every) > 1 else 1.0 / (len(every) - k)
        watched = _Watched(fun, t0 + share * (deadline - t0))
        x = _bounded(par, np.asarray(theta, dtype=float), k_max)
        f0, _ = watched(x)
        f = f0
        while math.isfinite(f):
            x, _, _ = bfgs(functools.partial(_tangent_of, par, watched, k_max), x, target=-math.inf,
                           max_iter=max_iter, project=lambda z: _bounded(par, z, k_max))
            x = watched.best[1]
            if watched.best[0] > f * (1.0 - RESTART_RTOL):
                break
            f = watched.best[0]
        rows.append({"name": name, "theta": watched.best[1] if math.isfinite(watched.best[0]) else x,
                     "gamma": float(watched.best[0]), "start_gamma": float(f0), "seconds": time.perf_counter() - wall0})
    return sorted(rows, key=lambda r: r["gamma"])


def hinf_route(system: FTCSystem, order: int, starts: Sequence[tuple[str, Controller]], calls: SolverCalls,
               solver: str, *, k_max: float | None = None, seed: int = 0, budget_seconds: float | None = None,
               ) -> tuple[Controller | None, Any, list[float], str, list[dict[str, Any]]]:
    """The ``hinf`` route: :func:`minimise_gamma` from the certified controllers ``starts``
    (order ``order``, best first), then the core analysis of each answer, best first, until
    one is certified (``budget_seconds``: :func:`minimise_gamma`'s). Returns ``(controller, report, history, message, rows)``; ``history``
    is ``[start's certified gamma, certified gamma]``."""
    from .descent import accepted_gamma
    from .of_blocks import controller_blocks
    from .results import verify_controller

    par = Parametrisation.build(system, order)
    usable = [(name, par.theta(controller_blocks(c))) for name, c in starts if c.n_c == order]
    if not usable:
        return None, None, [], f"hinf: no certified start of order {order}", []
    found = minimise_gamma(system, order, usable, calls, k_max=k_max, seed=seed, budget_seconds=budget_seconds)
    public = [{"name": f"hinf from {r['name']}", "gamma_certified": None, "spectral_abscissa": None,
               "note": f"order {order}, bounded-real level {r['start_gamma']:.6g} -> {r['gamma']:.6g}",
               "reason": "" if math.isfinite(r["gamma"]) else "start not feasible in the bounded-real program",
               "seconds": r["seconds"]} for r in found]
    for row, r in zip(public, found):
        if not math.isfinite(r["gamma"]):
            continue
        ctrl = par.controller(r["theta"], f"{system.name} hinf (order {order})")
        report = verify_controller(system, ctrl, solver)
        calls.outcomes.extend(a for res in (report.nominal, report.robust, report.mes_lmi) for a in res.attempts)
        gamma = accepted_gamma(report, True)
        row["gamma_certified"], row["spectral_abscissa"] = gamma, report.mss.spectral_abscissa
        if gamma is not None:
            for later in public:
                if later is not row and not later["reason"]:
                    later["reason"] = "not sent to the core analysis (a lower level was certified)"
            return ctrl, report, [r["start_gamma"], gamma], (
                f"hinf (order {order}): BFGS on the bounded-real level from {r['name']}, "
                f"{r['start_gamma']:.6g} -> {r['gamma']:.6g}; certified "
                f"{'robust' if report.robust.certified else 'nominal (Lemma 4.1 not certified)'} gamma {upper_text(gamma)}"), public
        row["reason"] = "not certified by the core analysis"
    return None, None, [], "hinf: no answer certified by the core analysis", public
