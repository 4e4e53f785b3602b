r"""Linearisation of a plant-map FMU per fault mode, at one operating point.

For fault mode :math:`i` the FMU is :math:`\dot x = f_i(x, u, w)`, :math:`y = g(x)`,
:math:`y_m = g_m(x)` (the map's ``states``, ``inputs``, ``disturbances``, ``performance``,
``measured``). Around :math:`(x_{op}, u_{op}, w_{op})` the deviation model is

.. math::  \dot{\delta x} = A_i \delta x + B_i \delta u + D_i \delta w + f_i(x_{op}, u_{op}, w_{op}),
           \quad \delta y = C_i \delta x, \quad \delta y_m = C_{y,i} \delta x,

with :math:`A_i = \partial f_i/\partial x`, :math:`B_i = \partial f_i/\partial u`,
:math:`D_i = \partial f_i/\partial w`, :math:`C_i = \partial g/\partial x`. The constant
*drift* :math:`f_i(x_{op}, \dots)` is zero in the mode the operating point is a trim of and
in general not in the faulty modes; the linear model does not carry it and the result says so.

Routes, best first (:func:`linearize_plant` picks the best the FMU allows):

``directional``  ``fmi2GetDirectionalDerivative`` of the derivatives ``der(x)`` and the
    outputs with respect to states and inputs (exact; the states must be the FMU's
    continuous states and it must declare ``providesDirectionalDerivative``).
``finite-differences``  the derivative variables read after initialising at perturbed
    states and inputs; central differences with steps :math:`\delta` and :math:`\delta/2`,
    the Richardson combination :math:`(4 J_{\delta/2} - J_\delta)/3` as the answer and
    :math:`|J_{\delta/2} - J_\delta|` as its error estimate.
``identification``  for co-simulation FMUs that expose no derivatives: one ``fmi2DoStep``
    of length :math:`h` from perturbed initial states and with perturbed (held) inputs gives
    central-difference columns of :math:`\Phi = e^{A h}` and :math:`\Gamma = \int_0^h e^{A s}
    ds\,[B\ D]`, and the drift column :math:`g = x(h) - x_{op}`. Then

    .. math::  \operatorname{logm}\begin{bmatrix}\Phi & \Gamma & g\\ 0 & I & 0\\ 0 & 0 & 1\end{bmatrix} / h
               = \begin{bmatrix} A & [B\ D] & f\\ 0 & 0 & 0 \\ 0 & 0 & 0\end{bmatrix}

    (the exponential of the block matrix on the right, times :math:`h`, is the one on the
    left; the principal logarithm is the right branch while :math:`h |\operatorname{Im}
    \lambda(A)| < \pi`). Away from an equilibrium the state moves during the step and the
    result has an :math:`O(h)` error; the answer is the Richardson combination
    :math:`2 L_{h/2} - L_h` and :math:`|L_{h/2} - L_h|` its error estimate.

The outputs are linear maps of the state read at :math:`t = 0` after initialisation
(central differences; an output depending directly on ``u`` or ``w`` is reported).

Accuracy: a matrix whose error estimate exceeds :data:`ACCURACY_FRACTION` of its largest
entry is listed in :attr:`Linearisation.inaccurate` (the command line warns and writes the
system file only with ``--accept-inaccurate``).

Every FMI call goes through the session's error path (:meth:`FMUSession.call_error`): an FMU
that fails during a probe raises :class:`~ftc_verify.errors.PlantRunError` naming the FMU
file, the call, the fault mode and time, and the FMU's own log messages (:func:`fmi_calls`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any
from collections.abc import Callable

import numpy as np
import scipy.linalg

from ..errors import FMUError, PlantRunError, ValidationError
from ..model.system import FTCSystem, JointChain, Mode
from .fmu_session import FMICallError, FMUSession, VarGroup
from .plant_map import PlantMap

__all__ = ["ModeLinearisation", "Linearisation", "linearize_plant", "trim_plant", "ROUTES", "ACCURACY_FRACTION",
           "TrimFailed", "fmi_calls", "fmu_failure"]

#: The linearisation routes: the values of ``route`` of :func:`linearize_plant`.
ROUTES = ("directional", "finite-differences", "identification")
#: The ``fmi2SetupExperiment`` tolerance used while linearising (or the map's, if tighter).
LINEARISATION_TOLERANCE = 1e-12
#: Largest error estimate a linearised matrix may have, as a fraction of its largest absolute
#: entry (``A``; ``[B D]``; ``[C; Cy]``, per fault mode). A matrix whose entries are all below
#: 1e-6 of the largest entry of ``[A B D]`` is measured against that instead (an exactly zero
#: block is not "inaccurate" for a rounding-level estimate). Above it the linearisation is
#: reported as inaccurate (:attr:`Linearisation.inaccurate`): the text output warns, the JSON
#: lists it, and ``linearize -o`` refuses to write it without ``--accept-inaccurate``.
ACCURACY_FRACTION = 1e-3


class TrimFailed(FMUError):
    """:func:`trim_plant` found no stationary point (a result of the plant, not bad input)."""


def fmu_failure(session: FMUSession, exc: Exception, when: str, names: Sequence[str] = ()) -> PlantRunError:
    """The :class:`PlantRunError` for a failed FMI call, built by :meth:`FMUSession.call_error`.

    Parameters
    ----------
    session : FMUSession
        The session the call was made on.
    exc : Exception
        The :class:`~ftc_verify.plants.fmu_session.FMICallError` of a session call
        (:meth:`FMUSession.read`...), or the :class:`FMUError` a session method (e.g.
        :meth:`FMUSession.start_path`) already built for one.
    when : str
        Where the call happened (fault mode, time), e.g. ``"at t = 0 in fault mode 1"``.
    names : sequence of str
        The variables of the call.

    Returns
    -------
    PlantRunError
        Naming the FMU file, the call, ``when`` and the FMU's own log messages.
    """
    err = session.call_error(exc, when, names) if isinstance(exc, FMICallError) else exc
    text, prefix = str(err), f"{session.path}: "
    return PlantRunError(str(session.path), text[len(prefix):] if text.startswith(prefix) else text)


@contextmanager
def fmi_calls(session: FMUSession, when: str, names: Sequence[str] = ()) -> Iterator[None]:
    """Turn a failing FMI call inside the block into :func:`fmu_failure`'s
    :class:`PlantRunError` (:class:`~ftc_verify.plants.fmu_session.FMICallError` and the
    session's own call errors; fault values must have been validated before,
    :meth:`FMUSession.fault_writes`)."""
    try:
        yield
    except PlantRunError:
        raise
    except FMUError as exc:
        raise fmu_failure(session, exc, when, names) from None


@dataclass(frozen=True)
class ModeLinearisation:
    """The linear model of one fault mode: matrices, the drift, and error estimates
    (largest absolute entry of the difference between two step sizes; 0 when exact)."""

    name: str
    A: np.ndarray
    B: np.ndarray
    D: np.ndarray
    C: np.ndarray
    Cy: np.ndarray | None
    drift: np.ndarray
    errors: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Linearisation:
    """Every mode's :class:`ModeLinearisation`, the route used and the operating point."""

    route: str
    modes: tuple[ModeLinearisation, ...]
    states_op: np.ndarray
    notes: tuple[str, ...]
    inaccurate: tuple[str, ...] = ()

    def system(self, name: str, chain: JointChain) -> FTCSystem:
        """The core-format system (``A, B, C, D, Cy`` per mode) with ``chain``."""
        modes = tuple(Mode(A=m.A, B=m.B, C=m.C, D=m.D, Cy=m.Cy, label=f"mode[{k}]")
                      for k, m in enumerate(self.modes, start=1))
        return FTCSystem(name, modes, chain)

    def to_dict(self) -> dict[str, Any]:
        return {"route": self.route, "states_op": self.states_op.tolist(), "notes": list(self.notes),
                "accuracy_fraction": ACCURACY_FRACTION, "inaccurate": list(self.inaccurate),
                "modes": [{"name": m.name, "drift": m.drift.tolist(), "drift_norm": float(np.linalg.norm(m.drift)),
                           "errors": m.errors} for m in self.modes]}


