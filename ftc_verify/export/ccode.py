r"""The FDI-switched controller as one dependency-free C99 file.

For FDI mode :math:`l` (1-based in C, ``0 <= l - 1 < m``) the controller of
:mod:`ftc_verify.controllers.controller`

.. math::

    \dot x_c = A_{c,l} x_c + B_{c,l} v, \qquad u = C_{c,l} x_c + D_{c,l} v

(static state feedback :math:`u = K_l x`, the paper's eq. (2), is :math:`n_c = 0`,
:math:`D_{c,l} = K_l`; the dynamic controllers of the paper's Section V have
:math:`n_c \ge 1`) is sampled with the period :math:`h` of the export and the input
:math:`v` held over a sample, as the simulators run it (the loop of the reference paper with sample-and-hold,
:mod:`ftc_verify.simulation.supervisor`):

.. math::

    u_k = C_{c,l} x_{c,k} + D_{c,l} v_k, \qquad
    x_{c,k+1} = \Phi_{c,l} x_{c,k} + \Gamma_{c,l} v_k, \qquad
    \Phi_{c,l} = e^{A_{c,l} h}, \quad \Gamma_{c,l} = \int_0^h e^{A_{c,l} s}\, ds\, B_{c,l},

(the solution :math:`x_c(t + h) = e^{A_{c,l} h} x_c(t) + \int_0^h e^{A_{c,l}(h - s)} ds\,
B_{c,l} v` of the ODE with :math:`v` constant, the integral substituted :math:`s \to h - s`),
with :math:`(\Phi_{c,l}, \Gamma_{c,l})` from :meth:`Controller.discretise
<ftc_verify.controllers.controller.Controller.discretise>` -- the very matrices the
supervisor uses for a full step -- written into the file with 17 significant digits
(``repr``, so the C doubles are the same numbers). The C code is a matrix-vector product
and nothing else: no exponential is computed on the target, and a step of another length
is refused (``ftc_ctrl_step`` returns ``FTC_CTRL_BAD_STEP``) because the matrices are those
of :math:`h` only. A step is accepted when :math:`|h' - h| \le 10^{-9} h` (the steps of
an importer's grid ``t_k = k h`` differ from :math:`h` by rounding).

The file declares (prefix ``ftc_ctrl``):

* ``ftc_ctrl_state`` -- a struct holding :math:`x_c` (one unused entry when :math:`n_c = 0`);
* ``ftc_ctrl_init(s)`` -- :math:`x_c = 0`;
* ``ftc_ctrl_output(s, fdi_mode, v, u)`` -- :math:`u = C_{c,l} x_c + D_{c,l} v`;
* ``ftc_ctrl_step(s, fdi_mode, v, h)`` -- :math:`x_c \leftarrow \Phi_{c,l} x_c + \Gamma_{c,l} v`;

both return ``FTC_CTRL_OK`` (0), ``FTC_CTRL_BAD_MODE`` (an FDI mode outside ``1..m``) or
``FTC_CTRL_BAD_STEP``. Full-information controllers (entries indexed by the true mode as
well) are not exported: the controller's inputs are the measured signal and the FDI mode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import __version__
from ..controllers.controller import Controller
from ..errors import ValidationError

__all__ = ["STEP_RTOL", "ControllerTables", "controller_tables", "controller_c_source"]

#: Relative difference accepted between a requested step and the exported period.
STEP_RTOL = 1e-9


@dataclass(frozen=True, eq=False)
class ControllerTables:
    """The numbers the C file embeds: per FDI mode ``Phi`` (n_c x n_c), ``Gamma`` (n_c x n_v),
    ``Cc`` (n_u x n_c), ``Dc`` (n_u x n_v), and the period ``step``."""

    step: float
    phi: tuple[np.ndarray, ...]
    gamma: tuple[np.ndarray, ...]
    cc: tuple[np.ndarray, ...]
    dc: tuple[np.ndarray, ...]
    measures: str

    @property
    def modes(self) -> int:
        """The number of FDI modes (entries)."""
        return len(self.dc)

    @property
    def nu(self) -> int:
        """The number of control inputs ``u``."""
        return int(self.dc[0].shape[0])

    @property
    def nv(self) -> int:
        """The number of measured signals ``v``."""
        return int(self.dc[0].shape[1])

    @property
    def nc(self) -> int:
        """The controller order ``n_c``."""
        return int(self.cc[0].shape[1])


def controller_tables(controller: Controller, step: float, m: int) -> ControllerTables:
    """The matrices of ``controller`` sampled with period ``step`` (module docstring).

    Parameters
    ----------
    controller : Controller
        Checked against its system already (:meth:`Controller.check`).
    step : float
        The sampling period ``h`` (> 0, finite).
    m : int
        The system's number of modes.

    Raises
    ------
    ValidationError
        For full-information controllers (``m * m`` entries) or a bad ``step``.
    """
    if not (isinstance(step, float) and 0.0 < step < float("inf")):
        raise ValidationError(f"--step {step!r}: must be a positive finite number")
    if controller.full_information(m):
        raise ValidationError(
            f"controller: {controller.entries} full-information entries (indexed by the true mode as well); "
            "an exported controller reads only the FDI mode: export an FDI-mode controller (one entry per mode)")
    steps = [controller.discretise(e, step) for e in range(controller.entries)]
    return ControllerTables(step=step, phi=tuple(np.asarray(p, dtype=float) for p, _ in steps),
                            gamma=tuple(np.asarray(g, dtype=float) for _, g in steps),
                            cc=tuple(np.asarray(c, dtype=float) for c in controller.Cc),
                            dc=tuple(np.asarray(d, dtype=float) for d in controller.Dc),
                            measures=controller.measures)


def _number(x: float) -> str:
    text = repr(float(x))
    return text if any(ch in text for ch in ".e") else text + ".0"


def _table(name: str, mats: tuple[np.ndarray, ...]) -> list[str]:
    """``static const double name[modes][rows * cols]`` (row-major), or nothing when empty."""
    rows, cols = mats[0].shape
    if rows * cols == 0:
        return []
    lines = [f"static const double {name}[{len(mats)}][{rows * cols}] = {{"]
    for k, mat in enumerate(mats, start=1):
        body = ", ".join(_number(x) for x in np.asarray(mat, dtype=float).reshape(-1))
        lines.append(f"    {{{body}}}{',' if k < len(mats) else ''} /* FDI mode {k} */")
    return lines + ["};"]


_FUNCTIONS = r"""
void ftc_ctrl_init(ftc_ctrl_state *s) {
    int i;
    for (i = 0; i < FTC_CTRL_NC_ALLOC; i++) s->xc[i] = 0.0;
}

