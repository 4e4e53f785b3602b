r"""The controller type: one entry per FDI mode, static or dynamic, on a measured signal.

Every controller of ftc-verify is, per FDI mode :math:`l`, a linear system

.. math::

    \dot x_c = A_{c,l}\, x_c + B_{c,l}\, v, \qquad u = C_{c,l}\, x_c + D_{c,l}\, v,

whose input :math:`v` is either the plant state (``measures="state"``, :math:`v = x`) or
the measured output of the *true* mode :math:`i` (``measures="output"``,
:math:`v = y_m = C_{y,i} x`). The controller state :math:`x_c` has the same dimension
:math:`n_c` in every FDI mode and continues across FDI switches (no reset).

* Static state feedback :math:`u = K_l x` (paper eq. (2)) is the case :math:`n_c = 0`,
  :math:`D_{c,l} = K_l`, ``measures="state"``; :meth:`Controller.state_feedback` builds it.
  Baselines that also know the true mode (full information, :math:`u = K_{il} x`) give
  :math:`m^2` entries indexed ``s = i m + l``; every other controller gives :math:`m`.
* Dynamic output feedback (paper Section V, :math:`K_j = [[\hat A_j, \hat B_j],
  [\hat C_j, \hat D_j]]`) is ``measures="output"`` with :math:`n_c \ge 1`;
  :meth:`Controller.dynamic` builds it. :math:`n_c = 0` with ``measures="output"`` is
  static output feedback :math:`u = D_{c,l} y_m`.

A controller may carry its sampling **period** :math:`h` (``period``, seconds; ``None``
for a continuous-time controller): it reads :math:`v(t_k)` and the FDI report
:math:`l(t_k)` at :math:`t_k = k h` and holds :math:`u` until the next sample
(:mod:`ftc_verify.analysis.moments.sampled` certifies that loop).

The closed loop is built from ``(system, controller)`` in one place,
:func:`ftc_verify.analysis.closedloop.closed_loop`; the simulators use
:meth:`Controller.discretise` for the exact update of :math:`x_c` between samples.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ValidationError
from ..model.system import FTCSystem, Matrix, Mode, as_matrix

__all__ = ["MEASURES", "Controller", "check_period"]

#: What a controller reads: the plant state, or the measured output ``y_m = Cy x``.
MEASURES = ("state", "output")


def check_period(value: Any, name: str = "period") -> float:
    """A sampling period: a finite number ``> 0`` (not a bool), else a
    :class:`~ftc_verify.errors.ValidationError` naming ``name`` and the value."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValidationError(f"{name}: expected a positive number of seconds, got {value!r}")
    h = float(value)
    if not (math.isfinite(h) and h > 0):
        raise ValidationError(f"{name}: must be a positive finite number of seconds, got {value!r}")
    return h