class _Probe:
    """Evaluations of the FMU at a state, inputs and fault mode (each from a fresh initialisation)."""

    def __init__(self, session: FMUSession, pm: PlantMap) -> None:
        self.s, self.pm = session, pm
        md = session.model_description
        if not session.init.n:
            raise ValidationError(f"{pm.source}: linearisation sets the state through [variables].initial_states "
                                  "(or the states themselves), but none can be set")
        by_state = {d.variable.derivative.name: d.variable for d in md.derivatives
                    if d.variable is not None and d.variable.derivative is not None}
        ders = [by_state.get(x) for x in pm.states]
        self.der = VarGroup(ders) if all(d is not None for d in ders) else None
        self.out = VarGroup(session.variables.outputs + session.variables.measured)
        self.states = VarGroup(session.variables.states)
        for mode in range(pm.m):  # the map's fault values, checked before any FMI call
            session.fault_writes(mode)
        self.at = ""

    def start(self, mode: int, x: np.ndarray, uw: np.ndarray) -> None:
        s = self.s
        self.at = f"in fault mode {mode + 1} ({self.pm.faults[mode].name}) while linearising"
        with fmi_calls(s, f"at t = 0 {self.at}", s.uw.names):
            s.start_path(x, mode, None)
            s.write(s.uw, uw)

    def read(self, grp: VarGroup, t: float = 0.0) -> np.ndarray:
        with fmi_calls(self.s, f"at t = {t:g} {self.at}", grp.names):
            self.s.read(grp)
        return np.array(list(grp.buf)[:grp.n], dtype=float)

    def derivative(self, mode: int, x: np.ndarray, uw: np.ndarray) -> np.ndarray:
        assert self.der is not None
        self.start(mode, x, uw)
        return self.read(self.der)

    def outputs(self, mode: int, x: np.ndarray, uw: np.ndarray) -> np.ndarray:
        self.start(mode, x, uw)
        return self.read(self.out)

    def flow(self, mode: int, x: np.ndarray, uw: np.ndarray, h: float) -> np.ndarray:
        self.start(mode, x, uw)
        with fmi_calls(self.s, f"in the step from t = 0 to t = {h:g} {self.at}"):
            self.s.step(0.0, h)
        return self.read(self.states, h)


