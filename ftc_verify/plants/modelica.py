r"""FMI 2.0 FMUs (Model Exchange + Co-Simulation) from a flat Modelica model, without a Modelica tool.

The ``.mo`` text is scanned for refused constructs
(:func:`~ftc_verify.plants.modelica_checks.scan_source`), parsed and flattened by **pymoca
0.12** into a CasADi DAE residual :math:`F(t, x, \dot x, w, u, p) = 0` (states :math:`x`,
algebraic variables :math:`w`, Real inputs :math:`u`, Real parameters :math:`p`) and solved
for :math:`z = (\dot x, w)` block by block: the structural block-triangular form of
:math:`\partial F/\partial z` orders the blocks, and each block must be *linear* in its own
unknowns (an assignment, or a linear system such as a mass matrix, solved symbolically).
The explicit ODE :math:`\dot x = f(t, x, u, p)`, :math:`y = g(t, x, u, p)` (:math:`y` the
Modelica ``output`` variables) and its exact Jacobians are written to C by CasADi's code
generator and wrapped into the contract of ``fmus/ode/ode_model.h`` for
:func:`~ftc_verify.plants.ode_fmu.build_ode_fmu`.

Variables: states are the variables under ``der()`` (``start`` evaluated with the parameter
values when it is an expression), inputs the ``input Real`` variables, parameters the Real
``parameter`` variables with a value. A parameter bound to an expression of parameters is
substituted (pymoca's ``replace_parameter_expressions``), as are ``constant`` values and
Integer/Boolean parameters; none of those is exposed. Parameters are ``tunable`` unless
declared ``final`` or annotated ``Evaluate=true`` (then ``fixed``). Descriptions and units
come from the declarations; FMU names are the Modelica names with ``.``, ``[``, ``,`` turned
into ``_`` (``x[1]`` becomes ``x_1``; an output that is the state ``x`` becomes ``x_out``).
The ``experiment`` annotation sets the default experiment.

:func:`build_modelica_fmu` checks the FMU before returning it: its derivatives, outputs and
directional derivatives (read through fmpy) must equal CasADi's evaluation to
:data:`CHECK_RTOL` at the start point and at a random nearby point.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..errors import FMUError, ValidationError
from .modelica_checks import (check_start_point, compare_fmu, declaration_line, evaluate_parameters,
                               experiment_settings, scan_source)
from .ode_fmu import OdeFmuSpec, OdeVariable, build_ode_fmu

__all__ = ["CHECK_RTOL", "PYMOCA_OPTIONS", "ModelicaTranslation", "translate_modelica", "modelica_spec",
           "build_modelica_fmu", "check_modelica_fmu"]

#: Relative agreement (to the largest entry of each compared vector) of the FMU with CasADi.
CHECK_RTOL = 1e-12
#: pymoca compiler options of the route.
PYMOCA_OPTIONS = {"expand_vectors": True, "replace_constant_values": True, "replace_parameter_expressions": True,
                  "check_balanced": False}
_INSTALL = "pip install 'ftc-verify[modelica]' (pymoca 0.12 and CasADi >=3.7,<3.8)"


def _backend() -> SimpleNamespace:
    """pymoca and CasADi, imported lazily; :class:`FMUError` when missing or incompatible."""
    try:
        import casadi
        import pymoca
        from pymoca import ast, parser
        from pymoca.backends.casadi import generator
        from pymoca.backends.casadi._options import _merge_default_options
        from pymoca.tree import flatten
    except ImportError as exc:
        raise FMUError(f"building an FMU from Modelica needs pymoca and CasADi ({exc}): {_INSTALL}") from None
    if generator.OP_MAP.get("/") == "__div__" and not hasattr(casadi.MX, "__div__"):
        raise FMUError(f"pymoca {pymoca.__version__} emits MX.__div__, which CasADi {casadi.__version__} no longer "
                       f"has (removed in 3.8): {_INSTALL}")
    return SimpleNamespace(ca=casadi, pymoca=pymoca, ast=ast, parser=parser, generator=generator, flatten=flatten,
                           options=_merge_default_options(dict(PYMOCA_OPTIONS)))


@dataclass(frozen=True)
class ModelicaTranslation:
    """A translated model: the spec and the CasADi functions its C source was generated from.

    Attributes
    ----------
    spec : OdeFmuSpec
        The spec (C source inside).
    rhs, out, jac : casadi.Function
        ``(t, x, u, p) -> dx``, ``-> y`` and ``-> (dfdx^T, dfdu^T, dgdx^T, dgdu^T)``.
    mo_file : Path
        The source file.
    """

    spec: OdeFmuSpec
    rhs: Any
    out: Any
    jac: Any
    mo_file: Path


# ------------------------------------------------------------------------------------------
# pymoca
# ------------------------------------------------------------------------------------------


def _load(b: SimpleNamespace, path: Path, text: str, model: str) -> tuple[Any, Any]:
    """``(pymoca CasADi model, flattened class)``; pymoca failures become ValidationError."""
    try:
        tree = b.parser.parse(text)
    except Exception as exc:
        raise ValidationError(f"{path}: pymoca cannot parse the file: {exc}") from None
    try:
        flat = b.flatten(tree, b.ast.ComponentRef.from_string(model))
        gen = b.generator.Generator(flat, model, dict(b.options))
        b.generator.GeneratorWalker().walk(gen, flat)
        gen.model.simplify(dict(b.options))
        return gen.model, flat.classes[model]
    except Exception as exc:
        raise ValidationError(f"{path}: pymoca cannot translate the model {model!r}: "
                              f"{type(exc).__name__}: {exc}") from None


def _c_name(name: str) -> str:
    """FMU/C name of a Modelica name: ``a.b[1,2]`` -> ``a_b_1_2``."""
    return re.sub(r"_+$", "", re.sub(r"[.\[\],\s]+", "_", name))


def _declaration(flat_class: Any, name: str) -> Any:
    """The flattened symbol declaring ``name`` (array elements map to the array)."""
    symbols = flat_class.symbols
    for key in (name, re.sub(r"\[[^\]]*\]$", "", name), re.sub(r"\[[^\]]*\]", "", name)):
        if key in symbols:
            return symbols[key]
    return None


def _meta(flat_class: Any, name: str) -> tuple[str, str, bool]:
    """``(description, unit, final)`` of ``name`` from its declaration."""
    sym = _declaration(flat_class, name)
    if sym is None:
        return "", "", False
    unit = getattr(getattr(sym, "unit", None), "value", None)
    return str(sym.comment or ""), unit if isinstance(unit, str) else "", bool(sym.final)


def _number(ca: Any, value: Any, symbols: list[Any], values: list[float]) -> float:
    """A metadata value as a float (MX expressions evaluated at the parameter values); NaN
    when it is not a scalar number."""
    try:
        if isinstance(value, ca.MX):
            if not value.is_constant():
                value = ca.Function("value", [ca.veccat(*symbols)], [value])(values)
            value = ca.DM(value)
        if isinstance(value, ca.DM):
            return float(value) if value.numel() == 1 else float("nan")
        return float(value)
    except (RuntimeError, TypeError, ValueError):
        return float("nan")


def _where(path: Path, text: str, name: str) -> str:
    line = declaration_line(text, name)
    return f"{path}:{line}" if line else str(path)


def _parameters(b: SimpleNamespace, m: Any, path: Path, text: str) -> tuple[list[Any], list[float], list[int]]:
    """``(symbols, values, indices of the Real ones)`` of pymoca's parameters; a parameter
    without a finite value (pymoca's NaN, e.g. when it has only ``start``) is refused."""
    values, real = [], []
    for k, v in enumerate(m.parameters):
        value = _number(b.ca, v.value, [], [])
        if not np.isfinite(value):
            hint = ("it has only a start value; bind it: 'parameter Real p = value'"
                    if type(v.start).__name__ != "_DefaultValue" else "bind it: 'parameter Real p = value'")
            raise ValidationError(f"{_where(path, text, v.symbol.name())}: parameter {v.symbol.name()!r} has no "
                                  f"finite value ({hint})")
        values.append(value)
        if v.python_type is float:
            real.append(k)
    return [v.symbol for v in m.parameters], values, real


def _variables(b: SimpleNamespace, m: Any, flat_class: Any, path: Path, text: str) -> dict[str, Any]:
    """Names, start values and metadata of the FMU's states, inputs, parameters, outputs."""
    p_syms, p_values, real = _parameters(b, m, path, text)
    for group, what in ((m.inputs, "input"), (m.alg_states, "variable")):
        for v in group:
            if v.python_type is not float:
                kind = {bool: "Boolean", int: "Integer"}.get(v.python_type, v.python_type.__name__)
                raise ValidationError(f"{_where(path, text, v.symbol.name())}: the {kind} {what} "
                                      f"{v.symbol.name()!r} is not supported (Real only)")
    fixed = evaluate_parameters(text)

    def var(v: Any, start: float, **extra: Any) -> OdeVariable:
        name = v.symbol.name()
        if not np.isfinite(start):
            raise ValidationError(f"{_where(path, text, name)}: the start value of {name!r} is not a finite "
                                  "number computable from the parameter values")
        desc, unit, _ = _meta(flat_class, name)
        return OdeVariable(_c_name(name), start, desc, unit, **extra)

    states = [var(v, _number(b.ca, v.start, p_syms, p_values)) for v in m.states]
    inputs = [var(v, _number(b.ca, v.start, p_syms, p_values)) for v in m.inputs]
    params = []
    for k in real:
        v = m.parameters[k]
        final = _meta(flat_class, v.symbol.name())[2] or re.split(r"[.\[]", v.symbol.name())[0] in fixed
        params.append(var(v, p_values[k], tunable=not final))
    outputs, taken = [], {x.name for x in states}
    for name in m.outputs:  # an output that is a state is exposed as <name>_out
        desc, unit, _ = _meta(flat_class, name)
        c_name = _c_name(name) + ("_out" if _c_name(name) in taken else "")
        outputs.append(OdeVariable(c_name, 0.0, desc or (f"output {name}" if c_name != _c_name(name) else ""), unit))
    return dict(states=states, inputs=inputs, parameters=params, outputs=outputs, p_values=p_values, real=real)


# ------------------------------------------------------------------------------------------
# DAE -> explicit ODE
# ------------------------------------------------------------------------------------------


def _residual(ca: Any, m: Any, v: dict[str, Any], where: str) -> tuple[Any, dict[str, Any]]:
    """The SX residual ``F`` (Integer/Boolean parameters replaced by their values) and its
    symbols ``t, x, xdot, w, u, p`` (``p`` the Real parameters of the FMU)."""
    try:
        f = m.dae_residual_function.expand()
    except RuntimeError as exc:
        raise ValidationError(f"{where}: CasADi cannot expand the residual to scalar form: {exc}") from None
    nx, nw, nu = len(m.states), len(m.alg_states), len(m.inputs)
    if nx == 0:
        raise ValidationError(f"{where}: the model has no states (no der()); an ODE FMU needs at least one")
    s = {"t": ca.SX.sym("t"), "x": ca.SX.sym("x", nx), "xdot": ca.SX.sym("xdot", nx), "w": ca.SX.sym("w", nw),
         "u": ca.SX.sym("u", nu), "p": ca.SX.sym("p", len(v["real"]))}
    position = {k: j for j, k in enumerate(v["real"])}
    p_all = [s["p"][position[k]] if k in position else ca.SX(value) for k, value in enumerate(v["p_values"])]
    args = [s["t"], s["x"], s["xdot"], s["w"], s["u"], ca.SX(f.size1_in(5), 1),
            ca.vertcat(*p_all) if p_all else ca.SX(0, 1)]
    if f.size1_in(5) or any(f.numel_in(k) != a.numel() for k, a in enumerate(args)):
        raise FMUError(f"{where}: unexpected pymoca residual signature {f}")
    res = f.call(args)[0] if f.n_out() else ca.SX(0, 1)
    return ca.vec(res), s


def _solve_block(ca: Any, res: Any, z: Any, rows: list[int], cols: list[int], known: dict[int, Any],
                 names: list[str], where: str) -> tuple[Any, Any]:
    """Solve the equations ``rows`` for the unknowns ``cols`` (the others in ``known``);
    ``(solution, coefficient matrix)``, refusing a block that is nonlinear in its unknowns."""
    fr = ca.vertcat(*[res[r] for r in rows])
    need = [k for k in sorted(known) if ca.depends_on(fr, z[k])]
    if need:
        fr = ca.substitute(fr, ca.vertcat(*[z[k] for k in need]), ca.vertcat(*[known[k] for k in need]))
    zc = ca.vertcat(*[z[c] for c in cols])
    jc = ca.jacobian(fr, zc)
    if ca.depends_on(jc, zc):
        what = ", ".join(names[c] for c in cols)
        raise ValidationError(f"{where}: the equations for {what} are nonlinear in them (an implicit equation "
                              "or a nonlinear algebraic loop); only unknowns that enter their equations "
                              "linearly can be solved without a nonlinear solver")
    f0 = ca.substitute(fr, zc, ca.SX.zeros(len(cols)))
    sol = -f0 / jc if len(cols) == 1 else ca.solve(jc, -f0)
    return sol, jc


def _solve(ca: Any, res: Any, z: Any, names: list[str], where: str) -> tuple[Any, list[tuple[list[str], Any]]]:
    """Solve ``res(z) = 0`` for ``z`` block by block (block-triangular form of d res/dz).

    Returns the solution and ``[(unknown names, coefficient matrix), ...]`` per block.
    """
    n = z.numel()
    if res.numel() != n:
        raise ValidationError(f"{where} is not balanced: {res.numel()} equation{'s' * (res.numel() != 1)} for {n} "
                              f"unknown{'s' * (n != 1)} ({', '.join(names)})")
    sp = ca.jacobian(res, z).sparsity()
    rank = ca.sprank(sp)
    if rank < n:
        raise ValidationError(f"{where}: the equations cannot be solved for {', '.join(names)} (structural "
                              f"rank {rank} of {n}): a higher-index DAE or equations that do not determine "
                              "every unknown")
    _, rowperm, colperm, rowblock, colblock, *_ = sp.btf()
    row_cols: dict[int, set[int]] = {}
    for r, c in zip(*sp.get_triplet()):
        row_cols.setdefault(r, set()).add(c)
    pending = list(range(len(rowblock) - 1))
    known: dict[int, Any] = {}
    blocks = []
    while pending:
        for k in pending:
            rows, cols = rowperm[rowblock[k]:rowblock[k + 1]], colperm[colblock[k]:colblock[k + 1]]
            if set().union(*(row_cols.get(r, set()) for r in rows)) - set(cols) <= known.keys():
                break
        else:  # pragma: no cover - the block-triangular form always has a solvable block
            raise FMUError(f"{where}: no solvable block in the block-triangular form")
        pending.remove(k)
        sol, jc = _solve_block(ca, res, z, rows, cols, known, names, where)
        known.update({c: sol[j] for j, c in enumerate(cols)})
        blocks.append(([names[c] for c in cols], jc))
    return ca.vertcat(*[known[k] for k in range(n)]), blocks


def explicit_ode(ca: Any, m: Any, v: dict[str, Any], where: str) -> tuple[Any, Any, Any, list[int]]:
    """CasADi functions ``rhs``, ``out``, ``jac`` of ``(t, x, u, p)`` solving the DAE of ``m``,
    and the indices of the parameters neither depends on.

    ``jac`` returns ``dfdx^T, dfdu^T, dgdx^T, dgdu^T`` dense (column-major storage of the
    transpose = the row-major layout of ``ode_model.h``).
    """
    res, s = _residual(ca, m, v, where)
    states = [x.symbol.name() for x in m.states]
    algebraic = [w.symbol.name() for w in m.alg_states]
    sol, blocks = _solve(ca, res, ca.vertcat(s["xdot"], s["w"]), [f"der({x})" for x in states] + algebraic, where)
    nx = len(states)
    dx, w = sol[:nx], sol[nx:]
    ys = [s["x"][states.index(n)] if n in states else w[algebraic.index(n)] for n in m.outputs]
    y = ca.vertcat(*ys) if ys else ca.SX(0, 1)
    args, names = [s["t"], s["x"], s["u"], s["p"]], ["t", "x", "u", "p"]
    rhs = ca.Function("ftc_rhs", args, [dx], names, ["dx"])
    out = ca.Function("ftc_out", args, [y], names, ["y"])
    jacs = [ca.densify(ca.jacobian(a, b)).T for a in (dx, y) for b in (s["x"], s["u"])]
    jac = ca.Function("ftc_jac", args, jacs, names, ["dfdx_t", "dfdu_t", "dgdx_t", "dgdu_t"])
    start = [0.0] + [np.array([q.start for q in v[g]], dtype=float) for g in ("states", "inputs", "parameters")]
    labels = ([f"der({x.name})" for x in v["states"]], [q.name for q in v["outputs"]], ["the Jacobian"] * 4)
    check_start_point(ca, args, blocks, [rhs, out, jac], labels, start, where)
    unused = [k for k in range(s["p"].numel()) if not ca.depends_on(ca.vertcat(dx, y), s["p"][k])]
    return rhs, out, jac, unused


# ------------------------------------------------------------------------------------------
# C source
# ------------------------------------------------------------------------------------------

_WRAPPER = """
/* ---- ode_model.h contract, wrapping the CasADi functions above ---------------------- */
#include "ode_model.h"

const int ODE_NX = {nx}, ODE_NU = {nu}, ODE_NP = {np}, ODE_NY = {ny};
const int ODE_HAS_JACOBIAN = 1;

typedef int (*ftc_casadi_fn)(const casadi_real **, casadi_real **, casadi_int *, casadi_real *, int);

static void ftc_eval(ftc_casadi_fn f, double t, const double *x, const double *u, const double *p,
                     double **out, int n_out) {{
    const casadi_real *arg[{sz_arg}] = {{&t, x, u, p}};
    casadi_real *res[{sz_res}] = {{0}};
    casadi_int iw[{sz_iw}];
    casadi_real w[{sz_w}];
    int k;
    for (k = 0; k < n_out; ++k) res[k] = out[k];
    (void)f(arg, res, iw, w, 0);
}}

void ode_rhs(double t, const double *x, const double *u, const double *p, double *dx) {{
    double *out[1] = {{dx}};
    ftc_eval(ftc_rhs, t, x, u, p, out, 1);
}}

void ode_out(double t, const double *x, const double *u, const double *p, double *y) {{
    double *out[1] = {{y}};
    ftc_eval(ftc_out, t, x, u, p, out, 1);
}}

void ode_jac(double t, const double *x, const double *u, const double *p, double *dfdx, double *dfdu,
             double *dgdx, double *dgdu) {{
    double *out[4] = {{dfdx, dfdu, dgdx, dgdu}};
    ftc_eval(ftc_jac, t, x, u, p, out, 4);
}}
"""


def _c_source(b: SimpleNamespace, functions: list[Any], sizes: dict[str, int], title: str) -> str:
    """CasADi's C code of ``functions`` (one file, no header) plus the ode_model.h wrapper."""
    ca = b.ca
    cg = ca.CodeGenerator("ftc_modelica", {"with_header": False, "casadi_int": "int", "casadi_real": "double"})
    for f in functions:
        cg.add(f)
    work = {f"sz_{k}": max(n, *(getattr(f, f"sz_{k}")() for f in functions))
            for k, n in (("arg", 4), ("res", 4), ("iw", 1), ("w", 1))}
    head = (f"/* {title}\n * generated by ftc-verify with pymoca {b.pymoca.__version__} and CasADi "
            f"{ca.__version__}: do not edit */\n"
            "#if defined(__GNUC__)\n#pragma GCC diagnostic ignored \"-Wunused-parameter\"\n"
            "#pragma GCC diagnostic ignored \"-Wunused-variable\"\n#endif\n")
    return head + cg.dump() + _WRAPPER.format(**sizes, **work)


# ------------------------------------------------------------------------------------------
# Public API
# ------------------------------------------------------------------------------------------


def _read(mo_file: str | Path, model: str | None) -> tuple[Path, str, str]:
    path = Path(mo_file)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValidationError(f"{path}: cannot read the Modelica file: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise ValidationError(f"{path}: not UTF-8 text: {exc}") from None
    model = path.stem if model is None else model
    if not isinstance(model, str) or not re.fullmatch(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*", model):
        raise ValidationError(f"{path}: model name {model!r} is not a Modelica class name")
    return path, text, model


def translate_modelica(mo_file: str | Path, *, model: str | None = None) -> ModelicaTranslation:
    """Translate ``model`` of ``mo_file`` into an :class:`OdeFmuSpec` and its CasADi functions.

    Parameters
    ----------
    mo_file : str or Path
        The ``.mo`` file (UTF-8).
    model : str, optional
        The model (class) to translate; default the file's stem.

    Returns
    -------
    ModelicaTranslation

    Raises
    ------
    ValidationError
        On a refused construct, a pymoca failure, an unbalanced or non-explicit model, a
        parameter without value, or a non-finite value at the start point.
    FMUError
        When pymoca or CasADi is missing or incompatible.
    """
    path, text, model = _read(mo_file, model)
    scan_source(path, text)
    b = _backend()
    m, flat_class = _load(b, path, text, model)
    v = _variables(b, m, flat_class, path, text)
    where = f"{path}: model {model!r}"
    rhs, out, jac, unused = explicit_ode(b.ca, m, v, where)
    params = list(v["parameters"])
    for k in unused:  # e.g. a parameter that only sets start values (fixed at build time)
        params[k] = dataclasses.replace(params[k], description=(params[k].description + " [not used by the "
                                        "equations; start values computed from it are fixed in the FMU]").strip())
    sizes = dict(nx=len(v["states"]), nu=len(v["inputs"]), np=len(params), ny=len(v["outputs"]))
    try:
        spec = OdeFmuSpec(
            model_name=_c_name(model), states=tuple(v["states"]), inputs=tuple(v["inputs"]),
            parameters=tuple(params), outputs=tuple(v["outputs"]), has_jacobian=True,
            description=str(getattr(flat_class, "comment", "") or f"{model} (from {path.name})"),
            c_source=_c_source(b, [rhs, out, jac], sizes, f"{model} from {path.name}"), **experiment_settings(text))
    except ValidationError as exc:  # e.g. x_1 and x[1] both become x_1
        raise ValidationError(f"{where}: {exc}") from None
    return ModelicaTranslation(spec, rhs, out, jac, path)


def modelica_spec(mo_file: str | Path, *, model: str | None = None) -> OdeFmuSpec:
    """The :class:`OdeFmuSpec` (C source inside) of ``model`` in ``mo_file``
    (see :func:`translate_modelica`)."""
    return translate_modelica(mo_file, model=model).spec


def build_modelica_fmu(mo_file: str | Path, *, model: str | None = None, dest: str | Path | None = None) -> Path:
    """Build the FMI 2.0 FMU (ME + CS) of ``model`` in ``mo_file``, checked against CasADi.

    Parameters
    ----------
    mo_file : str or Path
        The ``.mo`` file.
    model : str, optional
        The model to translate; default the file's stem.
    dest : str or Path, optional
        The ``.fmu`` file or an existing folder (see
        :func:`~ftc_verify.plants.ode_fmu.build_ode_fmu`); default in the cache.

    Returns
    -------
    Path
        The FMU, after :func:`check_modelica_fmu` passed.

    Raises
    ------
    ValidationError
        See :func:`translate_modelica`.
    FMUError
        When compiling fails, pymoca/CasADi are missing, or the FMU disagrees with CasADi.
    """
    translation = translate_modelica(mo_file, model=model)
    fmu = build_ode_fmu(translation.spec, None if dest is None else Path(dest))
    try:
        check_modelica_fmu(fmu, translation)
    except BaseException:  # a wrong FMU, or one interrupted before it was checked: never left behind
        fmu.unlink(missing_ok=True)
        raise
    return fmu


def check_modelica_fmu(fmu: str | Path, translation: ModelicaTranslation, seed: int = 0) -> None:
    """Compare the FMU's derivatives, outputs and directional derivatives with CasADi.

    Parameters
    ----------
    fmu : str or Path
        The FMU built from ``translation.spec``.
    translation : ModelicaTranslation
        Its translation (the CasADi functions are the reference).
    seed : int
        Seed of the random point: states, inputs and all parameters scaled by factors in
        [0.99, 1.01], time 0.37 (the other point is the start point at time 0).

    Raises
    ------
    FMUError
        When an entry differs by more than :data:`CHECK_RTOL` times the largest entry of its
        vector (derivatives, outputs, directional derivatives); names the first one.
    """
    compare_fmu(Path(fmu), translation, CHECK_RTOL, seed)
