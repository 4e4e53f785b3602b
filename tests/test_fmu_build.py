"""The LinearJumpPlant FMU: build, validation, exact stepping, FMU state, caching."""

from __future__ import annotations

import math
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

fmpy = pytest.importorskip("fmpy")
if shutil.which("gcc") is None:  # pragma: no cover - gcc is on every supported machine
    pytest.skip("gcc is needed to compile the FMU", allow_module_level=True)

from fmpy import calloc, extract, free, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2LastSuccessfulTime,
)

from ftc_verify.errors import FTCError, ValidationError
from ftc_verify.plants.build import cache_dir
from ftc_verify.plants.linear_jump import (
    FMUError,
    build_binary,
    build_fmu,
    fmu_dims,
    parse_system_text,
    source_dir,
    system_text,
    validate,
    variable_names,
)
from ftc_verify.model.system import FTCSystem
from ftc_verify.model.files import load_system

PAPER = Path(__file__).resolve().parents[1] / "examples" / "paper.toml"
CHAIN2 = dict(alpha=[[-1.0, 1.0], [2.0, -2.0]], beta_min=[[0, 1.0], [1.0, 0]], beta_max=[[0, 2.0], [2.0, 0]])


@pytest.fixture(scope="module")
def cache_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("ftc-verify-cache")


@pytest.fixture(autouse=True)
def _isolated_cache(cache_root: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FTC_VERIFY_CACHE", str(cache_root))


@pytest.fixture(scope="module")
def paper() -> FTCSystem:
    return load_system(PAPER)


def scalar_system(modes: list[tuple[float, float, float, float]], name: str = "scalar") -> FTCSystem:
    """x' = a x + b u + d w, y = c x per mode ``(a, b, d, c)``."""
    m = len(modes)
    alpha = np.full((m, m), 1.0) - m * np.eye(m)
    beta = np.ones((m, m)) - np.eye(m)
    return FTCSystem.from_arrays(
        name=name,
        modes=[dict(A=[[a]], B=[[b]], C=[[c]], D=[[d]]) for a, b, d, c in modes],
        alpha=alpha, beta_min=beta, beta_max=2 * beta,
    )


SCALAR_MODES = [(-0.7, 2.0, 0.5, 2.0), (0.3, -1.0, 1.5, 3.0), (0.0, 0.8, -0.2, 1.0)]


@pytest.fixture(scope="module")
def paper_fmu(paper: FTCSystem, cache_root: Path) -> Path:
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(cache_root))
        return build_fmu(paper)


@pytest.fixture(scope="module")
def scalar_fmu(cache_root: Path) -> Path:
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(cache_root))
        return build_fmu(scalar_system(SCALAR_MODES))


class Plant:
    """A co-simulation instance of an FMU, addressed by variable names."""

    def __init__(self, fmu: Path, unzip_dir: Path, *, x0=None, start_time: float = 0.0,
                 system_file: str | None = None, callbacks=None, logging: bool = False,
                 initialize: bool = True) -> None:
        md = read_model_description(str(fmu))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.names = [v.name for v in md.modelVariables]
        self.n = sum(name.startswith("x[") for name in self.names)
        extract(str(fmu), str(unzip_dir))
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(unzip_dir),
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName="plant")
        self.fmu.instantiate(callbacks=callbacks, loggingOn=logging)
        self.time = start_time
        self.closed = False
        if initialize:
            self.fmu.setupExperiment(startTime=start_time)
            self.fmu.enterInitializationMode()
            if x0 is not None:
                self.set("x0", x0)
            if system_file is not None:
                self.fmu.setString([self.vr["systemFile"]], [system_file])
            self.fmu.exitInitializationMode()

    def set(self, base: str, values) -> None:
        values = np.asarray(values, dtype=float)
        if values.ndim == 2:
            names = [f"{base}[{i + 1},{j + 1}]" for i in range(values.shape[0]) for j in range(values.shape[1])]
        else:
            names = [f"{base}[{i + 1}]" for i in range(values.size)]
        self.fmu.setReal([self.vr[k] for k in names], [float(v) for v in values.ravel()])

    def set_mode(self, mode: int) -> None:
        self.fmu.setInteger([self.vr["mode"]], [mode])

    def get(self, base: str, count: int) -> np.ndarray:
        return np.array(self.fmu.getReal([self.vr[f"{base}[{k}]"] for k in range(1, count + 1)]))

    def step(self, h: float) -> None:
        self.fmu.doStep(self.time, h)
        self.time += h

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            try:
                self.fmu.terminate()
            except FMICallException:
                pass  # e.g. never initialized; freeing is still required
            self.fmu.freeInstance()


