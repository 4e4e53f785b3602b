r"""Stabilising output feedback of any order by nonsmooth descent on the exact stability test.

The controller of FDI mode :math:`j` has order :math:`n_c` (0 is static output feedback)
and the blocks :math:`\mathcal K_j = [[A_{c,j}, B_{c,j}], [C_{c,j}, D_{c,j}]]`; for true
mode :math:`i` the closed loop is :math:`A_s = \bar A_{0i} + \bar B_{0i}\mathcal K_j \bar C_i`
(:mod:`ftc_verify.analysis.closedloop`, :func:`~ftc_verify.analysis.closedloop.barred`).
The objective is the worst-vertex spectral abscissa of the second-moment generator

.. math::

    f(\mathcal K) = \max_{\beta \in \text{vertices}} \mu(\beta), \qquad
    \mu = \max \operatorname{Re} \lambda(\mathcal L), \quad
    \mathcal L = \operatorname{blockdiag}_s\bigl(L_n (I \otimes A_s + A_s \otimes I) D_n\bigr)
                 + Q(\beta)^T \otimes I,

nonsmooth where the active eigenvalue is multiple, smooth almost everywhere. Its gradient
(derived here) at a simple active eigenvalue :math:`\lambda` with right and left
eigenvectors :math:`v`, :math:`u` (:math:`u^H \mathcal L = \lambda u^H`) is
:math:`d\lambda = u^H d\mathcal L\, v / (u^H v)`. With :math:`V_s = \operatorname{vec}^{-1}
(D_n v_s)` and :math:`U_s = \operatorname{vec}^{-1}(L_n^T u_s)` (the parts of the mode
:math:`s`), :math:`u_s^H L_n (I\otimes dA + dA\otimes I) D_n v_s = \operatorname{tr}(U_s^H
(dA\,V_s + V_s\,dA^T))`, so

.. math::

    \nabla_{A_s}\mu = \operatorname{Re}\frac{\bar U_s V_s^T + U_s^H V_s}{u^H v}, \qquad
    \nabla_{\mathcal K_j}\mu = \sum_{s = (i, j, p)} \bar B_{0i}^T \,\nabla_{A_s}\mu\, \bar C_i^T ,

the sum over every joint state of FDI mode :math:`j` (every true mode :math:`i` and, with
the phase-type delays of :mod:`ftc_verify.model.chain`, every phase :math:`p`: the
phases share the matrix :math:`A_{(i,j)}`, so their gradients add up).

The minimisation is BFGS with a weak Wolfe line search, the method Lewis and Overton
showed to work on such nonsmooth functions (and HIFOO uses for fixed-order
:math:`H_\infty`): the inverse-Hessian update stays positive definite when the curvature
:math:`s^T y > 0`, and the line search (bisection and doubling) needs only the Armijo
decrease :math:`f(x + t d) \le f(x) + c_1 t\, g^T d` and the weak Wolfe condition
:math:`g(x + t d)^T d \ge c_2\, g^T d`. The gain bound :math:`\|\mathcal K_j\|_2 \le k_{max}`
is kept by scaling each block back onto the ball after every trial step.

**Continuation in the detection rates.** Faster detection makes the FDI lag shorter, so
a loop is easier to stabilise with every ``beta`` multiplied by :math:`\kappa > 1`. The
descent runs at :math:`\kappa` = :data:`KAPPAS` in turn (8, 4, 2, 1.4, 1), each solution
starting the next, and stops at each level once the abscissa is below ``-margin``.

Nothing here certifies: the descent only proposes a controller, which the caller hands
to the core analysis (the verified verdict and the certified gammas).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg

from ..analysis.closedloop import barred
from ..analysis.moments.stability import duplication_matrix, second_moment_matrix
from ..claimtext import upper_text
from ..controllers.controller import Controller
from ..errors import ValidationError
from ..jsonable import OMIT, fields_dict
from ..limits import cpu_clock
from ..model.system import FTCSystem, JointChain, Matrix
from .results import SolverCalls, verify_controller
from .rightmost import rightmost
import itertools

__all__ = ["rate_scale", "BUDGET_SECONDS", "TUNING_SECONDS", "DESIGNED_STARTS", "KAPPAS", "LEVELS", "GAIN_SCAN", "Parametrisation", "abscissa", "abscissa_gradient", "worst_abscissa", "bfgs",
           "DescentResult", "stabilise", "deepen", "gain_scan", "unbounded_gain_diagnosis", "descent_route",
           "accepted_gamma"]

#: Detection-rate multipliers of the continuation, in order (the last is the true box).
KAPPAS = (8.0, 4.0, 2.0, 1.4, 1.0)
#: Abscissa levels of the tuning ladder (:func:`deepen`), in units of the plant's rate
#: scale ``1 + max |eig(A_i)|``.
LEVELS = (-0.05, -0.1, -0.2, -0.4, -0.8, -1.6)
#: Gain bounds of the diagnosis scan (:func:`gain_scan`).
GAIN_SCAN = (1e1, 1e2, 1e3, 1e4)
#: CPU seconds (:func:`~ftc_verify.limits.cpu_clock`) after which :func:`stabilise` begins no new start.
BUDGET_SECONDS = 30.0
#: CPU seconds after which the descent route begins no new tuning level and no P-K alternation.
TUNING_SECONDS = 60.0
#: Designed starts (observer controllers) tried at most, the most stable first.
DESIGNED_STARTS = 2


@dataclass(frozen=True, eq=False)
class Parametrisation:
    """The controllers of order ``n_c`` for ``system``, as vectors ``theta`` (the blocks
    ``K_j`` of the FDI modes, row-major, concatenated)."""

    system: FTCSystem
    n_c: int
    A0: tuple[Matrix, ...]
    B0: tuple[Matrix, ...]
    Cbar: tuple[Matrix, ...]

    @classmethod
    def build(cls, system: FTCSystem, n_c: int) -> Parametrisation:
        """Barred matrices of every true mode for a controller of order ``n_c``."""
        if n_c < 0:
            raise ValidationError(f"order: must be >= 0, got {n_c}")
        bars = [barred(md, md.measured, n_c) for md in system.modes]
        return cls(system, n_c, tuple(b.A0bar for b in bars), tuple(b.B0bar for b in bars),
                   tuple(b.Cbar for b in bars))

    @property
    def shape(self) -> tuple[int, int]:
        """Shape of each block ``K_j``: ``(n_c + nu, n_c + ny)``."""
        return self.B0[0].shape[1], self.Cbar[0].shape[0]

    @property
    def size(self) -> int:
        """Length of ``theta``."""
        r, c = self.shape
        return self.system.m * r * c

    def blocks(self, theta: Matrix) -> list[Matrix]:
        """``theta`` -> the ``m`` blocks ``K_j``."""
        r, c = self.shape
        return [np.asarray(b) for b in np.asarray(theta, dtype=float).reshape(self.system.m, r, c)]

    def theta(self, blocks: Sequence[Matrix]) -> Matrix:
        """The blocks -> ``theta``."""
        return np.concatenate([np.asarray(K, dtype=float).ravel() for K in blocks])

    def loop_matrices(self, theta: Matrix) -> list[Matrix]:
        """``A_s`` for every joint state ``s`` of the system's chain (pair ``(i, j)``; the
        phases of a pair repeat its matrix)."""
        K = self.blocks(theta)
        pair = {(i, j): self.A0[i] + self.B0[i] @ K[j] @ self.Cbar[i] for i, j in set(self.system.chain.joint_modes)}
        return [pair[ij] for ij in self.system.chain.joint_modes]

    def controller(self, theta: Matrix, name: str) -> Controller:
        """The dynamic controller of ``theta``."""
        nc = self.n_c
        K = self.blocks(theta)
        return Controller.dynamic([k[:nc, :nc] for k in K], [k[:nc, nc:] for k in K], [k[nc:, :nc] for k in K],
                                  [k[nc:, nc:] for k in K], name=name)


@functools.lru_cache(maxsize=16)
def _duplication(n: int) -> tuple[Matrix, Matrix]:
    """:func:`~ftc_verify.analysis.moments.stability.duplication_matrix` of ``n``, built
    once per size (read-only arrays: every gradient of a descent asks for the same one)."""
    D, L = duplication_matrix(n)
    D.flags.writeable = False
    L.flags.writeable = False
    return D, L


def abscissa(A: Sequence[Matrix], Q: Matrix) -> float:
    """``mu`` of :func:`abscissa_gradient` without the eigenvectors: LAPACK's ``geev``
    without them (about half the work at the descent's sizes). The eigenvalues are the
    same numbers bit for bit (the QR iteration on the active block does not depend on
    whether the Schur vectors are accumulated; checked on 7200 generators of the
    examples' loops), so a vertex chosen by this value is the one
    :func:`abscissa_gradient` would choose."""
    G = second_moment_matrix(A, Q)
    found = rightmost(G, False)
    if found is None:
        return float(scipy.linalg.eigvals(G, check_finite=False).real.max())
    return found[0]


def abscissa_gradient(A: Sequence[Matrix], Q: Matrix) -> tuple[float, list[Matrix]]:
    """``(mu, [grad_A_s mu])`` of the second-moment generator of the matrices ``A`` and
    the generator ``Q`` (module docstring); the gradient at the rightmost eigenvalue."""
    n = A[0].shape[0]
    D, L = _duplication(n)
    G = second_moment_matrix(A, Q)
    found = rightmost(G, True)
    if found is None:
        vals, vl, vr = scipy.linalg.eig(G, left=True, right=True, check_finite=False)
        k = int(np.argmax(vals.real))
        found = (float(vals[k].real), vl[:, k], vr[:, k])
    mu, u, v = found
    assert u is not None and v is not None
    w = np.vdot(u, v)
    h = D.shape[1]
    grads = []
    for s in range(len(A)):
        V = (D @ v[s * h:(s + 1) * h]).reshape(n, n, order="F")
        U = (L.T @ u[s * h:(s + 1) * h]).reshape(n, n, order="F")
        grads.append(np.real((np.conj(U) @ V.T + U.conj().T @ V) / w) if w != 0 else np.zeros((n, n)))
    return mu, grads


def worst_abscissa(par: Parametrisation, chain: JointChain, theta: Matrix,
                   vertices: Sequence[int] | None = None,
                   generators: Sequence[Matrix] | None = None) -> tuple[float, Matrix]:
    """``(f, grad f)``: the worst abscissa over the vertices of ``chain``'s rate box
    (or over the vertex indices ``vertices`` of :meth:`JointChain.vertices`) and its
    gradient in ``theta`` (module docstring; the sum over :math:`i` there runs over every
    joint state of FDI mode :math:`j`, all phases). ``chain`` has the joint states of
    ``par.system.chain`` (the continuation only scales its rates). ``generators``: the
    generators :meth:`JointChain.generator` of every vertex, when already computed (a
    BFGS run asks for the same ones at every evaluation)."""
    A = par.loop_matrices(theta)
    Q = generators if generators is not None else [chain.generator(b) for b in chain.vertices()]
    ks = list(range(len(Q)) if vertices is None else vertices)
    if len(ks) > 1:  # the worst vertex by eigenvalues alone; eigenvectors only there (the same vertex, first of equals)
        worst: tuple[int, float] | None = None
        for k in ks:
            mu = abscissa(A, Q[k])
            if worst is None or mu > worst[1]:
                worst = (k, mu)
        assert worst is not None
        ks = [worst[0]]
    mu, grads = abscissa_gradient(A, Q[ks[0]])
    r, c = par.shape
    gK = np.zeros((par.system.m, r, c))
    for s, (i, j) in enumerate(chain.joint_modes):  # every state of the pair (i, j): its phases
        gK[j] += par.B0[i].T @ grads[s] @ par.Cbar[i].T
    return mu, gK.ravel()


def _minimise(par: Parametrisation, chain: JointChain, x0: Matrix, *, target: float, max_iter: int,
              project: Any) -> tuple[Matrix, float, int]:
    """:func:`bfgs` on the worst abscissa over an active set of vertices: the set starts
    with the worst vertex at ``x0``; after each run every vertex is evaluated, and a
    vertex worse than the set's maximum joins it and the run continues (so the answer is
    the maximum over all vertices, at a fraction of the cost when the box has many)."""
    generators = [chain.generator(b) for b in chain.vertices()]  # the same at every evaluation

    def values(x: Matrix) -> list[float]:
        A = par.loop_matrices(x)
        return [abscissa(A, Q) for Q in generators]

    x = project(np.asarray(x0, dtype=float))
    every = values(x)
    active = {int(np.argmax(every))}
    evals = len(every)
    for _ in range(2 * len(every)):
        x, f, e = bfgs(lambda z: worst_abscissa(par, chain, z, sorted(active), generators), x, target=target,
                       max_iter=max_iter, project=project)
        every = values(x)
        evals += e * len(active) + len(every)
        worst = int(np.argmax(every))
        if every[worst] <= f + 1e-12 * max(1.0, abs(f)) or worst in active:
            return x, float(max(every)), evals
        active.add(worst)
    return x, float(max(every)), evals


def _project(par: Parametrisation, theta: Matrix, k_max: float | None) -> Matrix:
    """Each block scaled back onto ``||K_j||_2 <= k_max``."""
    if k_max is None:
        return theta
    out = []
    for K in par.blocks(theta):
        norm = np.linalg.norm(K, 2)
        out.append(K * (k_max / norm) if norm > k_max else K)
    return par.theta(out)


def bfgs(fun: Callable[[Matrix], tuple[float, Matrix]], x0: Matrix, *, target: float, max_iter: int = 200,
         project: Callable[[Matrix], Matrix] = lambda x: x,
         c1: float = 1e-4, c2: float = 0.9) -> tuple[Matrix, float, int]:
    """Minimise ``fun(x) -> (f, g)`` by BFGS with a weak Wolfe line search (module
    docstring) until ``f < target``; returns ``(x, f, evaluations)``."""
    x = project(np.asarray(x0, dtype=float))
    f, g = fun(x)
    evals = 1
    H = np.eye(x.size)
    for _ in range(max_iter):
        if f < target or not np.all(np.isfinite(g)) or np.linalg.norm(g) == 0:
            break
        d = -H @ g
        slope = float(g @ d)
        if slope >= 0:  # not a descent direction: restart from steepest descent
            H = np.eye(x.size)
            d, slope = -g, -float(g @ g)
        lo, hi, t = 0.0, np.inf, 1.0
        accepted = None
        for _ in range(40):
            xt = project(x + t * d)
            ft, gt = fun(xt)
            evals += 1
            if not np.isfinite(ft) or ft > f + c1 * t * slope:
                hi = t
            elif float(gt @ d) < c2 * slope:
                lo = t
                accepted = (xt, ft, gt)  # sufficient decrease already: keep the best so far
            else:
                accepted = (xt, ft, gt)
                break
            t = 0.5 * (lo + hi) if np.isfinite(hi) else 2.0 * lo
        if accepted is None:
            break
        xn, fn, gn = accepted
        s, y = xn - x, gn - g
        sy = float(s @ y)
        if sy > 1e-12 * np.linalg.norm(s) * np.linalg.norm(y):
            rho = 1.0 / sy
            I = np.eye(x.size)
            H = (I - rho * np.outer(s, y)) @ H @ (I - rho * np.outer(y, s)) + rho * np.outer(s, s)
        x, f, g = xn, fn, gn
    return x, f, evals


@dataclass(frozen=True)
class DescentResult:
    """What :func:`stabilise` reached from one start."""

    start: str
    order: int
    theta: Matrix = field(metadata=OMIT)
    abscissa: float
    gain_norm: float
    stabilised: bool
    history: tuple[tuple[float, float], ...] = field(default=())
    evaluations: int = 0
    seconds: float = 0.0

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary: the fields, ``theta`` omitted."""
        return fields_dict(self)


def _scaled_chain(chain: JointChain, kappa: float) -> JointChain:
    """``chain`` with every detection rate times ``kappa`` (mean delays divided by it; the
    phases, false-alarm rates and variant kept)."""
    return dataclasses.replace(chain, beta_min=kappa * chain.beta_min, beta_max=kappa * chain.beta_max)


def stabilise(system: FTCSystem, order: int, *, starts: Sequence[tuple[str, Matrix]] = (), seed: int = 0,
              random_starts: int = 2, k_max: float | None = None, margin: float = 1e-2,
              kappas: Sequence[float] = KAPPAS, max_iter: int = 100,
              budget_seconds: float = BUDGET_SECONDS) -> list[DescentResult]:
    """Descents from the starts in turn -- the zero controller, ``random_starts`` drawn from
    ``numpy.random.default_rng(seed)``, then the given ``(name, theta)`` ones (designed
    controllers, whose gains tend to be large) -- each through the
    continuation ``kappas`` (module docstring); sorted, best (lowest abscissa at the true
    rates) first. A start stops at the true rates once its abscissa is below ``-margin``;
    no new start begins after ``budget_seconds`` CPU seconds (the first always runs)."""
    par = Parametrisation.build(system, order)
    rng = np.random.default_rng(seed)
    scale = 1.0 / np.sqrt(max(1, par.shape[0] * par.shape[1]))
    all_starts = [("zero", np.zeros(par.size))]
    all_starts += [(f"random {k} (seed {seed})", scale * rng.standard_normal(par.size)) for k in range(random_starts)]
    all_starts += list(starts)  # last: designed starts (observers) tend to have large gains
    project = lambda x: _project(par, x, k_max)  # noqa: E731
    out: list[DescentResult] = []
    deadline = cpu_clock() + budget_seconds
    for name, theta in all_starts:
        if out and cpu_clock() > deadline:
            break
        t0 = time.perf_counter()
        x = np.asarray(theta, dtype=float)
        history, evals = [], 0
        f = np.inf
        for kappa in kappas:
            chain = _scaled_chain(system.chain, kappa)
            x, f, e = _minimise(par, chain, x, target=-margin, max_iter=max_iter, project=project)
            evals += e
            history.append((float(kappa), float(f)))
        gain = max(float(np.linalg.norm(K, 2)) for K in par.blocks(x))
        out.append(DescentResult(name, order, x, float(f), gain, bool(f < -margin), tuple(history), evals,
                                 time.perf_counter() - t0))
        if f < -margin:
            break
    return sorted(out, key=lambda r: r.abscissa)


def rate_scale(system: FTCSystem) -> float:
    """``1 + max_i max |eig(A_i)|``: the unit of the tuning ladder's abscissa levels."""
    return 1.0 + max(float(np.max(np.abs(np.linalg.eigvals(md.A)))) for md in system.modes)


def deepen(system: FTCSystem, order: int, theta: Matrix, level: float, *, k_max: float | None = None,
           max_iter: int = 150) -> tuple[Matrix, float]:
    """Continue the descent at the true rates from ``theta`` until the abscissa is below
    ``level`` (or no further progress); ``(theta, abscissa)``. The tuning ladder of
    :func:`~ftc_verify.synthesis.output_feedback.synthesize_output_feedback` calls it at
    each of :data:`LEVELS` and has every result certified by the core analysis."""
    par = Parametrisation.build(system, order)
    x, f, _ = _minimise(par, system.chain, theta, target=level, max_iter=max_iter,
                        project=lambda z: _project(par, z, k_max))
    return x, float(f)


def gain_scan(system: FTCSystem, order: int, *, seed: int = 0, bounds: Sequence[float] = GAIN_SCAN,
              max_iter: int = 150) -> list[tuple[float, float]]:
    """The best abscissa reached under each gain bound of ``bounds`` (each descent starting
    from the previous one's answer, at the true rates): ``[(k_max, abscissa)]``. An
    abscissa that stays positive while falling towards 0 as the bound grows says the exact
    test approaches 0 only with unbounded gains."""
    par = Parametrisation.build(system, order)
    x = 0.1 * np.random.default_rng(seed).standard_normal(par.size)
    out = []
    for bound in bounds:
        x, f, _ = _minimise(par, system.chain, x, target=-np.inf, max_iter=max_iter,
                            project=lambda z, b=bound: _project(par, z, b))
        out.append((float(bound), float(f)))
    return out


def unbounded_gain_diagnosis(system: FTCSystem, order: int, found: Sequence[DescentResult], *,
                             seed: int = 0) -> dict[str, Any]:
    """Why the descent found nothing: the best abscissa and the gain norm where it was
    reached, and :func:`gain_scan`. When the scan's abscissa falls as the bound grows
    and stays positive, the exact test approaches 0 only with unbounded gains (if at all):
    measuring more outputs or detecting faster is what helps, not a larger bound."""
    best = min(found, key=lambda r: r.abscissa)
    scan = gain_scan(system, order, seed=seed)
    values = [f for _, f in scan]
    falling = all(b <= a + 1e-9 for a, b in itertools.pairwise(values)) and values[-1] < values[0]
    text = (f"no controller of order <= {order} found: best abscissa {best.abscissa:.4g} at gain norm "
            f"{best.gain_norm:.3g} (from {best.start}); best abscissa under gain bounds "
            + ", ".join(f"{k:g}: {f:.3g}" for k, f in scan))
    if falling and values[-1] > 0:
        text += ("; it falls as the bound grows and stays positive: the exact test approaches 0 only with "
                 "unbounded gains, if at all -- measure more outputs or detect faster")
    return {"order": order, "best_abscissa": best.abscissa, "best_gain_norm": best.gain_norm,
            "gain_scan": [list(p) for p in scan], "unbounded_gains_only": bool(falling and values[-1] > 0),
            "message": text}


def descent_route(system: FTCSystem, order: int, rows: list[dict[str, Any]], k_max: float | None, solver: str,
                   calls: SolverCalls, seed: int) -> tuple[Controller | None, Any, list[float], str, list[dict[str, Any]]]:
    """``descent``: stabilise by :func:`~ftc_verify.synthesis.descent.stabilise` (starts: the
    observer designs of ``rows`` at full order, the zero controller, seeded random ones),
    then the tuning ladder: deepen the abscissa to each of
    :data:`~ftc_verify.synthesis.descent.LEVELS` (times the plant's rate scale) and have the
    core analysis certify each controller; the best certified gamma (robust where Lemma 4.1
    certifies, else nominal) is kept, and the ladder stops after two levels without a
    better one, or once a level is certified after :data:`TUNING_SECONDS`; then the P-K
    alternation (within that budget, at most 5 iterations). Returns ``(controller, report,
    history, message, descent rows)``."""
    par = Parametrisation.build(system, order)
    designed = sorted((r for r in rows if order == system.dims[0] and r.get("gains")),
                      key=lambda r: r["spectral_abscissa"] if r.get("spectral_abscissa") is not None else np.inf)
    starts = [(r["name"], par.theta(r["gains"])) for r in designed[:DESIGNED_STARTS]]
    found = stabilise(system, order, starts=starts, seed=seed, k_max=k_max)
    public = [{"name": f"descent from {r.start}", "gamma_certified": None, "spectral_abscissa": r.abscissa,
               "note": f"order {order}, gain norm {r.gain_norm:.3g}, kappa path "
                       + " -> ".join(f"{k:g}: {f:.3g}" for k, f in r.history),
               "reason": "stabilised; see the tuning ladder" if r.stabilised else "not stabilised"} for r in found]
    best = found[0]
    if not best.stabilised:
        scan = unbounded_gain_diagnosis(system, order, found, seed=seed)
        return None, None, [], f"descent: {scan['message']}", public + [{"name": "descent gain scan", **scan}]
    theta, scale = best.theta, rate_scale(system)
    chosen: tuple[Controller, Any, float] | None = None
    history: list[float] = []
    misses = 0
    deadline = cpu_clock() + TUNING_SECONDS
    for level in LEVELS:
        if chosen is not None and cpu_clock() > deadline:
            break
        theta, reached = deepen(system, order, theta, level * scale, k_max=k_max)
        ctrl = par.controller(theta, f"{system.name} descent (order {order})")
        report = verify_controller(system, ctrl, solver)
        calls.outcomes.extend(a for res in (report.nominal, report.robust, report.mes_lmi) for a in res.attempts)
        gamma = accepted_gamma(report, True)
        if gamma is not None and (chosen is None or gamma < chosen[2]):
            chosen, misses = (ctrl, report, gamma), 0
            history.append(gamma)
        elif chosen is not None:
            misses += 1
        if misses >= 2 or reached > level * scale:
            break
    if chosen is None:
        return None, None, [], (f"descent (order {order}) stabilised (abscissa {best.abscissa:.4g} from "
                                f"{best.start}) but the core certified no controller of the tuning ladder"), public
    tuned, why = (_alternate(system, par, chosen, k_max, solver, calls) if cpu_clock() < deadline
                  else (None, f"not tried (tuning budget of {TUNING_SECONDS:g} CPU s spent)"))
    note = f"; P-K alternation: {why}"
    if tuned is not None:
        chosen = tuned
        history.append(chosen[2])
    kind = "robust" if chosen[1].robust.certified else "nominal (Lemma 4.1 not certified)"
    msg = (f"descent (order {order}) from {best.start}: stabilised at the true rates, then the tuning ladder{note}; "
           f"best certified {kind} gamma {upper_text(chosen[2])}")
    return chosen[0], chosen[1], history, msg, public


def _nominal_system(system: FTCSystem) -> FTCSystem:
    """``system`` without its uncertainty channels."""
    from dataclasses import replace

    return replace(system, modes=tuple(replace(md, A1=None, A2=None, B1=None, B2=None) for md in system.modes))


def _alternate(system: FTCSystem, par: Parametrisation, chosen: tuple[Controller, Any, float], k_max: float | None,
               solver: str, calls: SolverCalls) -> tuple[tuple[Controller, Any, float] | None, str]:
    """The P-K alternation (the V-K iteration of ``vk``) from the ladder's best controller:
    the certified gamma's ``P`` and multipliers fixed, the controller blocks from the LMI
    of :func:`~ftc_verify.synthesis.state_feedback.gain_step`, and back; on the system as
    it is when Lemma 4.1 certified the start, else on its nominal part (Theorem 3.2's
    gamma). Every iterate is certified by the core; the result only if the core certifies
    it below the start on the real system (``None`` otherwise), with what happened."""
    from ..analysis.closedloop import closed_loop
    from .of_blocks import augmented_system, controller_blocks
    from .state_feedback import descend, gain_step

    target = system if chosen[1].robust.certified else _nominal_system(system)
    aug, cbars = augmented_system(target, par.n_c)
    found = descend(
        lambda B: closed_loop(target, par.controller(par.theta(B), "p-k")),
        lambda P, lam, j: gain_step(aug, P, lam, j, calls, k_max, measurement=cbars), system.m,
        controller_blocks(chosen[0]), calls, solver, 5, 1e-3)
    why = found.message
    if len(found.history) < 2:
        return None, f"no improvement ({why})"
    ctrl = par.controller(par.theta(found.gains), chosen[0].name)
    report = verify_controller(system, ctrl, solver)
    gamma = accepted_gamma(report, True)
    if gamma is None or gamma >= chosen[2] or (chosen[1].robust.certified and not report.robust.certified):
        return None, f"its answer not certified below the ladder's ({why})"
    return (ctrl, report, gamma), f"{upper_text(chosen[2])} -> {upper_text(gamma)} ({why})"



def accepted_gamma(report: Any, nominal_ok: bool) -> float | None:
    """The certified gamma a controller is ranked by: Lemma 4.1's, else (``nominal_ok``,
    the descent) Theorem 3.2's; ``None`` unless the core certified stability (the verdict
    and Theorem 3.1)."""
    if report is None or not report.certified_stable:
        return None
    if report.robust.certified:
        return report.robust.gamma
    return report.nominal.gamma if nominal_ok and report.nominal.certified else None