def _central(fun: Callable[[np.ndarray], np.ndarray], z0: np.ndarray, delta: np.ndarray) -> np.ndarray:
    cols = []
    for j in range(z0.size):
        e = np.zeros(z0.size)
        e[j] = delta[j]
        cols.append((fun(z0 + e) - fun(z0 - e)) / (2 * delta[j]))
    return np.column_stack(cols) if cols else np.zeros((0, 0))


def _richardson(fun: Callable[[np.ndarray], np.ndarray], z0: np.ndarray, rel: float) -> tuple[np.ndarray, float]:
    delta = rel * np.maximum(1.0, np.abs(z0))
    j1, j2 = _central(fun, z0, delta), _central(fun, z0, delta / 2)
    return (4 * j2 - j1) / 3, float(np.max(np.abs(j2 - j1), initial=0.0))


def _identify(probe: _Probe, mode: int, x0: np.ndarray, uw0: np.ndarray, h: float, rel: float) -> np.ndarray:
    """``[A, [B D], f]`` from one-step responses (module docstring, route identification)."""
    n, k = x0.size, uw0.size
    z0 = np.concatenate([x0, uw0])
    Jz = _central(lambda z: probe.flow(mode, z[:n], z[n:], h), z0, rel * np.maximum(1.0, np.abs(z0)))
    g = probe.flow(mode, x0, uw0, h) - x0
    M = np.zeros((n + k + 1, n + k + 1))
    M[:n, :n + k], M[:n, -1] = Jz, g
    M[n:, n:] = np.eye(k + 1)
    L = scipy.linalg.logm(M) / h
    if np.iscomplexobj(L):
        if np.max(np.abs(L.imag)) > 1e-9 * max(1.0, np.max(np.abs(L.real))):
            raise FMUError(f"identification: logm of the step response is complex for step {h:g}; "
                           "the step is too long for the plant's fastest oscillation")
        L = L.real
    return L[:n]