@pytest.fixture
def open_plant(tmp_path: Path):
    plants: list[Plant] = []

    def factory(fmu: Path, **kwargs) -> Plant:
        plant = Plant(fmu, tmp_path / f"unzip{len(plants)}", **kwargs)
        plants.append(plant)
        return plant

    yield factory
    for plant in plants:
        plant.close()


def reference_step(system: FTCSystem, mode: int, D1, D2, x, u, w, h: float) -> np.ndarray:
    """Exact zero-order-hold step with scipy's expm of the augmented matrix."""
    md = system.modes[mode - 1]
    A = np.array(md.A) + (md.A1 @ D1 @ md.A2 if md.A1 is not None else 0.0)
    B = np.array(md.B) + (md.B1 @ D2 @ md.B2 if md.B1 is not None else 0.0)
    n, nu, _, nw = system.dims
    M = np.zeros((n + nu + nw, n + nu + nw))
    M[:n, :n], M[:n, n:n + nu], M[:n, n + nu:] = A, B, md.D
    E = scipy.linalg.expm(M * h)
    return E[:n, :n] @ x + E[:n, n:] @ np.concatenate([u, w])


# ------------------------------------------------------------------------------------------
# Building and validation
# ------------------------------------------------------------------------------------------


def test_paper_fmu_validates_and_declares_its_contract(paper: FTCSystem, paper_fmu: Path) -> None:
    assert validate(paper_fmu) == []
    md = read_model_description(str(paper_fmu))
    cs = md.coSimulation
    assert cs.modelIdentifier == "LinearJumpPlant"
    assert cs.canHandleVariableCommunicationStepSize and cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    assert md.variableNamingConvention == "structured"
    names = [v.name for v in md.modelVariables]
    assert names == variable_names(fmu_dims(paper))
    assert names[:5] == ["x0[1]", "x0[2]", "u[1]", "u[2]", "w[1]"]
    assert "Delta1[2,1]" in names and "Delta2[1,2]" in names and names[-2:] == ["mode", "systemFile"]
    assert [v.valueReference for v in md.modelVariables] == list(range(1, len(names) + 1))
    by_name = {v.name: v for v in md.modelVariables}
    assert (by_name["mode"].type, by_name["mode"].causality, by_name["mode"].max) == ("Integer", "input", "2")
    assert by_name["x[1]"].causality == by_name["y[1]"].causality == "output"
    with zipfile.ZipFile(paper_fmu) as zf:
        members = set(zf.namelist())
        text = zf.read("resources/system.txt").decode()
    library = f"binaries/{fmpy.platform}/LinearJumpPlant{fmpy.sharedLibraryExtension}"
    assert {"modelDescription.xml", library, "resources/system.txt", "sources/model.c"} <= members
    parsed = parse_system_text(text)
    assert parsed["guid"] == md.guid and parsed["dims"] == fmu_dims(paper)
    for mode, tables in zip(paper.modes, parsed["modes"]):  # exact round trip of every number
        for key, value in tables.items():
            assert np.array_equal(value, mode.measured if key == "Cy" else getattr(mode, key)), key


def measured_system() -> FTCSystem:
    """Two modes, n = 3, with Cy (2 x 3): row 1 equal in both modes, row 2 different."""
    g = np.random.default_rng(17)
    modes = []
    for k in range(2):
        Cy = [[1.0, -2.0, 0.5], [0.3 + k, 0.0, -1.0 - 2 * k]]
        modes.append(dict(A=g.uniform(-1, 1, (3, 3)) - np.eye(3), B=g.uniform(-1, 1, (3, 2)),
                          C=g.uniform(-1, 1, (1, 3)), D=g.uniform(-1, 1, (3, 1)), Cy=Cy))
    return FTCSystem.from_arrays(name="measured", modes=modes, **CHAIN2)


