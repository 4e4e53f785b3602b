r"""Per-mode cross-validation against python-control.

For every joint mode :math:`s = (i, j)` (true, FDI; one per pair, whatever the
detection phases of :mod:`ftc_verify.model.chain`) the frozen closed loop
:math:`G_s = (A_s, B_{w,s}, C_{z,s}, 0)` is analysed twice:

* here, with numpy/scipy: poles are ``numpy.linalg.eigvals(A_s)``; the
  :math:`L_\infty` norm by the Bruinsma-Steinbuch iteration on the Hamiltonian
  :math:`H(\gamma) = \begin{bmatrix} A & B B^T/\gamma^2 \\ -C^T C & -A^T \end{bmatrix}`
  (it has an imaginary eigenvalue :math:`j\omega` iff :math:`\gamma` is a singular value
  of :math:`G(j\omega)`): from a lower bound :math:`\gamma_k`, the imaginary eigenvalues of
  :math:`H((1+2r)\gamma_k)` bracket the frequency intervals where the gain exceeds it, and
  :math:`\gamma_{k+1}` is the largest :math:`\sigma_{max}(G(j\omega))` at their
  midpoints. Every lower bound is a gain actually attained; the iteration stops when
  :math:`H((1+2r)\gamma_k)` has no imaginary eigenvalue, :math:`r =` :data:`NORM_RTOL`.
  Accuracy: deciding "on the imaginary axis" uses a threshold of ``1e-9 |lambda|``, so when
  the peak is very flat the upper end may be missed; measured against SLICOT's ab13dd it
  agreed to better than 1e-8 relative on the test loops (``tests/test_lmi_analysis.py``);
* by python-control: ``control.poles`` and, where slycot is installed (a dependency),
  ``control.linfnorm`` (SLICOT ``ab13dd``, tolerance 1e-10); without slycot
  ``control.norm(sys, 'inf', method='scipy')`` (python-control's own bisection, documented
  accuracy 1e-6; python-control 0.10.2 raises ``LinAlgError`` there on a first-order mode).

Disagreements beyond :data:`POLE_RTOL` or :data:`NORM_AGREE_RTOL` are reported, not
hidden. The :math:`H_\infty` norm of a frozen mode is infinite when the mode is
unstable (a frozen unstable mode does not contradict mean-square stability of the
switching loop); both tools' :math:`L_\infty` values are still compared.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..jsonable import OMIT, fields_dict
from .closedloop import ClosedLoop
from ..model.system import Matrix

__all__ = [
    "NORM_RTOL",
    "NORM_AGREE_RTOL",
    "POLE_RTOL",
    "ModeCheck",
    "linf_norm",
    "cross_validate",
]

#: Bisection tolerance of :func:`linf_norm`.
NORM_RTOL = 1e-10
#: Agreement required between our norm and python-control's (its tolerance is 1e-6).
NORM_AGREE_RTOL = 1e-5
#: Agreement required between pole sets (relative to ``max(1, |pole|)``).
POLE_RTOL = 1e-8


def _sigma_max(A: Matrix, B: Matrix, C: Matrix, omega: float) -> float:
    """:math:`\\sigma_{max}(G(j\\omega))`; ``inf`` where :math:`j\\omega I - A` is singular
    in float64 (an ill-conditioned ``A`` can be, at ``omega = 0``, while no eigenvalue
    computed is within the threshold of :func:`linf_norm`: the float transfer function has
    a pole there)."""
    n = A.shape[0]
    try:
        G = C @ np.linalg.solve(1j * omega * np.eye(n) - A, B)
    except np.linalg.LinAlgError:
        return math.inf
    value = float(np.linalg.norm(G, 2))
    return value if not math.isnan(value) else math.inf


def linf_norm(A: Matrix, B: Matrix, C: Matrix, *, rtol: float = NORM_RTOL) -> float:
    """:math:`L_\\infty` norm of ``C (sI - A)^{-1} B`` (module docstring).

    Returns ``inf`` when ``A`` has an eigenvalue within ``1e-12 |lambda|`` of the
    imaginary axis, or :math:`j\\omega I - A` is singular in float64 at a frequency tried.
    """
    poles = np.linalg.eigvals(A)
    if np.any(np.abs(poles.real) <= 1e-12 * np.maximum(1.0, np.abs(poles))):
        return math.inf
    if not np.any(B) or not np.any(C):
        return 0.0
    freqs = [0.0] + [abs(p) for p in poles] + [abs(p.imag) for p in poles]
    lo = max(_sigma_max(A, B, C, w) for w in freqs)
    if not (lo > 0 and math.isfinite(lo)):
        return lo
    BB, CC = B @ B.T, C.T @ C
    for _ in range(100):
        gamma = lo * (1.0 + 2.0 * rtol)
        ev = np.linalg.eigvals(np.block([[A, BB / gamma ** 2], [-CC, -A.T]]))
        on_axis = np.abs(ev.real) <= 1e-9 * np.maximum(1.0, np.abs(ev))
        omegas = np.unique(np.round(np.sort(np.abs(ev.imag[on_axis])), 14))
        if omegas.size == 0:
            return gamma
        mids = 0.5 * (omegas[:-1] + omegas[1:]) if omegas.size > 1 else omegas
        best = max(_sigma_max(A, B, C, float(w)) for w in mids)
        if best <= lo:
            return gamma
        lo = best
    return lo * (1.0 + 2.0 * rtol)


def _control_linf(sys: Any) -> tuple[float, str]:
    """python-control's norm: SLICOT ab13dd when slycot is there, else its scipy method."""
    import importlib.util

    import control

    if importlib.util.find_spec("slycot") is None:
        return float(control.norm(sys, "inf", method="scipy", print_warning=False)), "control.norm (scipy)"
    return float(control.linfnorm(sys, tol=1e-10)[0]), "control.linfnorm (SLICOT ab13dd)"


