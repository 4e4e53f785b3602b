"""Checks of :mod:`ftc_verify.plants.modelica`: source scans, the start point, the built FMU.

The Modelica text is scanned *before* pymoca sees it, with comments and string literals
blanked out (line numbers preserved), so that a refused construct gives one
:class:`~ftc_verify.errors.ValidationError` naming the construct, the ``.mo`` file and
the line, instead of a pymoca traceback or, worse, a silently wrong model. After the
translation, :func:`check_start_point` refuses singular or non-finite values at the start
point, and :func:`compare_fmu` compares the compiled FMU with CasADi.
"""

from __future__ import annotations

import ctypes
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FMUError, ValidationError

__all__ = ["REFUSED_CONSTRUCTS", "blank_comments", "line_of", "declared_names", "scan_source",
           "evaluate_parameters", "declaration_line", "experiment_settings", "check_start_point",
           "compare_fmu"]

#: ``(regular expression, what it is, why)`` of every construct the route refuses.
REFUSED_CONSTRUCTS: tuple[tuple[str, str, str], ...] = (
    (r"\bwhen\b", "a 'when' clause", "discrete events are not supported (pure ODE FMUs)"),
    (r"\bpre\s*\(", "pre()", "discrete-time operators are not supported"),
    (r"\bsample\s*\(", "sample()", "discrete-time operators are not supported"),
    (r"\b(?:edge|change|reinit|initial|terminal)\s*\(", "an event operator", "events are not supported"),
    (r"\bnoEvent\s*\(", "noEvent()", "event control is not supported (the FMU has no event indicators)"),
    (r"\bsmooth\s*\(", "smooth()", "event control is not supported (the FMU has no event indicators)"),
    (r"\bdelay\s*\(", "delay()", "delay differential equations are not supported"),
    (r"\bzeros\s*\(", "zeros()", "the route keeps array constructors minimal; write fill(0.0, n)"),
    (r"\bfunction\b", "a user 'function' definition", "write the function body into the equations"),
    (r"\bexternal\b", "an external function", "external code is not supported"),
    (r"\balgorithm\b", "an 'algorithm' section", "write equations instead"),
    (r"\binitial\s+equation\b", "an 'initial equation' section",
     "the FMU starts from the states' start values; give start values instead"),
    (r"\bdiscrete\b", "a 'discrete' variable", "discrete variables are not supported"),
)

_IDENT = r"[A-Za-z_]\w*"
_SUBSCRIPT = re.compile(rf"(?<![\w.]){_IDENT}(?:\.{_IDENT})*\s*\[([^\[\]]*)\]")
_LOOP_INDEX = re.compile(rf"\bfor\s+({_IDENT})\s+in\b")
_INTEGER_DECL = re.compile(r"\b(?:parameter|constant)\s+Integer\b([^;]*);")
_PARAMETER_DECL = re.compile(rf"\bparameter\s+{_IDENT}(?:\.{_IDENT})*\s+([^;]*);")
_EVALUATE = re.compile(r"\bannotation\s*\([^;]*\bEvaluate\s*=\s*true\b")
_LEADING = re.compile(rf"\s*(?:(?:within|model|block|class|record|package|connector|partial|encapsulated|"
                      rf"end)\s+{_IDENT}\b|equation\b|public\b|protected\b|within\b|\"[^\"]*\")")
_DECLARATION = re.compile(rf"\s*((?:(?:final|parameter|constant|input|output|flow|stream|replaceable)\s+)*"
                          rf"{_IDENT}(?:\.{_IDENT})*)\s+(.*)\Z", re.DOTALL)
_SUBSCRIPT_FUNCTIONS = {"end", "size", "integer", "div", "mod", "rem", "min", "max", "abs", "ndims"}


def blank_comments(text: str) -> str:
    """``text`` with ``//`` and ``/* */`` comments and ``"..."`` strings replaced by spaces
    (newlines kept, so offsets and line numbers stay valid)."""
    out = list(text)
    pattern = re.compile(r'//[^\n]*|/\*.*?\*/|"(?:\\.|[^"\\])*"', re.DOTALL)
    for m in pattern.finditer(text):
        start = m.start() + (1 if m.group().startswith('"') else 0)
        end = m.end() - (1 if m.group().startswith('"') else 0)
        for k in range(start, end):
            if out[k] != "\n":
                out[k] = " "
    return "".join(out)


def line_of(text: str, offset: int) -> int:
    """1-based line number of character ``offset`` of ``text``."""
    return text.count("\n", 0, offset) + 1


def _strip_groups(text: str) -> str:
    """``text`` without (nested) ``(...)`` and ``{...}`` groups."""
    previous = None
    while previous != text:
        previous, text = text, re.sub(r"\([^()]*\)|\{[^{}]*\}", " ", text)
    return text


def declared_names(declaration: str) -> list[str]:
    """Names declared by the part of a component clause after its type name, e.g.
    ``'n(min=1) = 2, m = 3'`` gives ``['n', 'm']``; an ``annotation`` ends the list."""
    body = re.split(r"\bannotation\b", _strip_groups(declaration))[0]
    names = []
    for piece in body.split(","):
        m = re.match(rf"\s*({_IDENT})", piece)
        if m:
            names.append(m.group(1))
    return names