def test_measured_outputs_are_cy_of_the_current_mode(open_plant, tmp_path: Path) -> None:
    """``ym[k]`` is ``Cy_r x`` of the current mode in every mode (after switches and steps);
    declared as depending on ``mode`` only where the row of ``Cy`` differs between modes."""
    system = measured_system()
    fmu = build_fmu(system, tmp_path / "measured.fmu")
    assert validate(fmu) == []
    md = read_model_description(str(fmu))
    names = [v.name for v in md.modelVariables]
    assert names == variable_names(fmu_dims(system)) and fmu_dims(system).nym == 2
    assert names.index("ym[1]") == names.index("y[1]") + 1 and names[-2:] == ["mode", "systemFile"]
    deps = {u.variable.name: [d.name for d in (u.dependencies or [])] for u in md.outputs}
    assert deps["ym[1]"] == [] and deps["ym[2]"] == ["mode"] and deps["y[1]"] == ["mode"]
    assert {u.variable.name for u in md.initialUnknowns} >= {"ym[1]", "ym[2]"}
    parsed = parse_system_text(zipfile.ZipFile(fmu).read("resources/system.txt").decode())
    for mode, tables in zip(system.modes, parsed["modes"]):
        assert np.array_equal(tables["Cy"], mode.Cy)
    plant = open_plant(fmu, x0=[0.4, -1.2, 0.7])
    for r, u in [(1, [0.5, -1.0]), (2, [1.0, 0.2]), (1, [0.0, 0.3]), (2, [-0.4, 0.0])]:
        plant.set_mode(r)
        plant.set("u", u)
        for _ in range(3):
            x = plant.get("x", 3)
            ym = plant.get("ym", 2)
            assert np.allclose(ym, system.modes[r - 1].Cy @ x, rtol=1e-14, atol=1e-15), r
            assert np.allclose(plant.get("y", 1), system.modes[r - 1].C @ x, rtol=1e-14, atol=1e-15)
            assert not np.allclose(ym, system.modes[2 - r].Cy @ x)  # the other mode's Cy differs
            plant.step(0.1)


def test_measured_outputs_default_to_c(scalar_fmu: Path, open_plant) -> None:
    """Without ``Cy`` the FMU still has ``ym`` (one per row of ``C``), equal to ``y = C_r x``."""
    md = read_model_description(str(scalar_fmu))
    assert [v.name for v in md.modelVariables if v.name.startswith("ym[")] == ["ym[1]"]
    plant = open_plant(scalar_fmu, x0=[0.9])
    for r in (1, 2, 3, 1):
        plant.set_mode(r)
        plant.set("u", [0.5 * r])
        plant.step(0.2)
        x = plant.get("x", 1)[0]
        assert plant.get("ym", 1)[0] == plant.get("y", 1)[0] == pytest.approx(SCALAR_MODES[r - 1][3] * x, rel=1e-14)


def test_scalar_fmu_has_no_uncertainty_inputs(scalar_fmu: Path) -> None:
    assert validate(scalar_fmu) == []
    names = [v.name for v in read_model_description(str(scalar_fmu)).modelVariables]
    assert names == ["x0[1]", "u[1]", "w[1]", "x[1]", "y[1]", "ym[1]", "mode", "systemFile"]


def test_same_system_gives_identical_fmu(paper: FTCSystem, paper_fmu: Path, tmp_path: Path) -> None:
    again = build_fmu(paper, tmp_path)
    assert again == tmp_path / "paper-section-vi.fmu"
    assert again.read_bytes() == paper_fmu.read_bytes()


