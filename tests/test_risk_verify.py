"""The risk stage of ``verify`` (ftc_verify.risk.verify_stage): the plant map's ``[risk]``
table, the pass/fail rule against its target, and the stage inside ``run_verify``.

The statistical assertions run on the closed-form loop of ``tests/test_risk.py``
(``examples/envelope_delay.toml``, P = 7.24e-5 for ``|x| < 3`` within 10 s at step 0.1)
with fixed seeds; their false-failure probabilities are stated where they are made.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.controllers.files import load_controller
from ftc_verify.errors import ProblemFileError
from ftc_verify.model.files import load_system
from ftc_verify.plants.plant_map import RiskTarget, dump_plant_map, load_plant_map
from ftc_verify.risk import Settings, run_risk
from ftc_verify.risk.envelope import region_envelope
from ftc_verify.risk.verify_stage import risk_verdict, verify_risk_stage
from ftc_verify.simulation.spec import SimulationSpec

ROOT = Path(__file__).resolve().parents[1]
SYSTEM = ROOT / "examples/envelope_delay.toml"
GAINS = ROOT / "examples/envelope_delay_gains.toml"

MAP = """fmu = "plant.fmu"
[variables]
inputs = ["u"]
disturbances = ["w"]
states = ["x"]
measured = ["y"]
performance = ["y"]
[operating_point]
states = [0.0]
[region]
states_min = [-3.0]
states_max = [3.0]
[[fault]]
name = "nominal"
set = { k = 1.0 }
[[fault]]
name = "fault"
set = { k = 0.0 }
"""


def _map(folder: Path, risk: str) -> Path:
    (folder / "plant.fmu").write_bytes(b"not opened by the reference backend")
    path = folder / "plant.toml"
    path.write_text(MAP + risk)
    return path


def test_risk_table_loads_and_round_trips(tmp_path: Path) -> None:
    path = _map(tmp_path, '[risk]\nhorizon = 10\ntarget = 1e-3\nbackend = "reference"\nmax_paths = 5000\n')
    pm = load_plant_map(path)
    assert pm.risk == RiskTarget(horizon=10.0, target=1e-3, backend="reference", max_paths=5000)
    path.write_text(dump_plant_map(pm, relative_to=tmp_path))
    assert load_plant_map(path).risk == pm.risk
    assert load_plant_map(_map(tmp_path, "")).risk is None


@pytest.mark.parametrize(("risk", "named"), [
    ("[risk]\ntarget = 1e-3\n", "[risk].horizon"),
    ("[risk]\nhorizon = 10\ntarget = 1.5\n", "[risk].target"),
    ("[risk]\nhorizon = -1\n", "[risk].horizon"),
    ('[risk]\nhorizon = 10\nbackend = "gpu"\n', "[risk].backend"),
    ("[risk]\nhorizon = 10\nmax_paths = 1\n", "[risk].max_paths"),
    ("[risk]\nhorizon = 10\nlimit = 3\n", "limit"),
])
def test_bad_risk_tables_are_refused(tmp_path: Path, risk: str, named: str) -> None:
    with pytest.raises(ProblemFileError, match=named.replace("[", r"\[").replace("]", r"\]")):
        load_plant_map(_map(tmp_path, risk))


def test_risk_table_needs_a_region(tmp_path: Path) -> None:
    path = _map(tmp_path, "[risk]\nhorizon = 10\n")
    path.write_text(path.read_text().replace("[region]\nstates_min = [-3.0]\nstates_max = [3.0]\n", ""))
    with pytest.raises(ProblemFileError, match=r"\[risk\]: the envelope is \[region\]"):
        load_plant_map(path)


def _result(method: str, hits: int, ci: tuple[float, float], bound: float | None) -> dict:
    return {"envelope": "e", "horizon": 1.0, "probability": sum(ci) / 2, "ci": list(ci), "confidence": 0.95,
            "method": method, "paths": 100, "hits": hits, "backend": "reference",
            "upper_bound": {"value": bound, "reason": ""}}


def test_the_rule_against_the_target() -> None:
    assert risk_verdict(_result("importance", 40, (1e-6, 2e-6), None), None)[0] is None
    assert risk_verdict(_result("importance", 40, (1e-6, 2e-6), None), 1e-5)[0] is True
    assert risk_verdict(_result("importance", 40, (1e-6, 2e-5), None), 1e-5)[0] is False
    # too few hits: the normal interval says nothing, even below the target
    ok, detail = risk_verdict(_result("importance", 0, (0.0, 0.0), None), 1e-5)
    assert ok is False and "undecided" in detail
    # the Wilson interval of crude Monte Carlo is informative with no hit
    assert risk_verdict(_result("crude", 0, (0.0, 0.03), None), 0.05)[0] is True
    # a proved bound below the target decides, whatever the estimate
    assert risk_verdict(_result("importance", 0, (0.0, 0.0), 1e-6), 1e-5)[0] is True


@pytest.fixture(scope="module")
def loop() -> tuple:
    system = load_system(SYSTEM)
    return system, load_controller(GAINS).check(system)


def test_stage_reuses_run_risk_and_decides(tmp_path: Path, loop: tuple) -> None:
    """The stage's numbers are run_risk's on the region envelope (same seed: equal), and
    the rule passes at a target 14 times the truth 7.24e-5 and fails at one below it. With
    the seed fixed the run is deterministic; had the seed been drawn, the interval's upper
    end exceeds 1e-3 or falls below 5e-5 with probability far below 1e-6 at this relative
    error (0.2)."""
    system, controller = loop
    pm = load_plant_map(_map(tmp_path, '[risk]\nhorizon = 10\ntarget = 1e-3\nbackend = "reference"\n'))
    spec = SimulationSpec(step=0.1, horizon=5.0, seed=4, disturbance="step")
    found, ok, detail = verify_risk_stage(system, controller, pm, spec)
    direct = run_risk(system, controller, region_envelope(pm.states_min, pm.states_max, pm.states_op, "m"),
                      horizon=10.0, step=0.1, settings=Settings(seed=4), disturbance="step").estimate
    assert found["probability"] == direct.probability and tuple(found["ci"]) == direct.ci
    assert ok is True and "<= target 0.001" in detail and found["target"] == 1e-3
    assert found["ci"][1] > 5e-5
    strict = dataclasses.replace(pm, risk=dataclasses.replace(pm.risk, target=5e-5))
    ok, detail = verify_risk_stage(system, controller, strict, spec)[1:]
    assert ok is False and "above target" in detail


@pytest.mark.slow(6)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_run_verify_reports_the_stage(tmp_path: Path) -> None:
    """The stage inside run_verify (paper example, LinearJumpPlant FMU as the plant map,
    crude Monte Carlo on the reference): the report carries it, its check line follows
    the rule, the markdown report has its section."""
    from ftc_verify.plants.linear_jump import build_fmu
    from ftc_verify.plants.plant_map import linear_jump_plant_map
    from ftc_verify.verification.report import write_report
    from ftc_verify.verification.verify import run_verify

    system = load_system(ROOT / "examples/paper.toml")
    gains = load_controller(ROOT / "examples/paper_gains.toml")
    pm = linear_jump_plant_map(system, build_fmu(system, tmp_path / "plant.fmu"))
    n = system.dims[0]
    pm = dataclasses.replace(pm, states_min=np.full(n, -0.05), states_max=np.full(n, 0.05),
                             risk=RiskTarget(horizon=5.0, target=0.5, backend="reference", method="crude",
                                             max_paths=200))
    rep = run_verify(system, controller=gains, paths=4, horizon=5.0, step=0.01, seed=3, plant=pm,
                     risk=verify_risk_stage)
    d = rep.to_dict()
    risk = d["risk"]
    assert risk is not None and risk["method"] == "crude" and risk["paths"] == 200 and risk["seed"] == 3
    check = next(c for c in d["checks"] if c["name"] == "risk")
    bound = (risk["upper_bound"] or {}).get("value")
    assert check["ok"] == (risk["ci"][1] <= 0.5 or (bound is not None and bound <= 0.5))
    assert f"[{'pass' if check['ok'] else 'FAIL'}] risk: P(leave" in str(rep)
    md = (write_report(rep, tmp_path / "out")[0].parent / "report.md").read_text()
    assert "## Risk" in md and risk["envelope"] in md


def test_reference_batches_on_dask_give_the_serial_numbers(loop: tuple) -> None:
    """``run_risk`` on a Dask client (a LocalCluster of 2 threaded workers) scores the
    reference chunks on the workers and returns exactly the serial estimate for the seed
    (the paths are drawn in the client; 1,300 paths per batch: several chunks per batch)."""
    distributed = pytest.importorskip("distributed")
    system, controller = loop
    env = region_envelope(np.array([-3.0]), np.array([3.0]), np.zeros(1), "box")
    settings = Settings(seed=11, batch=1300, pilot_paths=600)

    def run(client: object = None):
        return run_risk(system, controller, env, horizon=10.0, step=0.1, settings=settings, disturbance="step",
                        client=client).estimate

    serial = run()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cl, \
            distributed.Client(cl) as client:
        with distributed.get_task_stream(client) as tasks:
            spread = run(client)
        assert len(client.scheduler_info()["workers"]) == 2
    ran = [t for t in tasks.data if "_peak_scores" in str(t["key"])]
    assert len(ran) >= 2 * 6 and len({t["worker"] for t in ran}) == 2  # >= 6 batches of >= 2 chunks, both workers
    assert spread == serial and serial.hits >= 30


def test_no_bound_is_claimed_for_a_plant_fmu(loop: tuple) -> None:
    """With a plant map the bound stage is not asked: its certificate is of the linear
    model (a fault of the FMU may move the equilibrium, which that model does not carry)."""
    system, controller = loop

    def bound(*args: object, **kw: object) -> object:
        raise AssertionError("the bound stage ran for a plant FMU")

    res = run_risk(system, controller, region_envelope(np.array([-3.0]), np.array([3.0]), np.zeros(1), "box"),
                   horizon=10.0, step=0.1, settings=Settings(method="crude", max_paths=2, batch=2), disturbance="step",
                   plant=type("Map", (), {"fmu": "plant.fmu"})(), bound=bound)
    assert res.upper_bound is not None and res.upper_bound["value"] is None
    assert "plant map's FMU (plant.fmu)" in res.upper_bound["reason"]
