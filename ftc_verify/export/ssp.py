r"""The closed loop as an SSP 1.0 archive: the plant FMU and the exported controller FMU, connected.

:func:`write_loop_ssp` writes ``loop.ssp`` (a zip, SSP 1.0 "System Structure and
Parameterization"):

* ``SystemStructure.ssd`` -- one system ``loop`` with two components, ``plant``
  (``resources/plant.fmu``) and ``controller``
  (``resources/controller.fmu``, :mod:`ftc_verify.export.controller_fmu`), the connections
  plant's ``x`` (state feedback; ``y_m`` for output feedback) ``-> controller.v[i]`` and
  ``controller.u[i] ->`` the plant's ``u``, the system inputs ``w[j]`` to the plant's
  disturbances and the plant's performance outputs to the system outputs ``y[i]``;
* ``resources/modes.ssv`` -- the parameter set the system binds: the plant's fault
  variables in the true fault mode (``plant.mode`` for the ``LinearJumpPlant``, the
  plant map's ``fault_values`` otherwise), the FDI mode ``controller.fdi_mode`` (both fixed
  for a run: the loop of one joint mode), the initial state (``plant.x0[i]``) and the
  map's fixed parameters. They are ``parameter`` connectors, so that an importer sets
  them once, before initialisation.

Names of the plant's connectors are the plant FMU's variables (from its plant map,
:class:`~ftc_verify.plants.fault_map.FaultInjectionMap`; the ``LinearJumpPlant``'s by
default).

The default experiment's step is the controller's period ``h`` (its FMU refuses any other).

**The loop an SSP master runs.** An SSP 1.0 system fixes the connections, not the order
in which a master steps the components and copies the values. FMPy's ``simulate_ssp``
(``fmpy/ssp/simulation.py``) is a *Jacobi* master: it sets every connector to 0, then in
each round ``k`` (time :math:`t_k = k h`) sets each component's inputs from its
connectors, steps it over :math:`[t_k, t_{k+1}]`, reads its outputs, and only after all
components have stepped copies every connection (the system inputs ``w`` are set at the
round's start and reach the plant through a connection too). With :math:`c_u, c_v, c_w`
the connector values the plant's ``u``, the controller's ``v`` and the plant's ``w`` hold
during round ``k``, the archive's loop is exactly (:func:`jacobi_reference`)

.. math::

    x_{k+1} = \Phi x_k + \Gamma_B c_u^{(k)} + \Gamma_D c_w^{(k)}, \qquad
    x_{c,k+1} = \Phi_c x_{c,k} + \Gamma_c c_v^{(k)},

    c_u^{(k+1)} = C_c x_{c,k+1} + D_c c_v^{(k)}, \quad c_v^{(k+1)} = M x_{k+1}, \quad
    c_w^{(k+1)} = w(t_k), \qquad c^{(0)} = 0,

(:math:`\Phi, \Gamma_B, \Gamma_D`: the plant's exact zero-order hold over ``h``,
:func:`~ftc_verify.simulation.discretise.zoh_matrices`; :math:`\Phi_c, \Gamma_c` the
controller FMU's exact update, :func:`~ftc_verify.simulation.discretise.controller_zoh`;
:math:`M = I` or :math:`C_y`). For a static gain this is :math:`u_k = K x_{k-1}`: the
sampled loop with **one sample of delay** (and ``w`` delayed by one sample).

*No archive of these two FMUs can give FMPy's master the tool's undelayed loop*
(``simulate``: :math:`u_k = K x_k` over :math:`[t_k, t_{k+1}]`): the plant's input
during round ``k`` is the value its connector got in the exchange after round
``k - 1``, i.e. an output the controller produced from its inputs of round ``k - 1``,
which were copied no later than the exchange after round ``k - 2``: plant outputs at
:math:`t_{k-1}` at the latest. So :math:`u` over :math:`[t_k, t_{k+1}]` never depends on
:math:`x(t_k)`, whatever the controller FMU computes, in whichever order the components
are listed. Already the first step shows it: every connector starts at 0 and no
exchange precedes round 0, so the plant's input over :math:`[0, h]` is 0 and FMPy's
:math:`x(h) = \Phi x_0`, where the undelayed loop has :math:`\Phi x_0 + \Gamma_B K x_0`
(``tests/test_export_loop.py`` checks both statements). Only a controller that
predicts the plant (its true mode and ``w``) could hide the delay, and that is not the
certified controller. A master that exchanges the plant's outputs before stepping the
controller (Gauss-Seidel, or ``simulate --controller-fmu``) runs the undelayed loop.
"""


