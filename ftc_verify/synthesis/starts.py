r"""Starting gains for the ``iterative`` method, and why synthesis can fail.

The iterative (gain <-> Lyapunov) descent is only as good as its start, so it tries several
classical designs and starts from the best one that the core analysis certifies. Every
candidate below gives one gain :math:`K_j` per FDI mode ``j`` (the controller the paper's
model allows); none is trusted until :func:`ftc_verify.analysis.analyze` has run the
exact spectral test and certified a robust gamma (Lemma 4.1) for it.

``lqr`` (textbook)
    Per FDI mode, the LQR gain of the plant that mode reports:
    :math:`K_j = -R^{-1} B_j^T X_j` with :math:`X_j` the stabilising solution of
    :math:`A_j^T X + X A_j - X B_j R^{-1} B_j^T X + Q = 0`, :math:`Q = 10 I`, :math:`R = I`
    (the design a user writes in five lines; also the benchmark's baseline).
``lqr-C, rho``
    The same with weights from the performance output,
    :math:`Q_j = C_j^T C_j / \|C_j\|_2^2 + 10^{-2} I` (positive definite, so every
    stabilisable mode has a stabilising solution), :math:`R = \rho I` for
    :math:`\rho \in` :data:`LQR_SCALES` (the scale search: small ``rho`` fast gains,
    large ``rho`` gentle ones).
``averaged``
    One gain for every FDI mode: the LQR gain of the plant averaged over the stationary
    distribution :math:`\pi` of the fault chain,
    :math:`\bar A = \sum_i \pi_i A_i`, :math:`\bar B = \sum_i \pi_i B_i` (textbook weights).
``full-info projected``
    The full-information design (gains :math:`K_s` that may use the true mode, the
    convex relaxation; one per joint state ``s``) projected onto FDI-mode gains by
    averaging over the joint states of FDI mode ``j`` (every true mode and, with
    phase-type delays, every phase) with the weights of the joint chain's stationary
    distribution at the midpoint of the rate box:
    :math:`K_j = \sum_{s = (i, j, p)} p_s K_s / \sum_{s = (i, j, p)} p_s`.

With a gain bound ``k_max`` a candidate gain with :math:`\|K_j\|_2 > k_{max}` is scaled onto
the bound (:math:`K_j k_{max}/\|K_j\|_2`) and the start is marked "scaled to the gain
bound"; the certification then decides whether it still counts.

:func:`stabilisability` is the per-mode Popov-Belevitch-Hautus test used to explain a
failure: an eigenvalue :math:`\lambda` of :math:`A_i` with :math:`\Re\lambda \ge 0` for
which :math:`[A_i - \lambda I,\ B_i]` loses rank cannot be moved by any gain in mode ``i``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..analysis.conditioning import stationary_distribution
from ..model.system import FTCSystem, Matrix

__all__ = ["LQR_SCALES", "Candidate", "lqr_gain", "candidates", "stationary", "stabilisability", "certify_start",
           "diagnose"]

#: Input weights ``R = rho I`` of the ``lqr-C`` scale search.
LQR_SCALES = (1e-2, 1.0, 1e2)
#: Relative rank tolerance of the PBH test (singular values below it times the largest).
PBH_RTOL = 1e-9


@dataclass(frozen=True)
class Candidate:
    """One starting design: its name, its FDI-mode gains (``None`` when the design does not
    exist, e.g. no stabilising Riccati solution) and a note (scaled, or why none)."""

    name: str
    gains: tuple[Matrix, ...] | None
    note: str = ""


def lqr_gain(A: Matrix, B: Matrix, Q: Matrix, R: Matrix) -> Matrix | None:
    """``-R^{-1} B^T X`` for the stabilising solution ``X`` of the Riccati equation in the
    module docstring (scipy's ``solve_continuous_are``); ``None`` when there is none
    (``(A, B)`` not stabilisable) or the closed loop it gives is not Hurwitz."""
    from scipy.linalg import solve_continuous_are

    try:
        X = solve_continuous_are(A, B, Q, R)
    except (np.linalg.LinAlgError, ValueError):
        return None
    if not np.all(np.isfinite(X)):
        return None
    K = -np.linalg.solve(R, B.T @ X)
    if np.max(np.linalg.eigvals(A + B @ K).real) >= 0:
        return None
    return K


def stationary(G: Matrix) -> Matrix:
    """Stationary distribution ``p`` of a generator ``G`` (``p G = 0``, ``sum p = 1``):
    :func:`~ftc_verify.analysis.conditioning.stationary_distribution`."""
    return stationary_distribution(G)


def _bounded(gains: list[Matrix], k_max: float | None) -> tuple[tuple[Matrix, ...], str]:
    """Gains scaled onto the bound where they exceed it, and the note saying so."""
    if k_max is None:
        return tuple(gains), ""
    out, scaled = [], False
    for K in gains:
        norm = float(np.linalg.norm(K, 2))
        if norm > k_max:
            K, scaled = K * (k_max / norm), True
        out.append(K)
    return tuple(out), "scaled to the gain bound" if scaled else ""


def _per_mode(name: str, system: FTCSystem, weights: Any, k_max: float | None) -> Candidate:
    gains = []
    for j, mode in enumerate(system.modes):
        Q, R = weights(mode)
        K = lqr_gain(mode.A, mode.B, Q, R)
        if K is None:
            return Candidate(name, None, f"no stabilising Riccati solution in mode {j + 1}")
        gains.append(K)
    bounded, note = _bounded(gains, k_max)
    return Candidate(name, bounded, note)


def _output_weight(mode: Any) -> Matrix:
    CtC = mode.C.T @ mode.C
    scale = float(np.linalg.norm(CtC, 2))
    return (CtC / scale if scale > 0 else 0.0 * CtC) + 1e-2 * np.eye(mode.A.shape[0])


def candidates(system: FTCSystem, k_max: float | None, full_info: list[Matrix] | None) -> list[Candidate]:
    """The classical starting designs of the module docstring, in order. ``full_info``:
    the full-information gains ``K_s``, one per joint state in the chain's order (``None``
    when that LMI failed)."""
    n, nu = system.dims[0], system.dims[1]
    out = [_per_mode("lqr", system, lambda md: (10.0 * np.eye(n), np.eye(nu)), k_max)]
    for rho in LQR_SCALES:
        out.append(_per_mode(f"lqr-C rho={rho:g}", system, lambda md, r=rho: (_output_weight(md), r * np.eye(nu)),
                             k_max))
    pi = stationary(system.chain.alpha)
    A_bar = sum(p * md.A for p, md in zip(pi, system.modes))
    B_bar = sum(p * md.B for p, md in zip(pi, system.modes))
    K = lqr_gain(A_bar, B_bar, 10.0 * np.eye(n), np.eye(nu))
    if K is None:
        out.append(Candidate("averaged", None, "the averaged plant has no stabilising Riccati solution"))
    else:
        gains, note = _bounded([K] * system.m, k_max)
        out.append(Candidate("averaged", gains, note))
    if full_info is None:
        out.append(Candidate("full-info projected", None, "the full-information LMI gave no gains"))
    else:
        p = stationary(system.chain.generator(system.chain.midpoint()))
        joint = system.chain.joint_modes
        projected: list[Matrix] = []
        for j in range(system.m):
            w = np.array([p[s] for s, (_, l_) in enumerate(joint) if l_ == j])
            Ks = [full_info[s] for s, (_, l_) in enumerate(joint) if l_ == j]
            w = w / w.sum() if w.sum() > 0 else np.full(len(Ks), 1.0 / len(Ks))
            projected.append(sum(wk * Kk for wk, Kk in zip(w, Ks)))
        bounded, note = _bounded(projected, k_max)
        out.append(Candidate("full-info projected", bounded, note))
    return out


def stabilisability(system: FTCSystem, *, dual: bool = False) -> list[dict[str, Any]]:
    """Per true mode, the PBH test: ``{"mode", "stabilisable", "uncontrollable"}`` with the
    eigenvalues ``lambda`` (real part >= 0) at which ``[A - lambda I, B]`` loses rank.
    ``dual=True`` tests detectability of ``(A, Cy)`` instead (``[A' - lambda I, Cy']``)."""
    rows = []
    for i, md in enumerate(system.modes):
        n = md.A.shape[0]
        A, B = (md.A.T, md.measured.T) if dual else (md.A, md.B)
        bad = []
        for lam in np.linalg.eigvals(A):
            if lam.real < 0:
                continue
            s = np.linalg.svd(np.hstack([A - lam * np.eye(n), B.astype(complex)]), compute_uv=False)
            if s[-1] <= PBH_RTOL * max(1.0, s[0]):  # n singular values: the smallest decides the rank
                bad.append(complex(lam))
        rows.append({"mode": i + 1, "stabilisable": not bad,
                     "uncontrollable": [[z.real, z.imag] for z in bad]})
    return rows


def certify_start(system: FTCSystem, name: str, gains: tuple[Matrix, ...] | list[Matrix], solver: str,
                  note: str = "", *, loop: Any = None) -> dict[str, Any]:
    """The core analysis of one start: the exact spectral test at every rate vertex,
    then the robust gamma of Lemma 4.1 (certificate re-checked with numpy). Returns the
    ``starts`` row of the synthesis result: ``name``, ``gamma_certified`` (``None`` when
    not certified), ``spectral_abscissa``, ``note`` and ``reason`` (why it does not count).
    ``loop``: the closed loop when the gains are not state feedback (output feedback)."""
    from ..analysis.closedloop import state_feedback_loop
    from ..analysis.lmi_analysis import hinf_gamma
    from ..analysis.moments.stability import mean_square_stability

    loop = state_feedback_loop(system, list(gains)) if loop is None else loop
    mss = mean_square_stability(loop)
    row: dict[str, Any] = {"name": name, "gamma_certified": None, "spectral_abscissa": mss.spectral_abscissa,
                           "note": note, "reason": "", "gains": tuple(gains), "attempts": ()}
    if not mss.stable:
        return row | {"reason": f"not mean-square stable (spectral abscissa {mss.spectral_abscissa:.4g})"}
    res = hinf_gamma(loop, robust=True, solver=solver)
    row["attempts"] = res.attempts
    if not res.certified or res.gamma is None:
        return row | {"reason": f"robust gamma not certified ({res.solver_status}: {res.message})"}
    return row | {"gamma_certified": float(res.gamma), "lmi": res}


def diagnose(system: FTCSystem, rows: list[dict[str, Any]], statuses: list[str], k_max: float | None,
             *, output_feedback: bool = False) -> dict[str, Any]:
    """Why no certified controller was found, in order of precedence:

    * ``not stabilisable``: some true mode fails the PBH test (:func:`stabilisability`):
      no gain moves its unstable uncontrollable eigenvalues, so a controller could only
      rely on the chain leaving that mode;
    * ``not detectable`` (``output_feedback``): some true mode has an unstable eigenvalue
      that ``y_m = Cy x`` does not see (the dual PBH test);
    * ``stable but not certified``: some start was mean-square stable, yet no robust gamma
      was certified: the solver failed (its statuses are listed) or the uncertainty is too
      large for those gains;
    * ``no certified controller within the gain bound`` (or without one): no start reached
      mean-square stability; the best spectral abscissa reached is given.
    """
    modes = stabilisability(system)
    abscissas = [r["spectral_abscissa"] for r in rows if r.get("spectral_abscissa") is not None]
    best = min(abscissas) if abscissas else None
    trouble = {s: statuses.count(s) for s in sorted(set(statuses)) if s not in ("optimal", "infeasible")}
    bad = [r for r in modes if not r["stabilisable"]]
    blind = [r for r in stabilisability(system, dual=True) if not r["stabilisable"]] if output_feedback else []
    if blind and not bad:
        eig = ", ".join(f"{complex(*z):.4g}" for r in blind for z in r["uncontrollable"])
        reason, text = "not detectable", (f"the measured output does not see mode(s) {[r['mode'] for r in blind]} "
                                          f"(PBH on (A, Cy): unobservable eigenvalue(s) {eig})")
    elif bad:
        eig = ", ".join(f"{complex(*z):.4g}" for r in bad for z in r["uncontrollable"])
        reason, text = "not stabilisable", (f"the plant is not stabilisable in mode(s) {[r['mode'] for r in bad]} "
                                            f"(PBH: uncontrollable eigenvalue(s) {eig})")
    elif best is not None and best < 0:
        reason, text = "stable but not certified", (
            f"gains with spectral abscissa {best:.4g} (mean-square stable) were found but no robust gamma was "
            f"certified; solver statuses other than optimal/infeasible: {trouble or 'none'}")
    else:
        bound = f"within the gain bound {k_max:g}" if k_max is not None else "(no gain bound)"
        reason, text = "no certified controller", (
            f"no FDI-mode-only controller certified {bound}; "
            + ("no gains were produced" if best is None else f"best spectral abscissa reached {best:.4g}"))
    return {"reason": reason, "message": text, "modes": modes, "best_spectral_abscissa": best,
            "solver_statuses": trouble}