int ftc_ctrl_output(const ftc_ctrl_state *s, int fdi_mode, const double v[], double u[]) {
    int i, j, l = fdi_mode - 1;
    if (fdi_mode < 1 || fdi_mode > FTC_CTRL_MODES) return FTC_CTRL_BAD_MODE;
    for (i = 0; i < FTC_CTRL_NU; i++) {
        double acc = 0.0;
#if FTC_CTRL_NV > 0
        for (j = 0; j < FTC_CTRL_NV; j++) acc += FTC_CTRL_DC[l][i * FTC_CTRL_NV + j] * v[j];
#endif
#if FTC_CTRL_NC > 0
        for (j = 0; j < FTC_CTRL_NC; j++) acc += FTC_CTRL_CC[l][i * FTC_CTRL_NC + j] * s->xc[j];
#endif
        u[i] = acc;
    }
    (void)s, (void)v, (void)j, (void)l;
    return FTC_CTRL_OK;
}

int ftc_ctrl_step(ftc_ctrl_state *s, int fdi_mode, const double v[], double h) {
    double d = h - FTC_CTRL_STEP;
    if (fdi_mode < 1 || fdi_mode > FTC_CTRL_MODES) return FTC_CTRL_BAD_MODE;
    if (!(h > 0.0) || (d < 0.0 ? -d : d) > FTC_CTRL_STEP_RTOL * FTC_CTRL_STEP) return FTC_CTRL_BAD_STEP;
#if FTC_CTRL_NC > 0
    {
        int i, j, l = fdi_mode - 1;
        double next[FTC_CTRL_NC];
        for (i = 0; i < FTC_CTRL_NC; i++) {
            double acc = 0.0;
            for (j = 0; j < FTC_CTRL_NC; j++) acc += FTC_CTRL_PHI[l][i * FTC_CTRL_NC + j] * s->xc[j];
#if FTC_CTRL_NV > 0
            for (j = 0; j < FTC_CTRL_NV; j++) acc += FTC_CTRL_GAMMA[l][i * FTC_CTRL_NV + j] * v[j];
#endif
            next[i] = acc;
        }
        for (i = 0; i < FTC_CTRL_NC; i++) s->xc[i] = next[i];
    }
#endif
    (void)s, (void)v;
    return FTC_CTRL_OK;
}
"""


def controller_c_source(tables: ControllerTables, *, title: str) -> str:
    """The C99 file of ``tables`` (module docstring); ``title`` names the controller and
    system in its header comment (``*/`` is removed from it)."""
    t = tables
    safe = title.replace("*/", "* /")
    v_what = "the plant state x" if t.measures == "state" else "the measured output y_m = Cy x"
    lines = [
        f"/* {safe}",
        f" * generated by ftc-verify {__version__}: the FDI-switched controller sampled with period",
        f" * h = {_number(t.step)} s (exact zero-order hold, v held over a step), {t.modes} FDI modes,",
        f" * v = {v_what} ({t.nv} signals), u = {t.nu} control inputs, x_c of order {t.nc}.",
        " *   u_k = Cc[l] x_c,k + Dc[l] v_k,  x_c,k+1 = Phi[l] x_c,k + Gamma[l] v_k",
        " * Phi = expm(Ac h), Gamma = int_0^h expm(Ac s) ds Bc. C99, no dependencies. */",
        "#ifndef FTC_CTRL_C", "#define FTC_CTRL_C", "",
        f"#define FTC_CTRL_MODES {t.modes}", f"#define FTC_CTRL_NV {t.nv}", f"#define FTC_CTRL_NU {t.nu}",
        f"#define FTC_CTRL_NC {t.nc}", f"#define FTC_CTRL_NC_ALLOC {max(t.nc, 1)}",
        f"#define FTC_CTRL_STEP {_number(t.step)}", f"#define FTC_CTRL_STEP_RTOL {_number(STEP_RTOL)}",
        "#define FTC_CTRL_OK 0", "#define FTC_CTRL_BAD_MODE (-1)", "#define FTC_CTRL_BAD_STEP (-2)", "",
        "typedef struct {", "    double xc[FTC_CTRL_NC_ALLOC]; /* the controller state x_c */", "} ftc_ctrl_state;", "",
        "void ftc_ctrl_init(ftc_ctrl_state *s);",
        "int ftc_ctrl_output(const ftc_ctrl_state *s, int fdi_mode, const double v[], double u[]);",
        "int ftc_ctrl_step(ftc_ctrl_state *s, int fdi_mode, const double v[], double h);", "",
    ]
    lines += _table("FTC_CTRL_DC", t.dc) + _table("FTC_CTRL_CC", t.cc)
    lines += _table("FTC_CTRL_PHI", t.phi) + _table("FTC_CTRL_GAMMA", t.gamma)
    return "\n".join(lines) + "\n" + _FUNCTIONS + "\n#endif /* FTC_CTRL_C */\n"