from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree as ET

from typing import Any

import numpy as np

from .. import __version__
from ..controllers.controller import Controller
from ..errors import ValidationError
from ..model.system import FTCSystem, Matrix
from ..plants.build import write_zip

__all__ = ["SSD_NS", "SSC_NS", "SSV_NS", "LoopSpec", "jacobi_reference", "loop_spec", "loop_ssd", "loop_ssv",
           "write_loop_ssp"]

SSD_NS = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC_NS = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV_NS = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
_FMU_TYPE = "application/x-fmu-sharedlibrary"


@dataclass(frozen=True)
class LoopSpec:
    """The plant's variables and the fixed values of one loop (names as in the plant FMU).

    Attributes
    ----------
    inputs, disturbances, outputs, reads : tuple of str
        The plant's ``u``, ``w``, ``y`` and the signals the controller reads (``x`` or
        ``y_m``), in the controller's order.
    parameters : tuple of (str, str, str)
        ``(name, SSC type, value text)`` of every plant variable set once: the fault
        variables of the true mode, the initial state, the map's fixed parameters.
    fault_mode, fdi_mode : int
        The true fault mode and the FDI mode (1-based).
    step, stop_time : float
        The default experiment.
    name : str
        The system's name (the SSD's description).
    """

    inputs: tuple[str, ...]
    disturbances: tuple[str, ...]
    outputs: tuple[str, ...]
    reads: tuple[str, ...]
    parameters: tuple[tuple[str, str, str], ...]
    fault_mode: int
    fdi_mode: int
    step: float
    stop_time: float
    name: str


def _q(ns: str, tag: str) -> str:
    return f"{{{ns}}}{tag}"


def _unique(items: list[tuple[str, str, str]]) -> list[tuple[str, str, str]]:
    """The connectors with each name once (a measured output may also be a performance output)."""
    out: list[tuple[str, str, str]] = []
    for item in items:
        if all(item[0] != c[0] for c in out):
            out.append(item)
    return out


def _connector(parent: ET.Element, name: str, kind: str, typ: str = "Real") -> None:
    c = ET.SubElement(parent, _q(SSD_NS, "Connector"), {"name": name, "kind": kind})
    ET.SubElement(c, _q(SSC_NS, typ))


def _component(parent: ET.Element, name: str, source: str, connectors: list[tuple[str, str, str]]) -> None:
    comp = ET.SubElement(parent, _q(SSD_NS, "Component"), {"name": name, "type": _FMU_TYPE, "source": source})
    conns = ET.SubElement(comp, _q(SSD_NS, "Connectors"))
    for cname, kind, typ in connectors:
        _connector(conns, cname, kind, typ)