def _refuse(path: Path, text: str, offset: int, what: str, why: str) -> ValidationError:
    return ValidationError(f"{path}:{line_of(text, offset)}: {what} is not supported by the Modelica-to-FMU "
                           f"route: {why}")


def _scan_subscripts(path: Path, text: str) -> None:
    """Refuse 3-D (or higher) arrays and subscripts that use a variable."""
    allowed = set(_LOOP_INDEX.findall(text)) | _SUBSCRIPT_FUNCTIONS
    for m in _INTEGER_DECL.finditer(text):
        allowed.update(declared_names(m.group(1)))
    for m in _SUBSCRIPT.finditer(text):
        inside = m.group(1)
        if _strip_groups(inside).count(",") >= 2:
            raise _refuse(path, text, m.start(), f"the 3-D array {m.group().strip()!r}",
                          "arrays of at most two dimensions are supported")
        for name in re.finditer(rf"(?<![\w.]){_IDENT}\b(?!\s*\()", inside):
            if name.group() not in allowed:
                raise _refuse(path, text, m.start(), f"indexing by the variable {name.group()!r} in "
                              f"{m.group().strip()!r}",
                              "subscripts may use literals, for-loop indices and Integer parameters only")


def scan_source(path: Path, text: str) -> None:
    """Raise :class:`ValidationError` on the first refused construct of ``text``.

    Parameters
    ----------
    path : Path
        The ``.mo`` file (for the message).
    text : str
        Its content.

    Raises
    ------
    ValidationError
        ``<file>:<line>: <construct> is not supported by the Modelica-to-FMU route: <why>``
        for the first (in file order) of :data:`REFUSED_CONSTRUCTS`, a 3-D array or a
        subscript that uses a variable.
    """
    code = blank_comments(text)
    hits = []
    for pattern, what, why in REFUSED_CONSTRUCTS:
        m = re.search(pattern, code)
        if m:
            hits.append((m.start(), what, why))
    if hits:
        offset, what, why = min(hits)
        raise _refuse(path, code, offset, what, why)
    _scan_subscripts(path, code)


def evaluate_parameters(text: str) -> set[str]:
    """Names of parameters declared with ``annotation(Evaluate=true)`` (a regex scan:
    pymoca 0.12 drops component annotations)."""
    code = blank_comments(text)
    names: set[str] = set()
    for m in _PARAMETER_DECL.finditer(code):
        if _EVALUATE.search(m.group(0)):
            names.update(declared_names(m.group(1)))
    return names


def _statements(code: str) -> Iterator[tuple[int, str]]:
    """``(offset, text)`` of the ``;``-separated statements of ``code``, leading class
    headers and section keywords removed."""
    offset = 0
    for piece in code.split(";"):
        start = 0
        while True:
            m = _LEADING.match(piece, start)
            if not m:
                break
            start = m.end()
        yield offset + start, piece[start:]
        offset += len(piece) + 1


def declaration_line(text: str, name: str) -> int | None:
    """Line of the declaration of the component ``name`` (its first part before ``.`` or
    ``[``), or None when no declaration is found."""
    base = re.split(r"[.\[]", name)[0]
    code = blank_comments(text)
    for offset, statement in _statements(code):
        m = _DECLARATION.match(statement)
        if m and base in declared_names(m.group(2)):
            where = re.search(rf"\b{re.escape(base)}\b", statement[m.start(2):])
            return line_of(code, offset + m.start(2) + (where.start() if where else 0))
    return None


_EXPERIMENT_KEYS = {"StopTime": "stop_time", "Interval": "step_size", "Tolerance": "tolerance"}


def experiment_settings(text: str) -> dict[str, float]:
    """``stop_time``, ``step_size``, ``tolerance`` from ``annotation(experiment(...))``
    (only the keys found with a positive numeric literal)."""
    code = blank_comments(text)
    m = re.search(r"\bexperiment\s*\(([^()]*)\)", code)
    out: dict[str, float] = {}
    if m:
        for key, value in re.findall(r"\b(StopTime|Interval|Tolerance)\s*=\s*([-+0-9.eE]+)", m.group(1)):
            try:
                number = float(value)
            except ValueError:
                continue
            if number > 0:
                out[_EXPERIMENT_KEYS[key]] = number
    return out


def check_start_point(ca: Any, args: list[Any], blocks: list[Any], functions: list[Any], labels: tuple[Any, ...],
                      start: list[Any], where: str) -> None:
    """Refuse a singular or non-finite block coefficient matrix ``blocks = [(unknown names,
    SX matrix), ...]`` or a non-finite output of ``functions`` (named by ``labels``) at the
    point ``start`` (values of the symbols ``args``)."""
    if blocks:
        values = ca.Function("blocks", args, [jc for _, jc in blocks]).call(start)
        for (names, _), value in zip(blocks, values):
            a = np.atleast_2d(np.array(value, dtype=float))
            if not np.all(np.isfinite(a)) or np.linalg.cond(a) > 1e14:
                raise ValidationError(f"{where}: the equations for {', '.join(names)} cannot be solved for them "
                                      f"at the start point (coefficient {a.tolist()} singular or not finite)")
    for f, names in zip(functions, labels):
        for k, value in enumerate(f.call(start)):
            a = np.array(value, dtype=float).ravel()
            bad = np.flatnonzero(~np.isfinite(a))
            if bad.size:
                what = names[bad[0]] if f.n_out() == 1 else names[k]
                raise ValidationError(f"{where}: {what} is {a[bad[0]]} at the start point")