def test_rebuild_without_changes_does_not_recompile(paper: FTCSystem, paper_fmu: Path, cache_root: Path,
                                                    tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    binary = build_binary()  # compiled when paper_fmu was built
    assert binary.parent == cache_dir() == cache_root / "fmus"
    stamp = binary.stat()
    build_fmu(paper, tmp_path / "a.fmu")
    assert build_binary() == binary
    after = binary.stat()
    assert (after.st_mtime_ns, after.st_ino) == (stamp.st_mtime_ns, stamp.st_ino)
    assert [p.name for p in cache_dir().glob("*.so")] == [binary.name]

    forced = build_binary(force=True)
    assert forced == binary and forced.stat().st_ino != stamp.st_ino  # a fresh file

    # a change of the sources gives another binary (the hash covers the sources)
    monkeypatch.setenv("FTC_VERIFY_CACHE", str(tmp_path / "cache"))
    copy = tmp_path / "src"
    shutil.copytree(source_dir(), copy)
    with open(copy / "model.c", "a") as fh:
        fh.write("\n/* changed */\n")
    other = build_binary(sources=copy)
    assert other.name != binary.name and other.is_file()


def test_compile_errors_and_missing_gcc_are_reported(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FTC_VERIFY_CACHE", str(tmp_path / "cache"))
    broken = tmp_path / "broken"
    shutil.copytree(source_dir(), broken)
    (broken / "model.c").write_text((broken / "model.c").read_text() + "\nthis is not C;\n")
    with pytest.raises(FMUError, match=r"(?s)compiling the LinearJumpPlant FMU failed.*model\.c.*error") as exc:
        build_binary(sources=broken)
    assert isinstance(exc.value, FTCError) and isinstance(exc.value, RuntimeError)
    assert not list((tmp_path / "cache" / "fmus").glob("*.so"))  # no half-written binary
    assert not list((tmp_path / "cache" / "fmus").glob(".*tmp"))

    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(FMUError, match="gcc not found on PATH"):
        build_binary()


def test_validate_and_build_reject_bad_input(tmp_path: Path) -> None:
    with pytest.raises(FMUError, match="no such FMU file"):
        validate(tmp_path / "missing.fmu")
    (tmp_path / "junk.fmu").write_text("not a zip")
    with pytest.raises(FMUError, match="not a zip archive"):
        validate(tmp_path / "junk.fmu")
    w = [[0.1]]
    mixed = FTCSystem.from_arrays(
        name="mixed",
        modes=[dict(A=[[-1.0]], B=[[1.0]], C=[[1.0]], D=[[1.0]], A1=w, A2=w),
               dict(A=[[-1.0]], B=[[1.0]], C=[[1.0]], D=[[1.0]], A1=[[0.1, 0.2]], A2=[[0.1], [0.3]])],
        **CHAIN2,
    )
    with pytest.raises(ValidationError, match=r"mode 2: A1 .* 2 x 2 Delta1, but mode 1 implies 1 x 1"):
        build_fmu(mixed, tmp_path / "mixed.fmu")


def test_validate_reports_a_mismatched_resource_file(paper: FTCSystem, paper_fmu: Path, tmp_path: Path) -> None:
    doctored = tmp_path / "doctored.fmu"
    with zipfile.ZipFile(paper_fmu) as src, zipfile.ZipFile(doctored, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "resources/system.txt":
                data = system_text(paper, guid="{other}").encode()
            dst.writestr(item, data)
    problems = validate(doctored)
    assert len(problems) == 1 and "guid {other}" in problems[0]


# ------------------------------------------------------------------------------------------
# Exact stepping
# ------------------------------------------------------------------------------------------


def test_scalar_plant_matches_the_analytic_solution(scalar_fmu: Path, open_plant) -> None:
    x0 = 0.4
    plant = open_plant(scalar_fmu, x0=[x0])
    assert plant.get("x", 1)[0] == x0 and plant.get("y", 1)[0] == pytest.approx(2.0 * x0)
    # (mode, u, w, h, steps): a mode switch, input changes, a = 0 and varying step sizes
    schedule = [(1, 1.2, -0.3, 0.1, 5), (2, -0.5, 0.8, 0.1, 4), (2, 2.0, 0.0, 0.25, 3),
                (3, 1.0, 1.0, 0.5, 3), (1, 0.0, 2.0, 0.05, 4), (1, 0.0, 2.0, 1.5, 2)]
    x, t = x0, 0.0
    for mode, u, w, h, steps in schedule:
        a, b, d, c = SCALAR_MODES[mode - 1]
        plant.set_mode(mode)
        plant.set("u", [u])
        plant.set("w", [w])
        assert plant.get("y", 1)[0] == pytest.approx(c * x, rel=1e-12, abs=1e-12)  # y uses the new mode
        for _ in range(steps):
            plant.step(h)
            t += h
            # x(t + h) = e^{a h} x + (e^{a h} - 1) / a (b u + d w)
            phi = (math.expm1(a * h) / a) if a != 0.0 else h
            x = math.exp(a * h) * x + phi * (b * u + d * w)
            got_x, got_y = plant.get("x", 1)[0], plant.get("y", 1)[0]
            assert abs(got_x - x) <= 1e-10 * max(1.0, abs(x)), (mode, h, got_x, x)
            assert abs(got_y - c * x) <= 1e-10 * max(1.0, abs(c * x))
    assert plant.fmu.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(t, abs=1e-12)


def test_paper_system_matches_scipy_expm_with_uncertainty(paper: FTCSystem, paper_fmu: Path, open_plant) -> None:
    n, _nu, ny, _nw = paper.dims
    x = np.array([1.0, -0.5])
    plant = open_plant(paper_fmu, x0=x)
    D1 = np.array([[0.3, -0.5], [0.2, 0.7]])
    D2 = np.array([[-0.4, 0.1], [0.6, 0.2]])
    zero = np.zeros((2, 2))
    # (mode, Delta1, Delta2, u, w, step sizes)
    schedule = [
        (1, zero, zero, [0.3, -1.2], [0.7], [0.1, 0.1, 0.1]),
        (1, D1, D2, [0.3, -1.2], [0.7], [0.1, 0.05, 0.3]),
        (2, D1, D2, [-0.8, 0.4], [-0.2], [0.01, 0.25, 1.0]),
        (2, -D1, D2.T, [-0.8, 0.4], [0.0], [0.2, 0.2]),
        (1, D1.T, zero, [0.0, 1.0], [1.5], [0.5, 0.125, 0.3]),
    ]
    for mode, d1, d2, u, w, steps in schedule:
        plant.set_mode(mode)
        plant.set("Delta1", d1)
        plant.set("Delta2", d2)
        plant.set("u", u)
        plant.set("w", w)
        for h in steps:
            plant.step(h)
            x = reference_step(paper, mode, d1, d2, x, np.array(u), np.array(w), h)
            got = plant.get("x", n)
            assert np.linalg.norm(got - x) <= 1e-10 * np.linalg.norm(x), (mode, h, got, x)
            y = paper.modes[mode - 1].C @ x
            assert np.allclose(plant.get("y", ny), y, rtol=1e-10, atol=1e-12)


def test_uncertainty_channel_of_one_mode_only(tmp_path: Path, open_plant) -> None:
    """Mode 2 lacks B1, B2: it gets zero weights and ignores Delta2."""
    A = [[-1.0, 0.5], [0.0, -2.0]]
    system = FTCSystem.from_arrays(
        name="partial",
        modes=[dict(A=A, B=[[1.0], [0.0]], C=[[1.0, 0.0]], D=[[0.0], [1.0]],
                    B1=[[1.0], [2.0]], B2=[[0.5]]),
               dict(A=A, B=[[0.0], [1.0]], C=[[0.0, 1.0]], D=[[1.0], [0.0]])],
        **CHAIN2,
    )
    fmu = build_fmu(system, tmp_path / "partial.fmu")
    assert validate(fmu) == []
    plant = open_plant(fmu, x0=[1.0, 1.0])
    x, D2 = np.array([1.0, 1.0]), np.array([[0.8]])
    plant.set("Delta2", D2)
    plant.set("u", [1.0])
    for mode in (1, 2, 1):
        plant.set_mode(mode)
        plant.step(0.4)
        md = system.modes[mode - 1]
        x = reference_step(system, mode, None, D2 if md.B1 is not None else None, x, np.ones(1), np.zeros(1), 0.4)
        assert np.allclose(plant.get("x", 2), x, rtol=1e-12, atol=1e-15)


def test_variable_step_sizes_compose(paper: FTCSystem, paper_fmu: Path, open_plant) -> None:
    """With inputs held, steps 0.1 + 0.2 + 0.05 + 0.65 equal one step of 1.0."""
    runs = []
    for steps in ([1.0], [0.1, 0.2, 0.05, 0.65], [0.5] * 2, [0.001] * 10 + [0.99]):
        plant = open_plant(paper_fmu, x0=[0.2, 1.0])
        plant.set_mode(2)
        plant.set("u", [1.0, -1.0])
        plant.set("w", [0.5])
        plant.set("Delta1", [[0.5, 0.0], [0.0, -0.5]])
        for h in steps:
            plant.step(h)
        runs.append(plant.get("x", 2))
    for other in runs[1:]:
        assert np.allclose(other, runs[0], rtol=1e-12, atol=0)
    plant = open_plant(paper_fmu)
    with pytest.raises(FMICallException):  # the communication point must match the FMU time
        plant.fmu.doStep(0.5, 0.1)
    plant.step(0.0)  # a zero step is a no-op
    assert np.array_equal(plant.get("x", 2), [0.0, 0.0])


def test_fmu_state_get_set_and_serialize_restore_everything(paper_fmu: Path, open_plant) -> None:
    plant = open_plant(paper_fmu, x0=[1.0, 2.0])
    plant.set_mode(2)
    plant.set("u", [0.5, -0.5])
    plant.set("Delta1", [[0.1, 0.2], [0.3, 0.4]])
    plant.step(0.3)
    snapshot = (plant.time, plant.get("x", 2), plant.get("y", 1))
    state = plant.fmu.getFMUstate()

    def continue_run(p: Plant) -> np.ndarray:
        p.set_mode(1)
        p.set("u", [-1.0, 0.0])
        p.set("w", [2.0])
        for h in (0.1, 0.7):
            p.step(h)
        return p.get("x", 2)

    first = continue_run(plant)
    plant.fmu.setFMUstate(state)
    plant.time = snapshot[0]
    assert np.array_equal(plant.get("x", 2), snapshot[1]) and np.array_equal(plant.get("y", 1), snapshot[2])
    assert plant.fmu.getInteger([plant.vr["mode"]]) == [2]  # inputs are part of the state
    assert plant.fmu.getReal([plant.vr["u[1]"], plant.vr["w[1]"], plant.vr["Delta1[2,2]"]]) == [0.5, 0.0, 0.4]
    assert np.array_equal(continue_run(plant), first)

    blob = plant.fmu.serializeFMUstate(state)
    assert isinstance(blob, bytes) and blob[:8] == b"LJPSTATE"
    plant.fmu.freeFMUstate(state)
    # a fresh instance of the same FMU continues from the serialized state
    other = open_plant(paper_fmu)
    restored = other.fmu.deSerializeFMUstate(blob)
    other.fmu.setFMUstate(restored)
    other.fmu.freeFMUstate(restored)
    other.time = snapshot[0]
    assert np.array_equal(other.get("x", 2), snapshot[1])
    assert np.array_equal(continue_run(other), first)
    with pytest.raises(FMICallException):
        other.fmu.deSerializeFMUstate(b"LJPSTATE" + blob[8:-1])  # truncated


def test_discretisations_are_cached_per_mode_step_and_delta(paper_fmu: Path, open_plant) -> None:
    messages: list[str] = []

    def logger(env, instance, status, category, message) -> None:
        messages.append(message.decode())

    # No fmpy.logging.addLoggerProxy here: it keeps the Python logger in a process-wide
    # global that would dangle after this test. The FMU passes finished messages anyway.
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    plant = open_plant(paper_fmu, callbacks=callbacks, logging=True)

    def computed() -> int:
        return sum("computed the exact discretisation" in m for m in messages)

    for _ in range(3):
        plant.step(0.1)
    assert computed() == 1
    plant.set("Delta2", [[0.0, 0.5], [0.0, 0.0]])  # Delta changed: recompute
    plant.step(0.1)
    assert computed() == 2
    plant.set_mode(2)
    plant.step(0.1)
    plant.set_mode(1)
    plant.step(0.1)  # mode 1 with this Delta and h is still cached
    assert computed() == 3
    for h in (0.2, 0.1, 0.2, 0.1):  # several step sizes fit in the cache of a mode
        plant.step(h)
    assert computed() == 4
    plant.set("u", [3.0, 1.0])  # inputs do not enter the discretisation
    plant.step(0.1)
    assert computed() == 4
    assert any("instantiated from" in m for m in messages)


def test_system_file_parameter_overrides_resources(scalar_fmu: Path, open_plant, tmp_path: Path) -> None:
    other = scalar_system([(-2.0, 1.0, 0.0, 5.0), (1.0, 1.0, 0.0, 1.0), (0.5, 0.5, 0.5, 0.5)], name="other")
    path = tmp_path / "other.txt"
    path.write_text(system_text(other))
    plant = open_plant(scalar_fmu, x0=[1.0], system_file=str(path))
    plant.set("u", [1.0])
    plant.step(0.5)
    expected = math.exp(-1.0) + (math.expm1(-1.0) / -2.0)
    assert plant.get("x", 1)[0] == pytest.approx(expected, rel=1e-12)
    assert plant.get("y", 1)[0] == pytest.approx(5.0 * expected, rel=1e-12)
    assert plant.fmu.getString([plant.vr["systemFile"]]) == [str(path).encode()]

    wrong = tmp_path / "wrong.txt"
    wrong.write_text(system_text(scalar_system(SCALAR_MODES[:2])))  # m = 2 instead of 3
    bad = open_plant(scalar_fmu, initialize=False)
    bad.fmu.setupExperiment(startTime=0.0)
    bad.fmu.enterInitializationMode()
    bad.fmu.setString([bad.vr["systemFile"]], [str(wrong)])
    with pytest.raises(FMICallException):
        bad.fmu.exitInitializationMode()


def test_invalid_calls_fail_cleanly(paper_fmu: Path, open_plant) -> None:
    plant = open_plant(paper_fmu)
    with pytest.raises(FMICallException):
        plant.set_mode(3)  # only modes 1..2
    with pytest.raises(FMICallException):
        plant.set("x0", [1.0, 1.0])  # fixed parameter after initialization
    with pytest.raises(FMICallException):
        plant.fmu.setReal([plant.vr["x[1]"]], [1.0])  # an output
    with pytest.raises(FMICallException):
        plant.fmu.doStep(0.0, -0.1)
    assert plant.fmu.getInteger([plant.vr["mode"]]) == [1]
    plant.step(0.1)  # still usable


def test_fmpy_simulate_fmu_runs_the_plant(paper: FTCSystem, paper_fmu: Path) -> None:
    result = simulate_fmu(
        str(paper_fmu), stop_time=1.0, output_interval=0.25,
        start_values={"x0[1]": 1.0, "x0[2]": -1.0, "mode": 2, "u[1]": 0.5, "Delta1[1,1]": 0.5},
        output=["x[1]", "x[2]", "y[1]"],
    )
    x = np.array([1.0, -1.0])
    D1 = np.array([[0.5, 0.0], [0.0, 0.0]])
    for _ in range(4):
        x = reference_step(paper, 2, D1, np.zeros((2, 2)), x, np.array([0.5, 0.0]), np.zeros(1), 0.25)
    assert result["time"][-1] == pytest.approx(1.0)
    assert np.allclose([result["x[1]"][-1], result["x[2]"][-1]], x, rtol=1e-10, atol=0)
    assert result["y[1]"][-1] == pytest.approx((paper.modes[1].C @ x)[0], rel=1e-10)