def loop_ssd(spec: LoopSpec) -> str:
    """The ``SystemStructure.ssd`` text (module docstring)."""
    for prefix, uri in (("ssd", SSD_NS), ("ssc", SSC_NS), ("ssv", SSV_NS)):
        ET.register_namespace(prefix, uri)
    root = ET.Element(_q(SSD_NS, "SystemStructureDescription"), {
        "version": "1.0", "name": "ftc-loop", "generationTool": f"ftc-verify {__version__} (export-loop)"})
    system = ET.SubElement(root, _q(SSD_NS, "System"), {
        "name": "loop", "description": f"the FTC loop of {spec.name!r} in fault mode {spec.fault_mode}, "
                                       f"FDI mode {spec.fdi_mode}, sampled with period {spec.step!r} s"})
    conns = ET.SubElement(system, _q(SSD_NS, "Connectors"))
    for j in range(1, len(spec.disturbances) + 1):
        _connector(conns, f"w[{j}]", "input")
    for i in range(1, len(spec.outputs) + 1):
        _connector(conns, f"y[{i}]", "output")
    bindings = ET.SubElement(system, _q(SSD_NS, "ParameterBindings"))
    ET.SubElement(bindings, _q(SSD_NS, "ParameterBinding"), {"source": "resources/modes.ssv"})
    elements = ET.SubElement(system, _q(SSD_NS, "Elements"))
    plant = [(name, "parameter", typ) for name, typ, _ in spec.parameters]
    plant += [(name, "input", "Real") for name in spec.inputs + spec.disturbances]
    plant += [(name, "output", "Real") for name in spec.reads + spec.outputs]
    _component(elements, "plant", "resources/plant.fmu", _unique(plant))
    ctrl = [(f"v[{k}]", "input", "Real") for k in range(1, len(spec.reads) + 1)]
    ctrl += [(f"u[{k}]", "output", "Real") for k in range(1, len(spec.inputs) + 1)]
    ctrl.append(("fdi_mode", "parameter", "Integer"))
    _component(elements, "controller", "resources/controller.fmu", ctrl)
    links = ET.SubElement(system, _q(SSD_NS, "Connections"))

    def link(start: tuple[str | None, str], end: tuple[str | None, str]) -> None:
        attrs = {"startConnector": start[1], "endConnector": end[1]}
        if start[0]:
            attrs["startElement"] = start[0]
        if end[0]:
            attrs["endElement"] = end[0]
        ET.SubElement(links, _q(SSD_NS, "Connection"), dict(sorted(attrs.items())))

    for k, name in enumerate(spec.reads, start=1):
        link(("plant", name), ("controller", f"v[{k}]"))
    for k, name in enumerate(spec.inputs, start=1):
        link(("controller", f"u[{k}]"), ("plant", name))
    for k, name in enumerate(spec.disturbances, start=1):
        link((None, f"w[{k}]"), ("plant", name))
    for k, name in enumerate(spec.outputs, start=1):
        link(("plant", name), (None, f"y[{k}]"))
    ET.SubElement(root, _q(SSD_NS, "DefaultExperiment"), {"startTime": "0.0", "stopTime": repr(spec.stop_time)})
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def loop_ssv(spec: LoopSpec) -> str:
    """The ``resources/modes.ssv`` text: the modes and the initial state (module docstring)."""
    ET.register_namespace("ssv", SSV_NS)
    root = ET.Element(_q(SSV_NS, "ParameterSet"), {"version": "1.0", "name": "modes"})
    params = ET.SubElement(root, _q(SSV_NS, "Parameters"))
    values = [(f"plant.{name}", typ, value) for name, typ, value in spec.parameters]
    values.append(("controller.fdi_mode", "Integer", str(spec.fdi_mode)))
    for name, typ, value in values:
        p = ET.SubElement(params, _q(SSV_NS, "Parameter"), {"name": name})
        ET.SubElement(p, _q(SSV_NS, typ), {"value": value})
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_loop_ssp(spec: LoopSpec, plant_fmu: Path, controller_fmu: Path, dest: Path) -> Path:
    """Write the SSP archive ``dest`` atomically (:func:`~ftc_verify.plants.build.write_zip`):
    ``SystemStructure.ssd``, ``resources/modes.ssv`` and the two FMUs; returns ``dest``."""
    members = [("SystemStructure.ssd", loop_ssd(spec).encode(), 0o644),
               ("resources/modes.ssv", loop_ssv(spec).encode(), 0o644),
               ("resources/plant.fmu", Path(plant_fmu).read_bytes(), 0o644),
               ("resources/controller.fmu", Path(controller_fmu).read_bytes(), 0o644)]
    write_zip(Path(dest), members)
    return Path(dest)


def _value_text(value: Any, typ: str, where: str) -> str:
    if typ == "Real":
        return repr(float(value))
    if typ == "Integer":
        return str(int(value))
    if typ == "Boolean":
        return "true" if bool(value) else "false"
    raise ValidationError(f"{where}: an FMU variable of type {typ} cannot be an SSP parameter here "
                          "(Real, Integer and Boolean can)")