@dataclass(frozen=True, eq=False)
class ModeCheck:
    """One frozen joint mode, as seen by numpy/scipy and by python-control."""

    true_mode: int
    fdi_mode: int
    poles: np.ndarray
    stable: bool
    hinf_norm: float
    linf_norm: float
    control_poles: np.ndarray = field(metadata=OMIT)
    control_linf_norm: float
    agree: bool
    detail: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (``control_poles`` left out); modes 1-based; the poles (complex)
        as ``[re, im]`` pairs; an infinite norm as null."""
        return fields_dict(self)


def _pole_match(ours: np.ndarray, theirs: np.ndarray) -> float:
    """Largest relative distance from each of our poles to the nearest of theirs."""
    if ours.shape != theirs.shape:
        return math.inf
    worst = 0.0
    for p in ours:
        worst = max(worst, float(np.min(np.abs(theirs - p)) / max(1.0, abs(p))))
    return worst


def cross_validate(loop: ClosedLoop) -> tuple[ModeCheck, ...]:
    """Frozen-mode poles and norms of every pair ``(true, fdi)``, ours against
    python-control's (the phases of a pair, which share its loop matrices, checked once)."""
    import control

    out = []
    first: dict[tuple[int, int], int] = {}
    for s, (i, j) in enumerate(loop.modes):
        f = first.setdefault((i, j), s)
        if f != s and all(np.array_equal(M[f], M[s]) for M in (loop.A, loop.Bw, loop.Cz)):
            continue
        A, B, C = loop.A[s], loop.Bw[s], loop.Cz[s]
        poles = np.sort_complex(np.linalg.eigvals(A))
        stable = bool(np.all(poles.real < 0))
        ours = linf_norm(A, B, C)
        sys = control.ss(A, B, C, np.zeros((C.shape[0], B.shape[1])))
        cpoles = np.sort_complex(np.asarray(control.poles(sys), dtype=complex))
        try:
            theirs, _ = _control_linf(sys)
        except Exception as exc:  # report, never crash the analysis
            theirs = math.nan
            note = f"python-control's norm raised {type(exc).__name__}: {exc}"
        else:
            note = ""
        pole_err = _pole_match(poles, cpoles)
        if math.isinf(ours) or math.isinf(theirs):
            norm_ok = math.isinf(ours) and math.isinf(theirs)
        else:
            norm_ok = abs(ours - theirs) <= NORM_AGREE_RTOL * max(ours, theirs, 1e-300)
        agree = bool(pole_err <= POLE_RTOL and norm_ok)
        if not agree:
            note = "; ".join(
                x for x in (
                    note,
                    f"pole mismatch {pole_err:.2e}" if pole_err > POLE_RTOL else "",
                    f"norm: ours {ours:.10g}, control {theirs:.10g}" if not norm_ok else "",
                ) if x
            )
        out.append(ModeCheck(i + 1, j + 1, poles, stable, ours if stable else math.inf, ours,
                             cpoles, theirs, agree, note or "agree"))
    return tuple(out)
