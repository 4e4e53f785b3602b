r"""The ``LinearJumpPlant`` of a system as a flat Modelica model for the Modelica route.

:func:`linear_jump_modelica` writes, for one :class:`~ftc_verify.model.FTCSystem`, the plant

.. math::  \dot x = (A_r + A_{1,r} \Delta_1 A_{2,r}) x + (B_r + B_{1,r} \Delta_2 B_{2,r}) u + D_r w,
           \quad y = C_r x, \quad y_m = C_{y,r} x

(the model of ``fmus/modelica/LinearJumpPlant.mo``) in the form that
:func:`ftc_verify.plants.modelica.build_modelica_fmu` handles: scalar equations, the true
fault mode ``r`` a tunable Real parameter ``mode`` (1..m) selecting each mode's
coefficients through nested if-expressions (no array indexed by a variable, no Integer
input), and the entries of ``Delta1``, ``Delta2`` Real inputs. Its variables after the
route's renaming are ``x_k``, ``u_k``, ``w_k``, ``y_k``, ``ym_k``, ``Delta1_i_j``,
``Delta2_i_j`` and the parameter ``mode``; :func:`linear_jump_modelica_map` is the matching
:class:`~ftc_verify.plants.fault_map.FaultInjectionMap`.
"""

from __future__ import annotations

import numpy as np

from ..model.system import FTCSystem
from .fault_map import FaultInjectionMap
from .system_text import fmu_dims

__all__ = ["linear_jump_modelica", "linear_jump_modelica_map"]


def _select(values: list[float]) -> str:
    """``if mode < 1.5 then v1 elseif ... else vm`` (one coefficient per mode)."""
    if all(v == values[0] for v in values):
        return repr(float(values[0]))
    parts = [f"if mode < {k + 1.5!r} then {float(v)!r}" for k, v in enumerate(values[:-1])]
    return " else".join(parts) + f" else {float(values[-1])!r}"


def _row(coeffs: list[list[float]], names: list[str]) -> str:
    """``sum_j c_j(mode) * names[j]``, leaving out coefficients zero in every mode."""
    terms = [f"({_select(c)})*{n}" for c, n in zip(coeffs, names) if any(v != 0.0 for v in c)]
    return " + ".join(terms) if terms else "0"


def linear_jump_modelica(system: FTCSystem, name: str = "LinearJumpPlantModel") -> str:
    """The Modelica text of the plant of ``system`` (module docstring). The uncertain
    products are expanded symbolically: row ``i`` of ``A1 Delta1 A2 x`` is
    ``sum_{a,b} A1[i,a] Delta1[a,b] (A2 x)[b]``."""
    d = fmu_dims(system)
    md = system.modes
    x = [f"x[{k}]" for k in range(1, d.n + 1)]
    u = [f"u[{k}]" for k in range(1, d.nu + 1)]
    w = [f"w[{k}]" for k in range(1, d.nw + 1)]
    lines = [f"model {name}", '  "LinearJumpPlant of ftc-verify for one system (generated)"',
             f'  parameter Real mode(min = 1, max = {system.m}) = 1 "true fault mode r (1..m)";',
             f'  input Real u[{d.nu}] "control input";', f'  input Real w[{d.nw}] "disturbance input";']
    if d.q1:
        lines.append(f'  input Real Delta1[{d.q1}, {d.p1}] "uncertainty in A";')
    if d.q2:
        lines.append(f'  input Real Delta2[{d.q2}, {d.p2}] "uncertainty in B";')
    lines += [f'  Real x[{d.n}](each start = 0, each fixed = true) "state";',
              f'  output Real y[{d.ny}] "performance output y = C[r] x";',
              f'  output Real ym[{d.nym}] "measured output ym = Cy[r] x";', "equation"]
    for i in range(d.n):
        rhs = [_row([[m.A[i, j] for m in md] for j in range(d.n)], x),
               _row([[m.B[i, j] for m in md] for j in range(d.nu)], u),
               _row([[m.D[i, j] for m in md] for j in range(d.nw)], w)]
        for q, p, left, right, vec, delta in ((d.q1, d.p1, "A1", "A2", x, "Delta1"), (d.q2, d.p2, "B1", "B2", u, "Delta2")):
            for a in range(q):
                for b in range(p):
                    li = [_mat(m, left, d)[i, a] for m in md]
                    if not any(li):
                        continue
                    inner = _row([[_mat(m, right, d)[b, j] for m in md] for j in range(len(vec))], vec)
                    if inner != "0":
                        rhs.append(f"({_select(li)})*{delta}[{a + 1},{b + 1}]*({inner})")
        lines.append(f"  der(x[{i + 1}]) = " + " + ".join(t for t in rhs if t != "0") + ";"
                     if any(t != "0" for t in rhs) else f"  der(x[{i + 1}]) = 0;")
    for i in range(d.ny):
        lines.append(f"  y[{i + 1}] = {_row([[m.C[i, j] for m in md] for j in range(d.n)], x)};")
    for i in range(int(d.ny if d.nym is None else d.nym)):
        lines.append(f"  ym[{i + 1}] = {_row([[m.measured[i, j] for m in md] for j in range(d.n)], x)};")
    lines.append(f"end {name};")
    return "\n".join(lines) + "\n"


def _mat(mode: object, key: str, d: object) -> np.ndarray:
    """``A1`` .. ``B2`` of a mode, zero of the channel's shape when the mode has none."""
    val = getattr(mode, key)
    if val is not None:
        return np.asarray(val)
    n, nu = mode.A.shape[0], mode.B.shape[1]  # type: ignore[attr-defined]
    shape = {"A1": (n, d.q1), "A2": (d.p1, n), "B1": (n, d.q2), "B2": (d.p2, nu)}[key]  # type: ignore[attr-defined]
    return np.zeros(shape)


def linear_jump_modelica_map(system: FTCSystem) -> FaultInjectionMap:
    """The map of the FMU built from :func:`linear_jump_modelica` (names after the route's
    renaming: ``x[1]`` -> ``x_1``)."""
    d = fmu_dims(system)

    def names(prefix: str, count: int) -> tuple[str, ...]:
        return tuple(f"{prefix}_{k}" for k in range(1, count + 1))

    return FaultInjectionMap(
        fault=("mode",), fault_values=tuple((float(k),) for k in range(1, system.m + 1)),
        inputs=names("u", d.nu), states=names("x", d.n), disturbances=names("w", d.nw),
        outputs=names("y", d.ny), measured=names("ym", int(d.ny if d.nym is None else d.nym)),
        initial_states=names("x", d.n),
        delta1=tuple(f"Delta1_{i}_{j}" for i in range(1, d.q1 + 1) for j in range(1, d.p1 + 1)),
        delta2=tuple(f"Delta2_{i}_{j}" for i in range(1, d.q2 + 1) for j in range(1, d.p2 + 1)),
    )