# ------------------------------------------------------------------------------------------
# The built FMU against CasADi
# ------------------------------------------------------------------------------------------


def _points(spec: Any, seed: int) -> list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
    """``(t, x, u, p)``: the start point and a random point nearby."""
    start = [np.array([v.start for v in getattr(spec, g)], dtype=float) for g in ("states", "inputs", "parameters")]
    rng = np.random.default_rng(seed)
    near = [a * (1.0 + 0.01 * rng.uniform(-1.0, 1.0, a.shape)) for a in start]
    return [(0.0, start[0], start[1], start[2]), (0.37, near[0], near[1], near[2])]


def _differs(got: np.ndarray, want: np.ndarray, rtol: float) -> int | None:
    """Index of the first entry where ``got`` and ``want`` differ by more than ``rtol``
    times the largest entry of ``want`` (NaN only equals NaN), else None."""
    scale = float(np.max(np.abs(want[np.isfinite(want)]), initial=0.0))
    for k, (a, b) in enumerate(zip(got, want)):
        if np.isnan(a) and np.isnan(b):
            continue
        if not abs(a - b) <= rtol * scale:
            return k
    return None


def _fmu_values(model: Any, spec: Any, point: tuple[Any, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(derivatives, outputs, dfdx and dfdu as columns)`` of an instantiated FMU2Model."""
    t, x, u, p = point
    nx, nu, np_ = len(x), len(u), len(p)
    vr_x, vr_dx = list(range(1, nx + 1)), list(range(nx + 1, 2 * nx + 1))
    vr_u = list(range(2 * nx + 1, 2 * nx + nu + 1))
    vr_p = list(range(2 * nx + nu + 1, 2 * nx + nu + np_ + 1))
    vr_y = list(range(2 * nx + nu + np_ + 1, 2 * nx + nu + np_ + len(spec.outputs) + 1))
    model.setupExperiment(startTime=t)
    model.enterInitializationMode()
    model.setReal(vr_x + vr_u + vr_p, [*x, *u, *p])
    model.exitInitializationMode()
    model.newDiscreteStates()
    model.enterContinuousTimeMode()
    model.setTime(t)
    buffer = (ctypes.c_double * nx)()
    model.getDerivatives(buffer, nx)
    dx = np.array(buffer, dtype=float)
    y = np.array(model.getReal(vr_y), dtype=float) if vr_y else np.zeros(0)
    columns = [model.getDirectionalDerivative(vr_dx + vr_y, [k], [1.0]) for k in vr_x + vr_u]
    return dx, y, np.array(columns, dtype=float).reshape(nx + nu, nx + len(vr_y))


def compare_fmu(fmu: Path, translation: Any, rtol: float, seed: int = 0) -> None:
    """Raise :class:`~ftc_verify.errors.FMUError` unless the FMU's derivatives, outputs and
    directional derivatives equal CasADi's (``translation.rhs``, ``.out``, ``.jac``) to
    ``rtol`` at the start point and at a random nearby point (see
    :func:`ftc_verify.plants.modelica.check_modelica_fmu`)."""
    import shutil

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Model

    spec = translation.spec
    unzipdir = extract(str(fmu))
    try:
        md = read_model_description(unzipdir)
        for n, point in enumerate(_points(spec, seed)):
            model = FMU2Model(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.modelExchange.modelIdentifier,
                              instanceName=f"check{n}")
            model.instantiate()
            try:
                got = _fmu_values(model, spec, point)
            finally:
                model.terminate()
                model.freeInstance()
            dfdx, dfdu, dgdx, dgdu = (np.array(a, dtype=float) for a in translation.jac.call(list(point)))
            want = (np.array(translation.rhs.call(list(point))[0], dtype=float).ravel(),
                    np.array(translation.out.call(list(point))[0], dtype=float).ravel(),
                    np.vstack([np.hstack([dfdx, dgdx]), np.hstack([dfdu, dgdu])])
                    .reshape(got[2].shape))
            for what, a, b in zip(("derivatives", "outputs", "directional derivatives"), got, want):
                k = _differs(a.ravel(), b.ravel(), rtol)
                if k is not None:
                    raise FMUError(f"{fmu}: the FMU's {what} differ from CasADi's at the "
                                   f"{'start' if n == 0 else 'random'} point (entry {k}: {float(a.ravel()[k])!r} vs "
                                   f"{float(b.ravel()[k])!r}); the FMU is wrong, do not use it")
    finally:
        shutil.rmtree(unzipdir, ignore_errors=True)
