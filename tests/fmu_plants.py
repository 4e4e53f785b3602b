"""Small plant FMUs that misbehave, built here for the contract tests (issue 22).

Each is a one-state ODE FMU (``ftc_verify.plants.ode_fmu``) ``x' = -x + k u + w`` with
outputs ``y_meas = y_out = x``, a fault parameter ``k`` (1 nominal, 0.5 weak), its plant
map, the linear system file of the map and a stabilising state-feedback gain, except:

* ``"crash"``: the right-hand side dereferences NULL once ``t > 2`` (a segfault inside
  ``fmi2DoStep``);
* ``"fail"``: the right-hand side takes ``sqrt(2 - t)`` (NaN once ``t > 2``: the FMU's
  ``fmi2DoStep`` returns ``fmi2Error`` with a log message);
* ``"stiff"``: a second state ``z' = -1e6 (z - x)`` makes every ``fmi2DoStep`` take
  thousands of explicit Runge-Kutta steps (the FMU's time dominates a run);
* ``"ok"``: the plain plant;
* ``"early"``: ``x' = 1 + x^2 + k u + w`` plus ``0 sqrt(-t)``: no stationary point at
  ``u = w = 0`` (``linearize --trim`` fails), and every ``fmi2DoStep`` returns ``fmi2Error``
  (NaN as soon as ``t > 0``) while the derivatives at ``t = 0`` are fine;
* ``"kink"``: ``x' = -x + k u + w - |x - 7.5e-6|``: not differentiable within the central
  difference steps of ``linearize``, whose error estimate then exceeds its stated fraction.
"""

from __future__ import annotations

from pathlib import Path

from ftc_verify.plants.ode_fmu import OdeFmuSpec, OdeVariable, build_ode_fmu

__all__ = ["KINDS", "build_plant"]

KINDS = ("ok", "crash", "fail", "stiff", "early", "kink")

_RHS = {
    "ok": "dx[0] = -x[0] + p[0] * u[0] + u[1];",
    "crash": ("if (t > 2.0) { volatile double *nowhere = 0; dx[0] = *nowhere; return; }\n"
              "    dx[0] = -x[0] + p[0] * u[0] + u[1];"),
    "fail": "dx[0] = -x[0] + p[0] * u[0] + u[1] + 0.0 * sqrt(2.0 - t);",
    "stiff": "dx[0] = -x[0] + p[0] * u[0] + u[1];\n    dx[1] = -1e6 * (x[1] - x[0]);",
    "early": "dx[0] = 1.0 + x[0] * x[0] + p[0] * u[0] + u[1] + 0.0 * sqrt(-t);",
    "kink": "dx[0] = -x[0] + p[0] * u[0] + u[1] - fabs(x[0] - 7.5e-6);",
}

_SOURCE = """#include <math.h>
#include "ode_model.h"

const int ODE_NX = {nx}, ODE_NU = 2, ODE_NP = 1, ODE_NY = 2;
const int ODE_HAS_JACOBIAN = 0;

void ode_rhs(double t, const double *x, const double *u, const double *p, double *dx) {{
    (void)t;
    {rhs}
}}

void ode_out(double t, const double *x, const double *u, const double *p, double *y) {{
    (void)t, (void)u, (void)p;
    y[0] = x[0];
    y[1] = x[0];
}}

void ode_jac(double t, const double *x, const double *u, const double *p, double *dfdx,
             double *dfdu, double *dgdx, double *dgdu) {{
    (void)t, (void)x, (void)u, (void)p, (void)dfdx, (void)dfdu, (void)dgdx, (void)dgdu;
}}
"""

_CHAIN = """[chain]
alpha = [[-0.5, 0.5], [1.0, -1.0]]
beta_min = [[0.0, 2.0], [2.5, 0.0]]
beta_max = [[0.0, 3.0], [3.5, 0.0]]
"""


def _map(states: list[str]) -> str:
    quoted = ", ".join(f'"{s}"' for s in states)
    zeros = ", ".join("0.0" for _ in states)
    return f"""fmu = "plant.fmu"
name = "test-plant"
tolerance = 1e-6

[variables]
inputs = ["u"]
disturbances = ["w"]
states = [{quoted}]
measured = ["y_meas"]
performance = ["y_out"]
initial_states = [{quoted}]

[operating_point]
states = [{zeros}]

[[fault]]
name = "nominal"
set = {{ k = 1.0 }}

[[fault]]
name = "weak"
set = {{ k = 0.5 }}

""" + _CHAIN


def _system(stiff: bool) -> str:
    modes = []
    for k in (1.0, 0.5):
        if stiff:
            modes.append(f"[[mode]]\nA = [[-1.0, 0.0], [1e6, -1e6]]\nB = [[{k}], [0.0]]\nC = [[1.0, 0.0]]\n"
                         "D = [[1.0], [0.0]]\n")
        else:
            modes.append(f"[[mode]]\nA = [[-1.0]]\nB = [[{k}]]\nC = [[1.0]]\nD = [[1.0]]\n")
    return 'name = "test-plant"\n\n' + _CHAIN + "\n" + "\n".join(modes)


def build_plant(folder: Path, kind: str) -> Path:
    """Write ``plant.fmu``, ``plant.toml`` (the map), ``system.toml`` and ``K.toml`` of the
    plant ``kind`` (module docstring) into ``folder``; returns ``folder``."""
    if kind not in KINDS:
        raise ValueError(f"kind: {kind!r} is not one of {KINDS}")
    folder.mkdir(parents=True, exist_ok=True)
    stiff = kind == "stiff"
    states = ["x", "z"] if stiff else ["x"]
    spec = OdeFmuSpec(
        model_name=f"Plant_{kind}",
        states=tuple(OdeVariable(s) for s in states),
        inputs=(OdeVariable("u"), OdeVariable("w")),
        parameters=(OdeVariable("k", 1.0),),
        outputs=(OdeVariable("y_meas"), OdeVariable("y_out")),
        c_source=_SOURCE.format(nx=len(states), rhs=_RHS[kind]),
        description=f"test plant ({kind})",
    )
    build_ode_fmu(spec, folder / "plant.fmu")
    (folder / "plant.toml").write_text(_map(states))
    (folder / "system.toml").write_text(_system(stiff))
    gain = "[[-0.5, 0.0]]" if stiff else "[[-0.5]]"
    (folder / "K.toml").write_text(f"[[gain]]\nK = {gain}\n[[gain]]\nK = {gain}\n")
    return folder