def loop_spec(mapping: Any, types: dict[str, str], controller: Controller, *, fault_mode: int, fdi_mode: int,
              x0: Sequence[float] | None, step: float, stop_time: float, name: str) -> LoopSpec:
    """The :class:`LoopSpec` of a plant map's
    :class:`~ftc_verify.plants.fault_map.FaultInjectionMap` ``mapping`` (``types``: the
    plant FMU's variable types by name) and ``controller``, in the 1-based modes given.

    Raises
    ------
    ValidationError
        For a map with an operating point (the SSP loop has no offsets), a controller
        reading ``y_m`` the map does not name, an ``x0`` the map cannot set, a fault
        variable of another type.
    """
    op = mapping.operating_point
    if op is not None and not op.is_zero():
        raise ValidationError("plant map: an operating point (deviation variables) cannot be expressed in the SSP "
                              "loop, which connects the FMUs' absolute values")
    reads = tuple(mapping.measured) if controller.measures == "output" else tuple(mapping.states)
    if controller.measures == "output" and not reads:
        raise ValidationError("plant map: the controller reads y_m, but the map names no measured outputs")
    params: list[tuple[str, str, str]] = []
    values = mapping.values_for(fault_mode - 1)
    for var, value in zip(mapping.fault, values):
        typ = types.get(var, "Real")
        params.append((var, typ, _value_text(value, typ, f"fault variable {var!r}")))
    if x0 is not None:
        if len(mapping.initial_states) != len(x0):
            raise ValidationError(f"--x0: {len(x0)} values, but the plant map names {len(mapping.initial_states)} "
                                  "initial_states")
        params += [(var, "Real", repr(float(v))) for var, v in zip(mapping.initial_states, x0)]
    for var, value in mapping.parameters:
        typ = types.get(var, "Real")
        params.append((var, typ, _value_text(value, typ, f"parameter {var!r}")))
    return LoopSpec(inputs=tuple(mapping.inputs), disturbances=tuple(mapping.disturbances),
                    outputs=tuple(mapping.outputs), reads=reads, parameters=tuple(params), fault_mode=fault_mode,
                    fdi_mode=fdi_mode, step=step, stop_time=stop_time, name=name)


def jacobi_reference(system: FTCSystem, controller: Controller, *, fault_mode: int, fdi_mode: int,
                     x0: Sequence[float], step: float, steps: int,
                     w: Callable[[float], Sequence[float]] | None = None) -> Matrix:
    r"""The loop a Jacobi SSP master (FMPy's ``simulate_ssp``) runs on the archive of
    :func:`write_loop_ssp` for the system's linear plant (``Delta = 0``), computed from the
    simulators' discretisations: the recursion of the module docstring, one row
    :math:`x(t_{k+1})` per round, ``steps`` rows (FMPy's row ``k`` holds the outputs
    after round ``k``). ``w(t)``: the system inputs FMPy's ``input`` gives (zero when
    ``None``); ``fault_mode``, ``fdi_mode`` 1-based; the controller state starts at 0."""
    from ..simulation.discretise import controller_zoh, zoh_matrices

    mode, j = system.modes[fault_mode - 1], fdi_mode - 1
    phi, gb, gd = zoh_matrices(mode.A, mode.B, mode.D, step)
    meas = np.eye(mode.n) if controller.measures == "state" else mode.measured
    nc = controller.n_c
    if nc:
        phic, gamc = (a[0] for a in controller_zoh(controller, [j], [step]))
    x, xc = np.asarray(x0, dtype=float), np.zeros(nc)
    cu, cv, cw = np.zeros(mode.B.shape[1]), np.zeros(meas.shape[0]), np.zeros(mode.D.shape[1])
    out = np.empty((steps, mode.n))
    for k in range(steps):
        wk = np.zeros(mode.D.shape[1]) if w is None else np.asarray(w(k * step), dtype=float)
        x = phi @ x + gb @ cu + gd @ cw
        if nc:
            xc = phic @ xc + gamc @ cv
        cu = controller.Cc[j] @ xc + controller.Dc[j] @ cv if nc else controller.Dc[j] @ cv
        cv, cw = meas @ x, wk
        out[k] = x
    return out
