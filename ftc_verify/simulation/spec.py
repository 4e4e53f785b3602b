r"""One run specification for every simulator: :class:`SimulationSpec`.

A run of the sampled-data loop is described by the same few numbers whichever backend
integrates it -- the control period, the horizon and the number of paths, the
disturbance, the ``Delta`` schedule, the seed, the batch size and the backend options.
:class:`SimulationSpec` holds them, checks them once (errors name the field and the
value) and owns the rules every backend has to share:

* the **seed streams**: path ``k`` of a run draws only from child ``k`` of
  ``numpy.random.SeedSequence(seed)`` (:func:`path_streams`), and its ``Delta`` values
  from the first child of that stream (:func:`delta_stream`); paths built by hand draw
  their ``Delta`` from :meth:`SimulationSpec.generator`;
* the **Delta choice** on a plant (:meth:`SimulationSpec.resolve_delta`): the kind asked
  for, or zero where the system is certain or the plant FMU has no ``Delta`` inputs;
* the **grid-snap tolerance** (:func:`grid_snap_tolerance`): a regular grid point this
  close to a jump time is replaced by it, in the communication grid and in the
  vectorised energies alike;
* the **memory check** of the kept trajectories (:meth:`SimulationSpec.check_memory`),
  done by the simulators that keep records and by the command line before any work.

The simulators (:func:`~ftc_verify.simulation.reference.simulate_reference`,
:func:`~ftc_verify.simulation.streaming.simulate_streaming`,
:func:`~ftc_verify.simulation.supervisor.simulate_fmu`,
:func:`~ftc_verify.simulation.batches.fmu_monte_carlo`...) take ``spec=`` or, as a
shorthand, the spec's fields as keywords (:func:`spec_from`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ValidationError
from ..limits import CONNECT_TIMEOUT, check_memory
from .delta import DeltaSchedule

if TYPE_CHECKING:
    from ..controllers.controller import Controller
    from ..model.system import FTCSystem, JointChain, Matrix
    from .paths import ChainPath, PathSpec

__all__ = [
    "SimulationSpec",
    "spec_from",
    "schedule_of",
    "seed_sequence",
    "path_streams",
    "delta_stream",
    "fresh_seed",
    "grid_snap_tolerance",
    "GRID_SNAP_RTOL",
    "RECORD_BYTES_PER_NUMBER",
]

#: A regular grid point closer than ``GRID_SNAP_RTOL * step`` to a jump time is replaced by
#: the jump (:func:`grid_snap_tolerance`), so that no grid interval is degenerate.
GRID_SNAP_RTOL = 1e-12
#: Bytes per recorded number of a path record: the float64 arrays measured 8.05 bytes per
#: number at peak (tracemalloc, reference backend, 100 paths of the paper example); twice
#: that leaves room for the FMU backend's buffers and the plot.
RECORD_BYTES_PER_NUMBER = 16


def grid_snap_tolerance(step: float) -> float:
    """The distance below which a grid point of period ``step`` merges into a jump time:
    ``GRID_SNAP_RTOL * step`` (:func:`~ftc_verify.simulation.paths.communication_grid` and
    ``ftc_verify.simulation._vectorised_grid`` both use it)."""
    return GRID_SNAP_RTOL * step


# ------------------------------------------------------------------------------ seed streams
def seed_sequence(seed: int | np.random.SeedSequence) -> np.random.SeedSequence:
    """The root ``SeedSequence`` of ``seed`` (a ``SeedSequence`` is returned as it is).

    Raises
    ------
    ValidationError
        ``seed`` is neither a non-negative integer nor a ``SeedSequence``.
    """
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValidationError(f"seed: expected a non-negative integer or a numpy SeedSequence, got {seed!r}")
    return np.random.SeedSequence(int(seed))


def path_streams(seed: int | np.random.SeedSequence, first: int, stop: int) -> list[np.random.SeedSequence]:
    """The streams of paths ``first .. stop - 1`` of ``sample_paths(..., seed)``: children
    ``first .. stop - 1`` of ``SeedSequence(seed).spawn(count)`` (any ``count >= stop``),
    built directly as ``SeedSequence(entropy, spawn_key=(*spawn_key, n + k))`` with ``n``
    the children ``seed`` has spawned so far (0 for an integer); a ``SeedSequence`` given
    as ``seed`` is not advanced."""
    root = seed_sequence(seed)
    if not 0 <= first <= stop:
        raise ValidationError(f"paths: expected 0 <= first <= stop, got first={first!r}, stop={stop!r}")
    base = root.n_children_spawned
    return [np.random.SeedSequence(root.entropy, spawn_key=(*root.spawn_key, base + k), pool_size=root.pool_size)
            for k in range(int(first), int(stop))]


def delta_stream(stream: np.random.SeedSequence) -> np.random.SeedSequence:
    """The stream of a path's ``Delta`` draws: the first child of the path's own
    ``stream`` (independent of the chain's draws), built anew without advancing it."""
    return np.random.SeedSequence(stream.entropy, spawn_key=(*stream.spawn_key, 0), pool_size=stream.pool_size)


def fresh_seed() -> int:
    """A seed drawn from the operating system's entropy (recorded where a run reports it)."""
    return int(cast(int, np.random.SeedSequence().entropy) % 2**63)


def schedule_of(delta: DeltaSchedule | str | None) -> DeltaSchedule:
    """The :class:`DeltaSchedule` of ``delta`` (``None`` is ``zero``, a string a kind)."""
    if delta is None:
        return DeltaSchedule("zero")
    if isinstance(delta, str):
        return DeltaSchedule(delta)
    if isinstance(delta, DeltaSchedule):
        return delta
    raise ValidationError(f"delta: expected a DeltaSchedule, a kind or None, got {type(delta).__name__}")


# ------------------------------------------------------------------------------ checks
def _positive_float(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value <= 0:
        raise ValidationError(f"{name}: must be a positive finite number, got {value!r}")
    return float(value)


def _optional_int(name: str, value: Any, least: int) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
        raise ValidationError(f"{name}: must be an integer >= {least} or None, got {value!r}")
    return int(value)


def _initial_state(x0: Any) -> tuple[float, ...] | None:
    if x0 is None:
        return None
    try:
        return tuple(float(v) for v in np.asarray(x0, dtype=float).reshape(-1))
    except (TypeError, ValueError):
        raise ValidationError(f"x0: expected finite numbers, got {x0!r}") from None


# ------------------------------------------------------------------------------ the spec
@dataclass(frozen=True, eq=False)
class SimulationSpec:
    """How to run the sampled-data loop: every option the simulators share.

    Parameters
    ----------
    step : float
        Control period ``h`` (sample-and-hold), positive.
    horizon : float
        Length of the sampled paths (:meth:`sample_paths`; given paths keep their own).
    n_paths : int
        Paths a run samples (:meth:`sample_paths`, :meth:`path_spec`).
    seed : int or None
        Root of the seed streams (module docstring); ``None``: :meth:`with_seed` draws one,
        and paths built by hand draw ``Delta`` from an unseeded generator.
    beta : array or None
        The rate array of every sampled path; ``None`` draws it per path in its box.
    disturbance : str
        A kind of :data:`~ftc_verify.simulation.paths.DISTURBANCES`.
    delta : DeltaSchedule, its kind, or None
        :math:`\\Delta(t)` (``None`` is ``zero``); stored as a :class:`DeltaSchedule`.
    delta_explicit : bool
        ``delta`` was asked for: :meth:`resolve_delta` refuses a plant that cannot carry it
        instead of replacing it by zero.
    x0 : array-like or None
        Initial plant state of every path (default 0; its length is checked against the
        system by the simulator); stored as a tuple of floats.
    record : int
        Streamed runs: full trajectories kept for the first ``record`` paths.
    batch : int or None
        Paths per batch (``None``: the backend's default).
    workers, scheduler : int or str or None
        The Dask cluster of a Monte Carlo run (:meth:`client`): ``workers`` local worker
        processes or the scheduler at ``scheduler``; checked by
        :func:`~ftc_verify.simulation.cluster.check_cluster_options`.
    isolate : bool
        FMU Monte Carlo without a cluster: run the FMU in a watched child process.
    connect_timeout : float
        Seconds that connecting to ``scheduler`` may take, handshake included, before the
        address is refused (``--connect-timeout``; default
        :data:`~ftc_verify.limits.CONNECT_TIMEOUT`).

    Raises
    ------
    ValidationError
        Naming the field and the value.
    """

    step: float = 0.01
    horizon: float = 30.0
    n_paths: int = 200
    seed: int | None = None
    beta: Matrix | None = None
    disturbance: str = "paper"
    delta: DeltaSchedule | str | None = None
    delta_explicit: bool = True
    x0: ArrayLike | None = None
    record: int = 0
    batch: int | None = None
    workers: int | None = None
    scheduler: str | None = None
    isolate: bool = True
    connect_timeout: float = CONNECT_TIMEOUT

    def __post_init__(self) -> None:
        from .paths import DISTURBANCES

        put = object.__setattr__
        put(self, "step", _positive_float("step", self.step))
        put(self, "horizon", _positive_float("horizon", self.horizon))
        put(self, "connect_timeout", _positive_float("connect_timeout", self.connect_timeout))
        if isinstance(self.n_paths, bool) or not isinstance(self.n_paths, (int, np.integer)) or self.n_paths < 1:
            raise ValidationError(f"paths: must be a positive integer, got {self.n_paths!r}")
        put(self, "n_paths", int(self.n_paths))
        if self.seed is not None:
            if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
                raise ValidationError(f"seed: expected a non-negative integer or None, got {self.seed!r}")
            put(self, "seed", int(self.seed))
        if self.beta is not None:
            if np.iscomplexobj(self.beta):
                raise ValidationError(f"beta: detection rates must be real, got {self.beta!r:.80}")
            try:
                beta = np.array(self.beta, dtype=float)
            except (TypeError, ValueError) as exc:
                raise ValidationError(f"beta: not an array of rates ({self.beta!r:.80}): {exc}") from None
            if not np.all(np.isfinite(beta)) or np.any(beta < 0):
                raise ValidationError(f"beta: rates must be finite and >= 0, got {self.beta!r:.80}")
            put(self, "beta", beta)
        if not isinstance(self.disturbance, str) or self.disturbance not in DISTURBANCES:
            raise ValidationError(f"disturbance: unknown kind {self.disturbance!r}; choose from {sorted(DISTURBANCES)}")
        put(self, "delta", schedule_of(self.delta))
        put(self, "x0", _initial_state(self.x0))
        put(self, "record", _optional_int("record", self.record, 0) or 0)
        put(self, "batch", _optional_int("batch", self.batch, 1))
        for name in ("delta_explicit", "isolate"):
            if not isinstance(getattr(self, name), bool):
                raise ValidationError(f"{name}: expected True or False, got {getattr(self, name)!r}")
        if self.scheduler is not None and not isinstance(self.scheduler, str):
            raise ValidationError(f"scheduler: expected an address string or None, got {self.scheduler!r}")
        if self.workers is not None or self.scheduler is not None:
            from .cluster import check_cluster_options

            check_cluster_options(_optional_int("workers", self.workers, 1), self.scheduler)

    @property
    def schedule(self) -> DeltaSchedule:
        """``delta`` as the :class:`DeltaSchedule` it is stored as."""
        return self.delta  # type: ignore[return-value]

    # -------------------------------------------------------------------- seeds and paths
    def with_seed(self) -> SimulationSpec:
        """This spec with a seed: itself when it has one, else with :func:`fresh_seed`."""
        return self if self.seed is not None else replace(self, seed=fresh_seed())

    def generator(self, rng: np.random.Generator | None = None) -> np.random.Generator:
        """The generator of the ``Delta`` draws of paths built by hand (sampled paths draw
        from their own streams): ``rng`` itself, else ``numpy.random.default_rng(seed)``."""
        if rng is not None:
            if not isinstance(rng, np.random.Generator):
                raise ValidationError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
            return rng
        return np.random.default_rng(self.seed)

    def sample_paths(self, chain: JointChain, first: int = 0, stop: int | None = None, *,
                     start: tuple[int, int] = (0, 0)) -> list[ChainPath]:
        """Paths ``first .. stop - 1`` (default: all ``n_paths``) of ``chain`` on
        ``[0, horizon]``, path ``k`` from stream ``k`` of ``seed``
        (:func:`~ftc_verify.simulation.paths.sample_path_range`)."""
        from .paths import sample_path_range

        for name, value in (("first", first), ("stop", stop)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer))
                                      or value < 0):
                raise ValidationError(f"{name}: expected a path index >= 0, got {value!r}")
        stop = self.n_paths if stop is None else int(stop)
        if stop <= first:
            raise ValidationError(f"first, stop: path range {first} .. {stop} - 1 is empty (stop must exceed first)")
        return sample_path_range(chain, self.horizon, self._seed_or_refuse(), first, stop, beta=self.beta,
                                 start=start)

    def path_spec(self, chain: JointChain, *, start: tuple[int, int] = (0, 0)) -> PathSpec:
        """The paths of :meth:`sample_paths` as a recipe, sampled where they are read
        (:class:`~ftc_verify.simulation.paths.PathSpec`)."""
        from .paths import PathSpec

        return PathSpec(chain, self.horizon, self.n_paths, self._seed_or_refuse(), beta=self.beta, start=start)

    def _seed_or_refuse(self) -> int:
        if self.seed is None:
            raise ValidationError("seed: sampling paths needs a seed (SimulationSpec.with_seed() draws one)")
        return self.seed

    # -------------------------------------------------------------------- Delta on a plant
    def resolve_delta(self, system: FTCSystem, plant: Any = None) -> tuple[SimulationSpec, str]:
        """This spec with the ``Delta`` a run of ``system`` on ``plant`` uses, and one line
        saying why.

        ``plant`` is a plant map (``None``: the ``LinearJumpPlant``, which always has the
        ``Delta`` inputs). The kind is ``zero`` for a certain system, and for an uncertain
        one whose plant map names no ``Delta`` inputs (``[variables].delta1``/``delta2``):
        the FMU cannot carry the model's uncertainty. With ``delta_explicit`` that case
        is refused instead of being replaced silently by zero.

        Raises
        ------
        ValidationError
            ``delta_explicit``, a kind other than ``zero`` asked for, an uncertain
            system and a plant map that names no ``Delta`` inputs.
        """
        requested = self.schedule.kind
        zero = replace(self, delta=DeltaSchedule("zero"))
        if not system.uncertain:
            return zero, "zero (the system has no norm-bounded uncertainty)"
        if plant is not None and not (plant.delta1 or plant.delta2):
            if self.delta_explicit and requested != "zero":
                raise ValidationError(
                    f"--delta {requested}: the plant map {plant.source} names no Delta inputs ([variables].delta1, "
                    f"delta2), so the system's uncertainty cannot be applied to its FMU; use --delta zero, or add "
                    "the FMU's Delta inputs to the map")
            return zero, ("zero: the plant map names no Delta inputs, so the model's uncertainty (Delta) is not "
                          "exercised on this FMU")
        return self, f"{requested} (the system's norm-bounded uncertainty, Delta, drawn as {requested!r})"

    # -------------------------------------------------------------------- resources
    def records_memory(self, system: FTCSystem, controller: Controller, count: int,
                       horizon: float | None = None) -> tuple[float, float]:
        """``(bytes, points)``: the estimated memory of ``count`` kept path records of
        ``horizon`` (default ``horizon``) and the grid points of each: ``horizon / step``
        plus twice the expected jumps at the largest rate of the chain, each point
        :data:`RECORD_BYTES_PER_NUMBER` bytes per recorded number."""
        horizon = self.horizon if horizon is None else float(horizon)
        n, nu, ny, nw = system.dims
        jumps = 2.0 * horizon * float(max(-system.chain.alpha.min(), system.chain.rate_max.max()))
        points = horizon / self.step + jumps + 2
        numbers = n + nu + ny + nw + controller.n_c + controller.n_v + 3
        return count * points * numbers * RECORD_BYTES_PER_NUMBER, points

    def check_memory(self, system: FTCSystem, controller: Controller, count: int,
                     horizon: float | None = None, *, beside: tuple[float, str] | None = None,
                     summaries: int = 0) -> None:
        """Refuse before simulating when ``count`` kept path records of ``horizon``
        (default ``horizon``; :meth:`records_memory`) would not fit in memory
        (:func:`~ftc_verify.limits.check_memory`), with ``beside = (bytes, what)`` another
        stage's memory held at the same time (``verify --h-max-work``: the refinement's
        program in the sampled-loop child) added to the estimate and named, and the
        per-path summaries of ``summaries`` paths (a streamed run's norms, switch counts
        and rates: ``4 + m^2`` numbers a path, :data:`RECORD_BYTES_PER_NUMBER` each).

        Raises
        ------
        MemoryLimitError
            Naming the paths, the grid points, the estimate and the limit.
        """
        need, points = self.records_memory(system, controller, count, horizon)
        extra, what = beside if beside is not None else (0.0, "")
        extra += float(summaries) * (4 + system.m ** 2) * RECORD_BYTES_PER_NUMBER
        check_memory(need + extra, f"{count} recorded paths of about {points:.3g} grid points each"
                     + (f" and the summaries of {summaries} paths" if summaries else "")
                     + (f" and {what}" if what else ""),
                     hint="use fewer --paths, a shorter --horizon or a larger --step"
                     + (" (or drop --h-max-work)" if what else ""))

    @contextmanager
    def client(self, given: Any = None, wait: bool = True) -> Iterator[Any]:
        """The Dask client of a Monte Carlo run: ``given`` when there is one, else a
        cluster of ``workers`` / ``scheduler`` opened for the block
        (:func:`~ftc_verify.simulation.cluster.open_client`; ``wait=False``: a local
        cluster still starting, its :class:`~ftc_verify.simulation.cluster.ClusterStart`),
        else ``None``."""
        if given is not None or (self.workers is None and self.scheduler is None):
            yield given
            return
        from .cluster import open_client

        with open_client(self.workers, self.scheduler, wait=wait, connect_timeout=self.connect_timeout) as client:
            yield client


def spec_from(spec: SimulationSpec | None, given: Mapping[str, Any]) -> SimulationSpec:
    """The spec of a simulator call: ``spec`` itself, or one built from the keywords
    ``given`` (field name -> value; ``None`` values take the spec's defaults).

    Raises
    ------
    ValidationError
        ``spec`` is not a :class:`SimulationSpec`, or is given together with a keyword.
    """
    named = {k: v for k, v in given.items() if v is not None}
    if spec is None:
        return SimulationSpec(**named)
    if not isinstance(spec, SimulationSpec):
        raise ValidationError(f"spec: expected a SimulationSpec, got {type(spec).__name__}")
    if named:
        raise ValidationError(f"spec: given together with {', '.join(sorted(named))}; set them in the spec instead")
    return spec