def _mode(probe: _Probe, route: str, mode: int, x0: np.ndarray, uw0: np.ndarray, rel: float,
          h: float) -> ModeLinearisation:
    n, nu = x0.size, len(probe.pm.inputs)
    z0 = np.concatenate([x0, uw0])
    errors: dict[str, float] = {}
    if route == "directional":
        s = probe.s
        probe.start(mode, x0, uw0)
        known = [v.valueReference for v in s.variables.states + s.variables.inputs + s.variables.disturbances]
        unknown = list(probe.der.vr)  # type: ignore[union-attr]
        with fmi_calls(s, f"at t = 0 {probe.at}", probe.der.names):  # type: ignore[union-attr]
            J = np.column_stack([s.directional_derivative(unknown, [vr], [1.0]) for vr in known])
        f = probe.read(probe.der)  # type: ignore[arg-type]
        errors["A"] = errors["B"] = 0.0
    elif route == "finite-differences":
        J, errors["A"] = _richardson(lambda z: probe.derivative(mode, z[:n], z[n:]), z0, rel)
        errors["B"] = errors["A"]
        f = probe.derivative(mode, x0, uw0)
    else:
        L1, L2 = _identify(probe, mode, x0, uw0, h, rel), _identify(probe, mode, x0, uw0, h / 2, rel)
        L = 2 * L2 - L1  # Richardson in h: the O(h) error of a drifting (non-equilibrium) step cancels
        J, f = L[:, :-1], L[:, -1]
        errors["A"] = errors["B"] = float(np.max(np.abs(L2 - L1)))
    Jy, errors["C"] = _richardson(lambda z: probe.outputs(mode, z[:n], z[n:]), z0, rel)
    ny = len(probe.pm.performance)
    feed = float(np.max(np.abs(Jy[:, n:]), initial=0.0))
    if feed > 1e-8:
        errors["output_feedthrough"] = feed
    return ModeLinearisation(
        name=probe.pm.faults[mode].name, A=J[:, :n], B=J[:, n:n + nu], D=J[:, n + nu:], C=Jy[:ny, :n],
        Cy=Jy[ny:, :n] if probe.pm.measured else None, drift=f, errors=errors)


def _route(session: FMUSession, probe: _Probe, route: str | None) -> str:
    md = session.model_description
    can_dd = bool(md.coSimulation.providesDirectionalDerivative) and probe.der is not None
    available = (["directional"] if can_dd else []) + (["finite-differences"] if probe.der is not None else []) \
        + ["identification"]
    if route is None:
        return available[0]
    if route not in available:
        raise ValidationError(f"route {route!r} is not available for {session.path} (available: {available})")
    return route


