r"""The safe envelope of a risk run: what "leaving" means, as a score on the simulation grid
and as the constraints of the proved bound.

Three kinds of envelope, all on the plant state :math:`x` (deviation from the operating
point) of the closed-loop state :math:`\xi = (x, x_c)`:

* ``output``: :math:`|z| < L` with :math:`z = C_i x` the performance output of the true
  mode :math:`i` (Euclidean norm over the output channels);
* ``state``: :math:`|x_I| < L` for one state index :math:`I`;
* ``region``: the plant map's ``[region]`` box, :math:`lo_k < x_{op,k} + x_k < hi_k`
  for every state with a finite side (:mod:`ftc_verify.plants.plant_map`).

The *score* of a grid point is the largest ratio of the monitored quantity to its limit,

.. math::

    S = |z|/L, \qquad S = |x_I|/L, \qquad
    S = \max_k \max\Bigl(\frac{x_k}{hi_k - x_{op,k}}, \frac{-x_k}{x_{op,k} - lo_k}\Bigr),

so the envelope is left exactly when :math:`S \ge 1` (a ratio with an infinite side is
left out). The score of a path is its largest score over the grid points of its record.

The constraints :math:`|H_s \xi| \ge \ell` of the upper bound (one matrix :math:`H_s`
per joint state :math:`s` of the closed loop, :class:`ftc_verify.analysis.closedloop.ClosedLoop`)
are :math:`H_s = [C_{i(s)}\ 0]`, :math:`\ell = L` (``output``) and :math:`H_s = [e_I^T\
0]`, :math:`\ell = L` (``state``): the same event. For ``region`` each bounded state gives
:math:`H_s = [e_k^T\ 0]`, :math:`\ell_k = \min(hi_k - x_{op,k}, x_{op,k} - lo_k)`: the
symmetric box inside the region, which is left whenever the region is, so a bound on
leaving it bounds leaving the region.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..errors import ValidationError
from ..model.system import FTCSystem, Matrix

__all__ = ["Envelope", "output_envelope", "state_envelope", "region_envelope"]


@dataclass(frozen=True, eq=False)
class Envelope:
    """A safe envelope (module docstring).

    Attributes
    ----------
    kind : str
        ``"output"``, ``"state"`` or ``"region"``.
    description : str
        One line for reports, e.g. ``|z| < 5``.
    upper, lower : (n,) arrays
        ``region``: the distances :math:`hi_k - x_{op,k}` and :math:`x_{op,k} - lo_k`
        (``inf`` for a missing side); otherwise unused (``inf``).
    limit : float
        :math:`L` of ``output`` and ``state`` (``nan`` for ``region``).
    index : int
        :math:`I` of ``state`` (0-based; ``-1`` otherwise).
    """

    kind: str
    description: str
    upper: np.ndarray
    lower: np.ndarray
    limit: float
    index: int

    def score(self, x: np.ndarray, y: np.ndarray) -> float:
        """Largest score over the grid points of a record: ``x`` ``(N, n)`` plant states,
        ``y`` ``(N, ny)`` performance outputs. ``0.0`` for an empty record."""
        if x.shape[0] == 0:
            return 0.0
        if self.kind == "output":
            return float(np.max(np.sqrt(np.sum(np.square(y), axis=1)))) / self.limit
        if self.kind == "state":
            return float(np.max(np.abs(x[:, self.index]))) / self.limit
        with np.errstate(divide="ignore", invalid="ignore"):
            up = np.where(np.isfinite(self.upper), x / self.upper, -np.inf)
            down = np.where(np.isfinite(self.lower), -x / self.lower, -np.inf)
        return float(max(np.max(up), np.max(down), 0.0))

    def score_system(self, system: FTCSystem) -> FTCSystem:
        r"""``system`` with every mode's performance output :math:`C_i` replaced by the
        envelope's rows :math:`G_i` (the measured output :math:`C_{y,i}` kept), so that the
        simulators' output peaks give the score: ``output`` :math:`G_i = C_i / L`, score
        :math:`\max|G x|`; ``state`` :math:`G = [e_I^T; -e_I^T]/L`; ``region`` the rows
        :math:`e_k^T/(hi_k - x_{op,k})` and :math:`-e_k^T/(x_{op,k} - lo_k)` of the finite
        sides; for the last two the score is the largest entry of :math:`G x` (:meth:`peak_score`)."""
        n = system.dims[0]
        eye = np.eye(n)
        if self.kind == "output":
            rows = [mode.C / self.limit for mode in system.modes]
        else:
            if self.kind == "state":
                g = np.vstack((eye[self.index], -eye[self.index])) / self.limit
            else:
                g = np.vstack([eye[k] / self.upper[k] for k in range(n) if np.isfinite(self.upper[k])]
                              + [-eye[k] / self.lower[k] for k in range(n) if np.isfinite(self.lower[k])])
            rows = [g for _ in system.modes]
        modes = tuple(dataclasses.replace(mode, C=r, Cy=mode.measured) for mode, r in zip(system.modes, rows))
        return dataclasses.replace(system, modes=modes, names=None)

    def peak_score(self, peak_sq: np.ndarray, peak: np.ndarray) -> np.ndarray:
        """Per path the score from the output peaks of :meth:`score_system`'s system
        (:func:`~ftc_verify.simulation.vectorised.output_peaks_reference`)."""
        if self.kind == "output":
            return np.sqrt(np.maximum(peak_sq, 0.0))
        return np.maximum(np.max(peak, axis=0), 0.0)

    def constraints(self, system: FTCSystem, n_xi: int, states: tuple[tuple[int, int, int], ...]
                    ) -> list[tuple[list[Matrix], float]]:
        """The constraints :math:`(H_s, \\ell)` of the upper bound (module docstring) on the
        closed-loop state of dimension ``n_xi``, one ``H`` per joint state ``(true, fdi,
        phase)`` of ``states`` (:attr:`JointChain.states`)."""
        n = system.dims[0]

        def pad(rows: Matrix) -> Matrix:
            out = np.zeros((rows.shape[0], n_xi))
            out[:, :n] = rows
            return out

        if self.kind == "output":
            return [([pad(system.modes[i].C) for i, _, _ in states], self.limit)]
        picks = [self.index] if self.kind == "state" else [
            k for k in range(n) if np.isfinite(self.upper[k]) or np.isfinite(self.lower[k])]
        out = []
        for k in picks:
            e = np.zeros((1, n))
            e[0, k] = 1.0
            level = self.limit if self.kind == "state" else float(min(self.upper[k], self.lower[k]))
            out.append(([pad(e) for _ in states], level))
        return out


def _limit(limit: float) -> float:
    if not (isinstance(limit, (int, float)) and np.isfinite(limit) and limit > 0):
        raise ValidationError(f"--limit {limit!r}: must be a positive finite number")
    return float(limit)


def output_envelope(limit: float) -> Envelope:
    """``|z| < limit``: the performance output of the true mode."""
    inf = np.full(0, np.inf)
    return Envelope("output", f"|z| < {_limit(limit):g}", inf, inf, _limit(limit), -1)


def state_envelope(system: FTCSystem, index: int, limit: float) -> Envelope:
    """``|x_I| < limit`` for the 0-based state index ``index``."""
    n = system.dims[0]
    if not (isinstance(index, int) and 0 <= index < n):
        raise ValidationError(f"--state {index + 1 if isinstance(index, int) else index!r}: "
                              f"the plant has states 1 .. {n}")
    inf = np.full(0, np.inf)
    return Envelope("state", f"|x{index + 1}| < {_limit(limit):g}", inf, inf, _limit(limit), index)


def region_envelope(states_min: np.ndarray | None, states_max: np.ndarray | None,
                    operating_point: np.ndarray, source: str) -> Envelope:
    """The plant map's state region around its operating point (``source`` names the map).

    Raises :class:`~ftc_verify.errors.ValidationError` when the map has no state region or
    the operating point is not strictly inside it."""
    if states_min is None or states_max is None:
        raise ValidationError(f"--region {source}: the plant map has no [region] states_min / states_max")
    xop = np.asarray(operating_point, dtype=float)
    upper, lower = np.asarray(states_max, float) - xop, xop - np.asarray(states_min, float)
    bad = np.flatnonzero(~((upper > 0) & (lower > 0)))
    if bad.size:
        k = int(bad[0])
        raise ValidationError(f"--region {source}: operating point state {k + 1} = {xop[k]:g} is not inside "
                              f"[{states_min[k]:g}, {states_max[k]:g}]")
    return Envelope("region", f"the [region] of {source} (x_op + x)", upper, lower, float("nan"), -1)