def _empty(rows: int, cols: int) -> Matrix:
    out = np.zeros((rows, cols))
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Controller:
    """A controller with one entry ``(Ac, Bc, Cc, Dc)`` per FDI mode (module docstring).

    Attributes
    ----------
    Ac, Bc, Cc, Dc : tuple of arrays, one per entry
        ``Ac`` is ``n_c x n_c``, ``Bc`` is ``n_c x n_v``, ``Cc`` is ``n_u x n_c`` and ``Dc``
        is ``n_u x n_v`` (``n_v`` = states or measured outputs, see ``measures``).
    measures : {"state", "output"}
        The controller input ``v``: the plant state ``x`` or the measured output ``y_m``.
    name : str
        A label for reports.
    period : float or None
        The sampling period ``h > 0`` of a digital implementation (module docstring);
        ``None`` (default): continuous time.
    """

    Ac: tuple[Matrix, ...]
    Bc: tuple[Matrix, ...]
    Cc: tuple[Matrix, ...]
    Dc: tuple[Matrix, ...]
    measures: str
    name: str = ""
    period: float | None = None
    #: The numbers of the controller file as written (float read -> decimal texts), set
    #: by :func:`~ftc_verify.controllers.files.load_controller`; ``None`` when the floats
    #: are the data.
    literals: Mapping[float, tuple[str, ...]] | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.period is not None:
            object.__setattr__(self, "period", check_period(self.period, "controller.period"))
        if self.measures not in MEASURES:
            raise ValidationError(f"controller.measures: expected one of {MEASURES}, got {self.measures!r}")
        count = len(self.Dc)
        if count == 0:
            raise ValidationError("controller: no entry given (one per FDI mode is needed)")
        for key in ("Ac", "Bc", "Cc"):
            if len(getattr(self, key)) != count:
                raise ValidationError(
                    f"controller.{key}: {len(getattr(self, key))} entries, but Dc has {count}"
                )
        for key in ("Ac", "Bc", "Cc", "Dc"):
            object.__setattr__(self, key, tuple(
                as_matrix(v, f"controller[{k}].{key}", allow_empty=True)
                for k, v in enumerate(getattr(self, key), start=1)
            ))
        nu, nv = self.Dc[0].shape
        nc = self.Ac[0].shape[0]
        expected = {"Ac": (nc, nc), "Bc": (nc, nv), "Cc": (nu, nc), "Dc": (nu, nv)}
        gain_file = self.measures == "state" and nc == 0
        for k in range(count):
            for key, shape in expected.items():
                got = getattr(self, key)[k].shape
                if got != shape:
                    where = f"gain[{k + 1}].K" if gain_file else f"controller[{k + 1}].{key}"
                    first = "gain[1].K" if gain_file else "controller[1]"
                    raise ValidationError(
                        f"{where}: expected shape {shape[0]} x {shape[1]} "
                        f"(n_c = {nc}, {nu} inputs, {nv} measured signals, as {first}), "
                        f"got {got[0]} x {got[1]}"
                    )

    # ---------------------------------------------------------------- constructors
    @classmethod
    def state_feedback(cls, gains: Sequence[ArrayLike], *, name: str = "", period: float | None = None) -> Controller:
        """Static state feedback ``u = K[l] x`` (``m`` gains) or ``u = K[i m + l] x``
        (``m * m`` full-information gains)."""
        Ks = [as_matrix(K, f"gain[{k}].K") for k, K in enumerate(gains, start=1)]
        if not Ks:
            raise ValidationError("gains: no gain given (one per FDI mode is needed)")
        nu, n = Ks[0].shape
        return cls(
            tuple(_empty(0, 0) for _ in Ks), tuple(_empty(0, n) for _ in Ks),
            tuple(_empty(nu, 0) for _ in Ks), tuple(Ks), "state", name, period,
        )

    @classmethod
    def dynamic(
        cls,
        Ac: Sequence[ArrayLike],
        Bc: Sequence[ArrayLike],
        Cc: Sequence[ArrayLike],
        Dc: Sequence[ArrayLike],
        *,
        name: str = "",
        period: float | None = None,
    ) -> Controller:
        """Dynamic output feedback on ``y_m``, one ``(Ac, Bc, Cc, Dc)`` per FDI mode."""
        return cls(tuple(Ac), tuple(Bc), tuple(Cc), tuple(Dc), "output", name, period)  # type: ignore[arg-type]

    def with_period(self, period: float | None) -> Controller:
        """The same controller with sampling period ``period`` (``None``: continuous time)."""
        return replace(self, period=period)

    # ---------------------------------------------------------------- properties
    @property
    def n_c(self) -> int:
        """Controller state dimension (0 for a static controller)."""
        return int(self.Ac[0].shape[0])

    @property
    def nu(self) -> int:
        """Number of control inputs."""
        return int(self.Dc[0].shape[0])

    @property
    def n_v(self) -> int:
        """Number of signals the controller reads (states or measured outputs)."""
        return int(self.Dc[0].shape[1])

    @property
    def entries(self) -> int:
        """Number of entries (``m``, or ``m * m`` for full-information gains)."""
        return len(self.Dc)

    @property
    def static(self) -> bool:
        """True when the controller has no state (``n_c = 0``)."""
        return self.n_c == 0

    @property
    def is_state_feedback(self) -> bool:
        """True for static state feedback ``u = K x``."""
        return self.static and self.measures == "state"

    @property
    def gains(self) -> tuple[Matrix, ...]:
        """The gains ``K`` of static state feedback (raises for other controllers)."""
        if not self.is_state_feedback:
            raise ValidationError(f"controller {self.describe()}: has no state-feedback gains")
        return self.Dc

    def full_information(self, m: int) -> bool:
        """True when the entries are indexed by joint mode (``m * m`` of them)."""
        return self.entries == m * m and self.entries != m

    def index(self, true: int, fdi: int, m: int) -> int:
        """The entry used in joint mode ``(true, fdi)`` (0-based)."""
        return true * m + fdi if self.full_information(m) else fdi

    def describe(self, m: int | None = None) -> str:
        """A short human-readable kind, e.g. ``FDI-mode state feedback``."""
        who = "full-information" if m is not None and self.full_information(m) else "FDI-mode"
        if self.is_state_feedback:
            return f"{who} state feedback"
        if self.static:
            return f"{who} static output feedback"
        return f"{who} dynamic {self.measures} feedback (n_c = {self.n_c})"

    def measurement(self, mode: Mode) -> Matrix:
        """The map from plant state to controller input in ``mode``: ``I`` or ``Cy``."""
        return np.eye(mode.n) if self.measures == "state" else mode.measured

    # ---------------------------------------------------------------- checks
    def check(self, system: FTCSystem, *, source: str = "controller") -> Controller:
        """Validate against ``system``; errors name ``source``, the entry and the shapes.

        Returns ``self`` so that ``Controller(...).check(system)`` reads naturally.
        """
        m = system.m
        n, nu, _, _ = system.dims
        allowed = (m, m * m) if self.is_state_feedback else (m,)
        if self.entries not in allowed:
            extra = f", or {m * m} for full-information gains" if self.is_state_feedback else ""
            raise ValidationError(
                f"{source}: {self.entries} entries given, the system has {m} modes "
                f"(expected {m} (one per FDI mode){extra})"
            )
        nv = n if self.measures == "state" else system.ny_measured
        what = "states" if self.measures == "state" else "measured outputs (rows of Cy, default C)"
        table = "gain" if self.is_state_feedback else "controller"
        if self.nu != nu:
            key = "K" if self.is_state_feedback else "Dc"
            raise ValidationError(
                f"{source}: {table}[1].{key}: {self.nu} rows, but the system has {nu} inputs "
                f"(expected {nu} x {nv}, got {self.nu} x {self.n_v})"
            )
        if self.n_v != nv:
            key = "K" if self.is_state_feedback else "Dc"
            raise ValidationError(
                f"{source}: {table}[1].{key}: {self.n_v} columns, but the system has {nv} {what} "
                f"(expected {nu} x {nv}, got {self.nu} x {self.n_v})"
            )
        return self

    # ---------------------------------------------------------------- sampled data
    def discretise(self, entry: int, h: float) -> tuple[Matrix, Matrix]:
        r"""Exact update of :math:`x_c` over a step ``h`` with the input :math:`v` held:

        .. math::

            x_c(t + h) = \Phi_c\, x_c(t) + \Gamma_c\, v(t), \qquad \Phi_c = e^{A_c h},
            \quad \Gamma_c = \int_0^h e^{A_c s}\, ds\; B_c,

        both read from one exponential of :math:`\bigl[\begin{smallmatrix} A_c & B_c \\ 0 & 0
        \end{smallmatrix}\bigr] h` (Van Loan). Returns ``(Phi_c, Gamma_c)``.
        """
        import scipy.linalg  # here: the plant processes of the Monte Carlo unpickle controllers without it

        nc, nv = self.n_c, self.n_v
        M = np.zeros((nc + nv, nc + nv))
        M[:nc, :nc] = self.Ac[entry]
        M[:nc, nc:] = self.Bc[entry]
        E = scipy.linalg.expm(M * float(h))
        return E[:nc, :nc], E[:nc, nc:]

    def output(self, entry: int, xc: Matrix, v: Matrix) -> Matrix:
        """The control ``u = Cc xc + Dc v`` of one entry."""
        return self.Cc[entry] @ xc + self.Dc[entry] @ v

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (the matrices as nested lists)."""
        out: dict[str, Any] = {"kind": self.describe(), "measures": self.measures, "n_c": self.n_c,
                               "name": self.name, "period": self.period}
        if self.is_state_feedback:
            out["gains"] = [K.tolist() for K in self.Dc]
        else:
            out["entries"] = [
                {"Ac": a.tolist(), "Bc": b.tolist(), "Cc": c.tolist(), "Dc": d.tolist()}
                for a, b, c, d in zip(self.Ac, self.Bc, self.Cc, self.Dc)
            ]
        return out

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Controller):
            return NotImplemented
        return self.measures == other.measures and self.period == other.period and all(
            len(getattr(self, k)) == len(getattr(other, k))
            and all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(getattr(self, k), getattr(other, k)))
            for k in ("Ac", "Bc", "Cc", "Dc")
        )

    __hash__ = None  # type: ignore[assignment]