def linearize_plant(pm: PlantMap, *, route: str | None = None, rel_step: float = 1e-5,
                    id_step: float = 1e-2) -> Linearisation:
    """Linearise the map's FMU in every fault mode at its operating point (module docstring).

    ``route``: one of :data:`~ftc_verify.plants.linearize.ROUTES` (default: the best available). ``rel_step``: central
    difference step relative to ``max(1, |value|)``. ``id_step``: the ``doStep`` length of
    the identification route.
    """
    x_op = pm.require_states_op("linearize")
    pm.require("inputs", "linearize")
    uw0 = np.concatenate([pm.inputs_op, pm.disturbances_op])
    with FMUSession(pm.fmu, pm.injection_map(), tolerance=min(pm.tolerance or 1.0, LINEARISATION_TOLERANCE)) as session:
        probe = _Probe(session, pm)
        chosen = _route(session, probe, route)
        modes = tuple(_mode(probe, chosen, i, x_op, uw0, rel_step, id_step) for i in range(pm.m))
    notes = [f"mode {k} ({m.name}): drift |f(x_op, u_op)| = {np.linalg.norm(m.drift):.3g}: the operating point is "
             "not an equilibrium here and the linear model does not carry the drift"
             for k, m in enumerate(modes, start=1)
             if np.linalg.norm(m.drift) > 1e-8 * max(1.0, float(np.linalg.norm(x_op)))]
    notes += [f"mode {k}: an output depends directly on u or w (largest entry {m.errors['output_feedthrough']:.3g}); "
              "the core model has no feedthrough" for k, m in enumerate(modes, start=1) if "output_feedthrough" in m.errors]
    return Linearisation(chosen, modes, x_op, tuple(notes), tuple(w for k, m in enumerate(modes, start=1)
                                                                  for w in _inaccurate(k, m)))


def _inaccurate(k: int, m: ModeLinearisation) -> list[str]:
    """Why the matrices of mode ``k`` miss :data:`ACCURACY_FRACTION` (empty: they do not)."""
    mats = {"A": ("A", m.A), "B": ("[B D]", np.hstack([m.B, m.D])),
            "C": ("[C; Cy]", m.C if m.Cy is None else np.vstack([m.C, m.Cy]))}
    floor = 1e-6 * float(np.max(np.abs(np.hstack([m.A, m.B, m.D])), initial=0.0))
    out = []
    for key, (label, M) in mats.items():
        err = m.errors.get(key)
        scale = max(float(np.max(np.abs(M), initial=0.0)), floor)
        if err is not None and err > ACCURACY_FRACTION * scale:
            out.append(f"mode {k} ({m.name}): the error estimate of {label}, {err:.3g}, exceeds "
                       f"{ACCURACY_FRACTION:g} of its largest entry {scale:.3g}")
    return out


def trim_plant(pm: PlantMap, *, x_guess: np.ndarray | None = None, tol: float = 1e-9) -> np.ndarray:
    """States that make the first (nominal) fault mode stationary at the map's inputs:
    ``f_1(x, u_op, w_op) = 0`` (derivatives, or ``x(h) - x`` for co-simulation FMUs without
    them), solved with :func:`scipy.optimize.root` (hybrid Powell) from ``x_guess``
    (default: the map's states, else the FMU's start values). Raises when no point is found."""
    import scipy.optimize

    uw0 = np.concatenate([pm.inputs_op, pm.disturbances_op])
    with FMUSession(pm.fmu, pm.injection_map(), tolerance=min(pm.tolerance or 1.0, LINEARISATION_TOLERANCE)) as session:
        probe = _Probe(session, pm)
        if x_guess is None:
            x_guess = pm.states_op if pm.states_op is not None else np.array(
                [float(v.start or 0.0) for v in session.variables.states])

        def fun(x: np.ndarray) -> np.ndarray:
            """f_1(x, u_op, w_op), or its one-step difference quotient without der(x)."""
            if probe.der is not None:
                return probe.derivative(0, x, uw0)
            return (probe.flow(0, x, uw0, 1e-2) - x) / 1e-2

        sol = scipy.optimize.root(fun, np.asarray(x_guess, dtype=float), method="hybr", tol=tol)
        resid = float(np.max(np.abs(fun(sol.x)))) if np.all(np.isfinite(sol.x)) else np.inf
    scale = max(1.0, float(np.max(np.abs(sol.x)))) if np.all(np.isfinite(sol.x)) else 1.0
    if not resid <= 1e-6 * scale:
        raise TrimFailed(f"{pm.fmu}: trim failed: no stationary point of mode 1 found at inputs "
                       f"{pm.inputs_op.tolist()} (residual {resid:.3g}; {' '.join(str(sol.message).split())})")
    return sol.x
