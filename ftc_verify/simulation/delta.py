r"""Time-varying norm-bounded uncertainty :math:`\Delta(t)` for simulation.

A :class:`DeltaSchedule` gives, for one :class:`~ftc_verify.simulation.paths.ChainPath`, the pair
``(Delta1, Delta2)`` on each chain segment (between consecutive jump times); both
simulation backends take the values from :func:`delta_segments`, so they see the same
:math:`\Delta(t)`. Kinds:

* ``zero`` -- the nominal plant;
* ``constant`` -- the given matrices throughout;
* ``sign`` -- the given matrices with alternating sign, flipping at every chain jump;
* ``random`` -- a fresh random matrix on every segment, :math:`\Delta = s\,G/\|G\|_2`
  with :math:`G` standard normal and :math:`s` uniform in [0, 1], drawn from the path's
  own stream (or the caller's generator for a path built by hand).

Every value satisfies :math:`\|\Delta\|_2 \le 1` (checked for given matrices).
``Delta1`` is ``p1 x q1`` for ``A1`` (``n x p1``) and ``A2`` (``q1 x n``); ``Delta2`` is
``p2 x q2`` for ``B1`` and ``B2``; modes that have a channel must agree on its shape.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ValidationError
from ..model.system import FTCSystem, Matrix, as_matrix

if TYPE_CHECKING:  # closedloop imports the analysis package, which the plant processes do not need
    from ..analysis.closedloop import ClosedLoop
    from .paths import ChainPath

__all__ = ["DELTA_KINDS", "DeltaSchedule", "delta_shapes", "delta_segments", "constant_delta_loops"]

DELTA_KINDS = ("zero", "constant", "sign", "random")


def delta_shapes(system: FTCSystem) -> tuple[tuple[int, int] | None, tuple[int, int] | None]:
    """Shapes of ``Delta1`` and ``Delta2`` (``None`` where no mode has the channel)."""
    shapes: list[tuple[int, int] | None] = []
    for left, right, label in (("A1", "A2", "Delta1"), ("B1", "B2", "Delta2")):
        found = {
            (getattr(md, left).shape[1], getattr(md, right).shape[0])
            for md in system.modes if getattr(md, left) is not None
        }
        if len(found) > 1:
            raise ValidationError(f"{label}: modes disagree on its shape {sorted(found)}")
        shapes.append(found.pop() if found else None)
    return shapes[0], shapes[1]


@dataclass(frozen=True, eq=False)
class DeltaSchedule:
    """How ``Delta(t)`` evolves on a path (see module docstring)."""

    kind: str = "zero"
    Delta1: Matrix | None = None
    Delta2: Matrix | None = None

    def __post_init__(self) -> None:
        if self.kind not in DELTA_KINDS:
            raise ValidationError(f"delta: unknown kind {self.kind!r}; choose from {list(DELTA_KINDS)}")
        for name in ("Delta1", "Delta2"):
            val = getattr(self, name)
            if val is None:
                continue
            arr = as_matrix(val, f"delta.{name}")
            norm = float(np.linalg.norm(arr, 2))
            if norm > 1.0 + 1e-12:
                raise ValidationError(f"delta.{name}: spectral norm {norm:.6g} exceeds 1")
            object.__setattr__(self, name, arr)


def _given(system: FTCSystem, schedule: DeltaSchedule) -> tuple[Matrix | None, Matrix | None]:
    out: list[Matrix | None] = []
    for name, shape in zip(("Delta1", "Delta2"), delta_shapes(system)):
        val = getattr(schedule, name)
        if shape is None:
            out.append(None)
        elif val is None:
            out.append(np.zeros(shape))
        elif val.shape != shape:
            raise ValidationError(f"delta.{name}: expected shape {shape}, got {val.shape}")
        else:
            out.append(val)
    return out[0], out[1]


def _random(shape: tuple[int, int] | None, rng: np.random.Generator) -> Matrix | None:
    if shape is None:
        return None
    G = rng.standard_normal(shape)
    # np.linalg.norm(G, 2) is this largest singular value (the same LAPACK call, without its
    # axis handling: a tenth of the Monte Carlo's per-path cost went there)
    norm = float(np.linalg.svd(G, compute_uv=False).max()) if G.size else float(np.linalg.norm(G, 2))
    return G * (rng.random() / norm) if norm > 0 else G


def delta_segments(
    system: FTCSystem,
    path: ChainPath,
    schedule: DeltaSchedule,
    rng: np.random.Generator | None = None,
) -> list[tuple[Matrix | None, Matrix | None]]:
    """``(Delta1, Delta2)`` on each chain segment of ``path`` (``len(path.times)`` entries).

    Kind ``random`` draws from the path's own stream
    (:meth:`~ftc_verify.simulation.paths.ChainPath.delta_generator`: the same values on
    every call and in every simulator), or from ``rng`` for a path without a stream
    (built by hand); the other kinds draw nothing.
    """
    segments = len(path.times)
    if schedule.kind == "random":
        own = path.delta_generator()
        rng = own if own is not None else rng
        if rng is None:
            raise ValidationError("delta: kind 'random' needs a numpy Generator for a path without its own stream")
        s1, s2 = delta_shapes(system)
        return [(_random(s1, rng), _random(s2, rng)) for _ in range(segments)]
    if schedule.kind == "zero":
        d1, d2 = _given(system, DeltaSchedule("zero"))
        return [(d1, d2)] * segments
    d1, d2 = _given(system, schedule)
    if schedule.kind == "constant":
        return [(d1, d2)] * segments
    out = []
    for k in range(segments):
        sign = 1.0 if k % 2 == 0 else -1.0
        out.append((None if d1 is None else sign * d1, None if d2 is None else sign * d2))
    return out


def constant_delta_loops(system: FTCSystem, loop: ClosedLoop) -> list[tuple[str, ClosedLoop]]:
    """The nominal loop and, when ``loop`` is uncertain, the loops with the constant
    ``Delta = +E`` and ``Delta = -E`` (``E`` the rectangular identity, norm 1) built in,
    labelled ``"Delta=0"``, ``"Delta=+E"``, ``"Delta=-E"``."""
    out = [("Delta=0", loop.nominal())]
    if not loop.uncertain:
        return out
    s1, s2 = delta_shapes(system)
    for sign, label in ((1.0, "Delta=+E"), (-1.0, "Delta=-E")):
        deltas = {}
        if s1 is not None:
            deltas["Delta1 (A)"] = sign * np.eye(*s1)
        if s2 is not None:
            deltas["Delta2 (B)"] = sign * np.eye(*s2)
        A = loop.perturbed(deltas)
        out.append((label, replace(loop.nominal(), A=A, source=None)))
    return out
