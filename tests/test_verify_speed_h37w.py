"""What issue 37's speed-ups of ``verify`` rest on, checked without timing anything.

* The plant processes of the isolated Monte Carlo import only what they run: the modules
  a plant process loads (its entry module, the supervisor, and the classes of its pickled
  job) pull in neither the analysis, nor cvxpy, nor scipy, nor matplotlib
  (``ftc_verify.simulation`` loads its names on first use), nor, once a path's grid and
  samples are made, ``numpy.ma`` (which ``np.unique`` imports).
* ``ftc_verify.simulation``'s lazy names are the objects of their modules, and a
  submodule is reachable as an attribute.
* ``report.json``'s ``timings["cpu"]`` counts a waited-for child's CPU time.
* The random ``Delta``'s norm is ``np.linalg.norm(G, 2)`` bit for bit.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ftc_verify.verification.report import cpu_seconds

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

CHILD_IMPORTS = """
import json, sys
import ftc_verify.simulation.isolated, ftc_verify.simulation.supervisor, ftc_verify.plants.plant_map
import ftc_verify.controllers.controller, ftc_verify.model.system, ftc_verify.simulation.spec
from ftc_verify.model.files import load_system
from ftc_verify.simulation.paths import communication_grid, sample_paths, sample_points
system = load_system(sys.argv[1])
path = sample_paths(system.chain, 30.0, 1, 5)[0]
t, _, _ = communication_grid(path, 0.01)
assert path.times.size > 1 and sample_points(path, 0.01, t).sum() == 3001
print(json.dumps(sorted(sys.modules)))
"""


def test_plant_process_imports_stay_light() -> None:
    out = subprocess.run([sys.executable, "-c", CHILD_IMPORTS, str(EXAMPLES / "paper.toml")], capture_output=True,
                         text=True, check=True, timeout=120)
    loaded = set(json.loads(out.stdout))
    assert "ftc_verify.simulation.supervisor" in loaded and "ftc_verify.plants.fmu_session" in loaded
    heavy = {m for m in loaded if m.split(".")[0] in ("scipy", "cvxpy", "matplotlib", "control", "clarabel")
             or m.startswith(("ftc_verify.analysis", "ftc_verify.synthesis", "numpy.ma.")) or m == "numpy.ma"}
    assert not heavy, sorted(heavy)[:10]


def test_lazy_names_are_the_module_objects() -> None:
    import ftc_verify.simulation as sim
    from ftc_verify.simulation import supervisor, vectorised

    assert sim.Supervisor is supervisor.Supervisor and sim.energies_reference is vectorised.energies_reference
    assert sim.vectorised is vectorised
    assert set(sim.__all__) <= set(dir(sim))
    with pytest.raises(AttributeError):
        sim.no_such_name  # noqa: B018


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork")
def test_cpu_seconds_counts_a_waited_child() -> None:
    before = cpu_seconds()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child burns 0.3 s of CPU
        t = time.process_time()
        while time.process_time() - t < 0.3:
            pass
        os._exit(0)
    os.waitpid(pid, 0)
    after = cpu_seconds()
    assert after["children"] - before["children"] >= 0.25
    assert after["total"] == pytest.approx(after["process"] + after["children"], abs=2e-3)


def test_random_delta_norm_is_numpys_two_norm() -> None:
    from ftc_verify.simulation.delta import DeltaSchedule, delta_segments
    from ftc_verify.model.system import FTCSystem

    system = FTCSystem.from_arrays(
        name="delta", modes=[dict(A=-np.eye(3), B=np.ones((3, 2)), C=np.ones((1, 3)), D=np.ones((3, 1)),
                                  A1=np.ones((3, 2)), A2=np.ones((3, 3)), B1=np.ones((3, 1)), B2=np.ones((2, 2)))] * 2,
        alpha=[[-1.0, 1.0], [1.0, -1.0]], beta_min=[[0.0, 2.0], [2.0, 0.0]], beta_max=[[0.0, 3.0], [3.0, 0.0]])
    from ftc_verify.simulation.paths import sample_paths

    path = sample_paths(system.chain, 20.0, 1, 3)[0]
    got = delta_segments(system, path, DeltaSchedule("random"))
    gen = path.delta_generator()
    for d1, d2 in got:  # the same draws, normalised by np.linalg.norm(G, 2) as before
        for d, shape in ((d1, (2, 3)), (d2, (1, 2))):
            G = gen.standard_normal(shape)
            norm = float(np.linalg.norm(G, 2))
            assert d.tobytes() == (G * (gen.random() / norm)).tobytes()


def test_early_reference_is_the_call_made_in_turn(paper_system, paper_gains) -> None:
    """The thread's reference equals ``simulate_reference`` on the same paths, also when the
    paths come back pickled (from the plant processes); other paths (snapped to the step
    grid) get ``None``, and the caller computes its own."""
    import pickle

    from ftc_verify.controllers import Controller
    from ftc_verify.simulation.paths import snap_to_grid
    from ftc_verify.simulation.reference import simulate_reference
    from ftc_verify.simulation.spec import spec_from
    from ftc_verify.verification.agreement import EarlyReference

    spec = spec_from(None, {"n_paths": 3, "horizon": 3.0, "step": 0.01, "seed": 4, "delta": "random"}).with_seed()
    paths = spec.sample_paths(paper_system.chain)
    ctrl = Controller.state_feedback(list(paper_gains))
    early = EarlyReference(paper_system, ctrl, paths, spec)
    got = early.result_for(pickle.loads(pickle.dumps(paths)))
    want = simulate_reference(paper_system, ctrl, paths, spec=spec)
    for a, b in zip(got.records, want.records, strict=True):
        assert a.x.tobytes() == b.x.tobytes() and a.u.tobytes() == b.u.tobytes()
    snapped = [snap_to_grid(p, 0.07)[0] for p in paths]
    assert any(len(s.times) > 1 and not np.array_equal(s.times, p.times) for s, p in zip(snapped, paths))
    assert early.result_for(snapped) is None and early.result_for(paths[:2]) is None


def test_early_reference_raises_what_the_reference_raised(paper_system) -> None:
    from ftc_verify.controllers import Controller
    from ftc_verify.errors import ValidationError
    from ftc_verify.simulation.spec import spec_from
    from ftc_verify.verification.agreement import EarlyReference

    spec = spec_from(None, {"n_paths": 2, "horizon": 1.0, "step": 0.01, "seed": 4}).with_seed()
    paths = spec.sample_paths(paper_system.chain)
    wrong = Controller.state_feedback([np.ones((2, 3))] * 2)  # the plant has 2 states
    early = EarlyReference(paper_system, wrong, paths, spec)
    with pytest.raises(ValidationError):
        early.result_for(paths)
