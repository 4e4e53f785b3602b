"""The run specification (``ftc_verify.simulation.spec``): its checks, the seed streams, the
Delta choice on a plant, the grid-snap tolerance and the memory check it owns."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from ftc_verify.controllers import load_controller
from ftc_verify.errors import MemoryLimitError, ValidationError
from ftc_verify.model.files import load_system
from ftc_verify.simulation import SimulationSpec
from ftc_verify.simulation.delta import DeltaSchedule
from ftc_verify.simulation.vectorised import energies_reference
from ftc_verify.simulation.paths import ChainPath, PathSpec, communication_grid, sample_paths
from ftc_verify.simulation.reference import simulate_reference
from ftc_verify.simulation.spec import GRID_SNAP_RTOL, grid_snap_tolerance, path_streams, spec_from
from ftc_verify.simulation.streaming import simulate_streaming

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"


@pytest.fixture(scope="module")
def paper() -> tuple:
    return load_system(PAPER), load_controller(GAINS)


@pytest.mark.parametrize("field, value, words", [
    ("step", 0.0, "step: must be a positive finite number, got 0.0"),
    ("step", float("nan"), "step: must be a positive finite number, got nan"),
    ("horizon", -1.0, "horizon: must be a positive finite number, got -1.0"),
    ("n_paths", 0, "paths: must be a positive integer, got 0"),
    ("seed", -3, "seed: expected a non-negative integer or None, got -3"),
    ("seed", True, "seed: expected a non-negative integer or None, got True"),
    ("disturbance", "wind", "disturbance: unknown kind 'wind'"),
    ("delta", "wobbly", "delta: unknown kind 'wobbly'"),
    ("delta", 3, "delta: expected a DeltaSchedule, a kind or None, got int"),
    ("x0", "abc", "x0: expected finite numbers, got 'abc'"),
    ("record", -1, "record: must be an integer >= 0 or None, got -1"),
    ("batch", 0, "batch: must be an integer >= 1 or None, got 0"),
    ("isolate", "yes", "isolate: expected True or False, got 'yes'"),
    ("workers", 0, "workers: must be an integer >= 1 or None, got 0"),
    ("scheduler", "no address", "--scheduler 'no address': not a scheduler address"),
])
def test_every_field_is_checked_naming_it_and_the_value(field: str, value: object, words: str) -> None:
    with pytest.raises(ValidationError) as err:
        SimulationSpec(**{field: value})
    assert words in str(err.value)


def test_the_spec_normalises_its_values() -> None:
    spec = SimulationSpec(step=1, seed=np.int64(4), delta="random", x0=np.array([[1.0], [2.0]]))
    assert spec.step == 1.0 and isinstance(spec.step, float) and spec.seed == 4 and type(spec.seed) is int
    assert isinstance(spec.delta, DeltaSchedule) and spec.schedule.kind == "random"
    assert spec.x0 == (1.0, 2.0)
    assert SimulationSpec().schedule.kind == "zero" and SimulationSpec().record == 0


def test_spec_or_keywords_not_both() -> None:
    spec = SimulationSpec(step=0.1)
    assert spec_from(spec, {"step": None, "seed": None}) is spec
    assert spec_from(None, {"step": 0.2, "seed": None}).step == 0.2
    with pytest.raises(ValidationError, match="spec: given together with seed, step"):
        spec_from(spec, {"step": 0.1, "seed": 3})
    with pytest.raises(ValidationError, match="spec: expected a SimulationSpec, got dict"):
        spec_from({"step": 0.1}, {})  # type: ignore[arg-type]


# ------------------------------------------------------------------------------ seed streams
def test_the_spec_samples_the_paths_of_its_seed(paper: tuple) -> None:
    system, _ = paper
    spec = SimulationSpec(horizon=8.0, n_paths=30, seed=17)
    direct = sample_paths(system.chain, 8.0, 30, 17)
    for a, b in zip(spec.sample_paths(system.chain), direct, strict=True):
        np.testing.assert_array_equal(a.times, b.times)
        np.testing.assert_array_equal(a.true, b.true)
        np.testing.assert_array_equal(a.beta, b.beta)
        np.testing.assert_array_equal(a.delta_generator().random(3), b.delta_generator().random(3))
    part = spec.sample_paths(system.chain, 10, 20)  # a range on its own: the same paths
    for a, b in zip(part, direct[10:20], strict=True):
        np.testing.assert_array_equal(a.times, b.times)
    recipe = spec.path_spec(system.chain)
    assert isinstance(recipe, PathSpec) and len(recipe) == 30
    np.testing.assert_array_equal(recipe[29].times, direct[29].times)
    children = np.random.SeedSequence(17).spawn(30)
    assert [s.spawn_key for s in path_streams(17, 0, 30)] == [c.spawn_key for c in children]
    with pytest.raises(ValidationError, match="seed: sampling paths needs a seed"):
        SimulationSpec().sample_paths(system.chain)


def test_with_seed_draws_once_and_keeps_a_given_seed() -> None:
    given = SimulationSpec(seed=5)
    assert given.with_seed() is given
    drawn = SimulationSpec().with_seed()
    assert isinstance(drawn.seed, int) and 0 <= drawn.seed < 2**63
    assert drawn.generator().random() == np.random.default_rng(drawn.seed).random()


def test_spec_and_keywords_give_the_same_numbers(paper: tuple) -> None:
    system, controller = paper
    paths = sample_paths(system.chain, 6.0, 4, 3)
    spec = SimulationSpec(step=0.02, delta="random", disturbance="sine", seed=9, x0=[0.5, -0.5])
    a = simulate_reference(system, controller, paths, spec=spec)
    b = simulate_reference(system, controller, paths, step=0.02, delta="random", disturbance="sine", seed=9,
                           x0=[0.5, -0.5])
    assert a.seed == b.seed == 9 and a.options == b.options
    for ra, rb in zip(a.records, b.records, strict=True):
        np.testing.assert_array_equal(ra.x, rb.x)
        np.testing.assert_array_equal(ra.y, rb.y)
    ey, _ew = energies_reference(system, controller, paths, spec=spec)
    np.testing.assert_allclose(ey, [r.y_norm ** 2 for r in a.records], rtol=1e-10)
    streamed = simulate_streaming(system, controller, paths, spec=SimulationSpec(step=0.02, delta="random", seed=9,
                                                                               record=2))
    keywords = simulate_streaming(system, controller, paths, step=0.02, delta="random", seed=9, record=2)
    np.testing.assert_array_equal(streamed.y_norm, keywords.y_norm)
    assert len(streamed.records) == 2
    with pytest.raises(ValidationError, match="x0: a streamed run starts every path at x = 0"):
        simulate_streaming(system, controller, paths, spec=spec)


# ------------------------------------------------------------------------------ Delta on a plant
def test_resolve_delta_decides_the_delta_of_a_run() -> None:
    certain, uncertain = SimpleNamespace(uncertain=False), SimpleNamespace(uncertain=True)
    no_inputs = SimpleNamespace(delta1=(), delta2=(), source="motor.plant.toml")
    with_inputs = SimpleNamespace(delta1=("d1",), delta2=(), source="motor.plant.toml")
    asked = SimulationSpec(delta="random")
    spec, why = asked.resolve_delta(certain)
    assert spec.schedule.kind == "zero" and why.startswith("zero (the system has no norm-bounded uncertainty)")
    assert asked.resolve_delta(uncertain)[0] is asked
    assert asked.resolve_delta(uncertain, with_inputs)[0] is asked
    with pytest.raises(ValidationError, match=r"^--delta random: the plant map motor.plant.toml names no Delta"):
        asked.resolve_delta(uncertain, no_inputs)
    spec, why = SimulationSpec(delta="random", delta_explicit=False).resolve_delta(uncertain, no_inputs)
    assert spec.schedule.kind == "zero" and "names no Delta inputs" in why
    assert SimulationSpec(delta="zero").resolve_delta(uncertain, no_inputs)[0].schedule.kind == "zero"


# ------------------------------------------------------------------------------ the grid-snap tolerance
@pytest.mark.parametrize("offset, merged", [(0.5, True), (3.0, False)])
def test_one_snap_tolerance_for_the_grid_and_the_energies(paper: tuple, offset: float, merged: bool) -> None:
    """A jump ``offset`` tolerances after the grid point 0.3: merged into it (one grid
    point) within the tolerance, beside it beyond; the energies agree with the records
    either way, so both use the same tolerance."""
    system, controller = paper
    step = 0.1
    assert grid_snap_tolerance(step) == GRID_SNAP_RTOL * step
    jump = 3 * step + offset * grid_snap_tolerance(step)
    path = ChainPath(np.array([0.0, jump]), np.array([0, 1]), np.array([0, 0]), np.zeros((2, 2)), 1.0)
    t = communication_grid(path, step)[0]
    near = np.abs(t - jump) <= 4 * grid_snap_tolerance(step)
    assert int(np.count_nonzero(near)) == (1 if merged else 2)
    rec = simulate_reference(system, controller, [path], step=step).records[0]
    ey, _ = energies_reference(system, controller, [path], step=step)
    np.testing.assert_allclose(ey[0], rec.y_norm ** 2, rtol=1e-12)


# ------------------------------------------------------------------------------ the memory check
def test_api_callers_get_the_memory_check(paper: tuple, monkeypatch: pytest.MonkeyPatch) -> None:
    system, controller = paper
    paths = sample_paths(system.chain, 30.0, 3, 1)
    monkeypatch.setenv("FTC_VERIFY_MEMORY_LIMIT", "1K")
    with pytest.raises(MemoryLimitError, match=r"^3 recorded paths of about .* grid points each: about .* above "
                                               r"the limit of 1 kB \(FTC_VERIFY_MEMORY_LIMIT\)"):
        simulate_reference(system, controller, paths, step=0.01)
    with pytest.raises(MemoryLimitError, match="1 recorded paths"):
        simulate_streaming(system, controller, paths, step=0.01, record=1)
    ey, _ = energies_reference(system, controller, paths, step=0.01)  # keeps no trajectory: not refused
    assert ey.shape == (3,)
    with pytest.raises(MemoryLimitError, match="use fewer --paths, a shorter --horizon or a larger --step"):
        SimulationSpec(horizon=30.0).check_memory(system, controller, 3)
