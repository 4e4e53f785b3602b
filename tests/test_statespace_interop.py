"""python-control in and out: ``FTCSystem.from_statespace`` and ``ClosedLoop.to_statespace``.

Round trip of the paper's systems, the refusals (discrete time, feedthrough, unknown or
misused signals), the frozen loops against our eigenvalues and python-control's norm
against :func:`ftc_verify.analysis.crossval.cross_validate`, and the documentation's example.
"""

from __future__ import annotations

import math
import re
import runpy
import subprocess
import sys
from pathlib import Path

import control
import numpy as np
import pytest

from ftc_verify.analysis import closed_loop, cross_validate
from ftc_verify.controllers import Controller, load_controller
from ftc_verify.errors import ValidationError
from ftc_verify.model import FTCSystem, load_system

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
WEIGHTS = ("A1", "A2", "B1", "B2")


def as_statespace(system: FTCSystem, *, measured: bool) -> list:
    """One ``control.ss`` per mode: inputs ``u[k]`` then ``w``, outputs ``y`` then ``m[k]``."""
    out = []
    for md in system.modes:
        C = np.vstack([md.C, md.measured]) if measured else md.C
        outputs = ["y"] + ([f"m[{k}]" for k in range(md.ny_measured)] if measured else [])
        out.append(control.ss(md.A, np.hstack([md.B, md.D]), C, 0,
                              inputs=[f"u[{k}]" for k in range(md.B.shape[1])] + ["w"], outputs=outputs))
    return out


def weights(system: FTCSystem) -> list[dict[str, np.ndarray]]:
    return [{k: getattr(md, k) for k in WEIGHTS if getattr(md, k) is not None} for md in system.modes]


# ------------------------------------------------------------------ in

@pytest.mark.parametrize("file, measured", [("paper.toml", False), ("paper_two_outputs.toml", True)])
def test_round_trip_equals_the_system_file(file: str, measured: bool) -> None:
    want = load_system(EXAMPLES / file)
    got = FTCSystem.from_statespace(
        modes=as_statespace(want, measured=measured), chain=want.chain, inputs="u", disturbances="w",
        performance="y", measured="m" if measured else None, uncertainty=weights(want), name=want.name)
    assert got == want
    assert (got.modes[0].Cy is not None) == measured


def test_signals_by_index_and_in_any_order() -> None:
    paper = load_system(EXAMPLES / "paper.toml")
    plants = [control.ss(md.A, np.hstack([md.D, md.B[:, ::-1]]), np.vstack([md.C, md.C, [[1.0, 0.0]]]), 0)
              for md in paper.modes]  # python-control's default labels u[0..2], y[0..2]
    got = FTCSystem.from_statespace(modes=plants, chain=paper.chain, inputs=[2, "u[1]"], disturbances=0,
                                    performance="y[0]", measured=[1, 2])
    assert got.modes == paper.nominal().with_measured_output([[1.0, 2.0], [1.0, 0.0]]).modes
    assert got.name == "python-control"
    # a feedthrough into an output named in neither role does not matter
    plants = [control.ss(p.A, p.B, p.C, [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [7.0, 0.0, 0.0]]) for p in plants]
    got = FTCSystem.from_statespace(modes=plants, chain=paper.chain, inputs=[2, 1], disturbances=0, performance=0)
    assert got.modes[1].D.tolist() == paper.modes[1].D.tolist()


@pytest.fixture(scope="module")
def paper_ss() -> tuple[FTCSystem, list]:
    paper = load_system(EXAMPLES / "paper_two_outputs.toml")
    return paper, as_statespace(paper, measured=True)


def build(paper_ss, **changes):
    paper, plants = paper_ss
    kwargs = dict(modes=plants, chain=paper.chain, inputs="u", disturbances="w", performance="y", measured="m")
    kwargs.update(changes)
    return FTCSystem.from_statespace(**kwargs)


def test_discrete_time_is_refused_naming_mode_and_dt(paper_ss) -> None:
    plants = list(paper_ss[1])
    plants[1] = control.c2d(plants[1], 0.05)
    with pytest.raises(ValidationError, match=r"mode 2: .*discrete-time \(dt = 0\.05\)"):
        build(paper_ss, modes=plants)


def test_feedthrough_is_refused_naming_mode_and_entry(paper_ss) -> None:
    plants = list(paper_ss[1])
    D = np.zeros((3, 3))
    D[2, 2] = 0.25  # from w to m[1]
    plants[1] = control.ss(plants[1].A, plants[1].B, plants[1].C, D, inputs=plants[1].input_labels,
                           outputs=plants[1].output_labels)
    with pytest.raises(ValidationError, match=r"mode 2: nonzero feedthrough D\['m\[1\]', 'w'\] = 0\.25"):
        build(paper_ss, modes=plants)
    build(paper_ss, modes=plants, measured="m[0]")  # m[1] no longer used


@pytest.mark.parametrize("changes, message", [
    (dict(inputs=("u", "v")), r"inputs: 'v' is not an input of mode 1 \(inputs: \['u\[0\]', 'u\[1\]', 'w'\]\)"),
    (dict(performance="z"), r"performance: 'z' is not an output of mode 1"),
    (dict(measured=[0, 5]), r"measured: output index 5 out of range: mode 1 has 3 outputs"),
    (dict(inputs="u[0]"), r"inputs \['u\[1\]'\] of mode 1 are neither control inputs nor disturbances"),
    (dict(disturbances=["w", "u[1]"]), r"inputs \['u\[1\]'\] named both as control inputs and as disturbances"),
    (dict(inputs=["u", "u[0]"]), r"inputs: input 'u\[0\]' named twice"),
    (dict(performance=()), r"performance: no output named"),
    (dict(inputs=[True]), r"inputs: expected input labels or 0-based indices, got True"),
    (dict(uncertainty={"A1": np.eye(2)}), r"mode 1\.A2: missing while A1 is given"),
    (dict(uncertainty={"C1": np.eye(2)}), r"uncertainty: mode 1: unknown keys \['C1'\]"),
    (dict(chain="chain"), r"chain: expected a JointChain, got str"),
])
def test_misused_signals_are_refused(paper_ss, changes, message) -> None:
    with pytest.raises(ValidationError, match=message):
        build(paper_ss, **changes)


def test_modes_must_agree(paper_ss) -> None:
    plants = paper_ss[1]
    relabelled = control.ss(plants[1].A, plants[1].B, plants[1].C, 0, inputs=["u[0]", "u[1]", "d"],
                            outputs=plants[1].output_labels)
    with pytest.raises(ValidationError, match=r"mode 2: inputs \['u\[0\]', 'u\[1\]', 'd'\] differ from mode 1's"):
        build(paper_ss, modes=[plants[0], relabelled])
    bigger = control.ss(np.eye(3), np.ones((3, 3)), np.ones((3, 3)), 0, inputs=plants[0].input_labels,
                        outputs=plants[0].output_labels)
    with pytest.raises(ValidationError, match=r"mode 2: 3 states differ from mode 1 \(2\)"):
        build(paper_ss, modes=[plants[0], bigger])
    with pytest.raises(ValidationError, match=r"mode 1: expected a control.StateSpace, got TransferFunction"):
        build(paper_ss, modes=[control.tf([1.0], [1.0, 1.0]), plants[1]])
    with pytest.raises(ValidationError, match=r"modes: expected a non-empty sequence"):
        build(paper_ss, modes=plants[0])
    with pytest.raises(ValidationError, match=r"3 mode tables given but chain.alpha has 2 rows"):
        build(paper_ss, modes=[*plants, plants[0]])


def test_model_import_does_not_import_control() -> None:
    code = "import sys, ftc_verify.model, ftc_verify.analysis.closedloop; print('control' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ------------------------------------------------------------------ out

def loops():
    paper = load_system(EXAMPLES / "paper.toml")
    phased = load_system(EXAMPLES / "paper_phase_type.toml")
    gains = load_controller(EXAMPLES / "paper_gains.toml")
    return {
        "state feedback": closed_loop(paper, gains),
        "observer": closed_loop(paper, load_controller(EXAMPLES / "paper_observer.toml")),
        "phase-type": closed_loop(phased, gains),
    }


@pytest.mark.parametrize("name", ["state feedback", "observer", "phase-type"])
def test_frozen_loops_match_our_eigenvalues_and_crossval_norms(name: str) -> None:
    loop = loops()[name]
    frozen = loop.to_statespace()
    # distinct pairs, 1-based (as per_mode, the CLI and the reports), first-seen order
    assert list(frozen) == [(i + 1, j + 1) for i, j in dict.fromkeys(loop.modes)]
    for s, (i, j) in enumerate(loop.modes):
        G = frozen[(i + 1, j + 1)]
        assert G.dt == 0 and G.nstates == loop.n and np.array_equal(G.A, loop.A[s])
        assert np.array_equal(G.B, loop.Bw[s]) and np.array_equal(G.C, loop.Cz[s]) and not np.any(G.D)
        ours = np.sort_complex(np.linalg.eigvals(loop.A[s]))
        theirs = np.sort_complex(np.asarray(control.poles(G), dtype=complex))
        np.testing.assert_allclose(theirs, ours, rtol=1e-9, atol=1e-9)
    n_c = 0 if loop.n_plant is None else loop.n - loop.n_plant
    G = next(iter(frozen.values()))
    assert G.state_labels == [f"x[{k}]" for k in range(loop.n - n_c)] + [f"xc[{k}]" for k in range(n_c)]
    assert G.input_labels == ["w[0]"] and G.output_labels == ["z[0]"]
    checks = cross_validate(loop)
    assert {(c.true_mode, c.fdi_mode) for c in checks} == set(frozen)
    for c in checks:
        G = frozen[(c.true_mode, c.fdi_mode)]
        norm = float(control.linfnorm(G, tol=1e-10)[0])
        assert math.isclose(norm, c.linf_norm, rel_tol=1e-6), (c.true_mode, c.fdi_mode, norm, c.linf_norm)


def test_deltas_perturb_the_frozen_loops() -> None:
    loop = loops()["state feedback"]
    deltas = {"Delta1 (A)": np.eye(2), "Delta2 (B)": -np.eye(2)}
    frozen = loop.to_statespace(deltas=deltas)
    for s, (i, j) in enumerate(loop.modes):
        assert np.array_equal(frozen[(i + 1, j + 1)].A, loop.perturbed(deltas)[s])
        assert not np.array_equal(frozen[(i + 1, j + 1)].A, loop.A[s])


def test_phases_with_different_matrices_are_refused() -> None:
    from dataclasses import replace

    loop = loops()["phase-type"]
    s = [k for k, pair in enumerate(loop.modes) if pair == (1, 0)][1]
    A = list(loop.A)
    A[s] = A[s] + 1.0
    with pytest.raises(ValidationError, match=r"joint states \d+ and \d+ of the pair \(true, fdi\) = \(2, 1\)"):
        replace(loop, A=tuple(A)).to_statespace()


def test_round_trip_through_a_static_controller() -> None:
    """In, close the loop, out: the frozen loop of the matched pair is A + B K."""
    paper = load_system(EXAMPLES / "paper.toml")
    system = FTCSystem.from_statespace(modes=as_statespace(paper, measured=False), chain=paper.chain,
                                       inputs="u", disturbances="w", performance="y")
    K = [np.array([[-1.0, 0.5], [-2.0, -3.0]])] * 2
    G = closed_loop(system, Controller.state_feedback(K)).to_statespace()[(2, 2)]
    np.testing.assert_array_equal(G.A, paper.modes[1].A + paper.modes[1].B @ K[1])


# ------------------------------------------------------------------ the documentation's example

def readme_example() -> str:
    """The one python example of the docs' page "python-control in and out"."""
    text = (ROOT / "docs" / "user-guide" / "python-control.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert len(blocks) == 1, "the page has one python example"
    return blocks[0]


def test_readme_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                             capsys: pytest.CaptureFixture[str]) -> None:
    """The page's example as a script run from the repository's root, in this process
    (``runpy``: the script's own namespace; an exception or a failed ``assert`` in it fails
    the test): what it prints is the claim, not a fresh interpreter (which cost about 1 s
    of CPU of imports this process has made)."""
    script = tmp_path / "example.py"
    script.write_text(readme_example(), encoding="utf-8")
    monkeypatch.chdir(ROOT)
    runpy.run_path(str(script), run_name="__main__")
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in lines] == [
        "(1, 1) true normal, FDI normal", "(1, 2) true normal, FDI faulty",
        "(2, 1) true faulty, FDI normal", "(2, 2) true faulty, FDI faulty"]


# ------------------------------------------------------------------ names round-trip

def named_plants() -> list:
    """The paper's plant with the user's names: modes, states, inputs and outputs."""
    paper = load_system(EXAMPLES / "paper.toml")
    return [control.ss(md.A, np.hstack([md.B, md.D]), np.vstack([md.C, [[1.0, 0.0]]]), 0, name=name,
                       states=["pos", "vel"], inputs=["thrust", "brake", "gust"], outputs=["pos_err", "pos_meas"])
            for md, name in zip(paper.modes, ("nominal", "faulty"))]


def test_names_round_trip_through_the_system_and_the_closed_loop() -> None:
    paper = load_system(EXAMPLES / "paper.toml")
    system = FTCSystem.from_statespace(modes=named_plants(), chain=paper.chain, inputs=["thrust", "brake"],
                                       disturbances="gust", performance="pos_err", measured="pos_meas")
    names = system.names
    assert names is not None and names.modes == ("nominal", "faulty") and names.states == ("pos", "vel")
    assert names.inputs == ("thrust", "brake") and names.disturbances == ("gust",)
    assert names.performance == ("pos_err",) and names.measured == ("pos_meas",)
    assert system.nominal().names == names  # kept where the system is rebuilt
    gains = load_controller(EXAMPLES / "paper_gains.toml")
    frozen = closed_loop(system, gains).to_statespace()
    assert list(frozen) == [(1, 1), (1, 2), (2, 1), (2, 2)]
    assert frozen[(2, 1)].name == "true faulty, FDI nominal"
    for G in frozen.values():
        assert G.state_labels == ["pos", "vel"] and G.input_labels == ["gust"] and G.output_labels == ["pos_err"]
    observer = closed_loop(system, load_controller(EXAMPLES / "paper_observer.toml")).to_statespace()
    G = observer[(1, 1)]
    assert G.state_labels[:2] == ["pos", "vel"] and G.state_labels[2:] == [f"xc[{k}]" for k in range(G.nstates - 2)]
    # the per-mode check of analyze is keyed as the frozen loops are
    assert {(c.true_mode, c.fdi_mode) for c in cross_validate(closed_loop(system, gains))} == set(frozen)


def test_automatic_names_and_files_get_the_defaults() -> None:
    paper = load_system(EXAMPLES / "paper.toml")
    plants = [control.ss(md.A, np.hstack([md.B, md.D]), md.C, 0) for md in paper.modes]  # sys[N], u[k], y[0]
    system = FTCSystem.from_statespace(modes=plants, chain=paper.chain, inputs=[0, 1], disturbances=2,
                                       performance=0)
    assert system.names is not None and system.names.modes == ("mode 1", "mode 2")
    assert paper.names is None and paper.signal_names.states == ("x[0]", "x[1]")
    G = closed_loop(paper, load_controller(EXAMPLES / "paper_gains.toml")).to_statespace()[(2, 1)]
    assert G.name == "true mode 2, FDI mode 1" and G.input_labels == ["w[0]"] and G.output_labels == ["z[0]"]


def test_names_of_the_wrong_length_are_refused() -> None:
    from dataclasses import replace

    from ftc_verify.model.names import SignalNames

    paper = load_system(EXAMPLES / "paper.toml")
    bad = replace(paper.signal_names, states=("only-one",))
    with pytest.raises(ValidationError, match=r"names\.states: 1 names \['only-one'\] for 2 states"):
        FTCSystem(paper.name, paper.modes, paper.chain, names=bad)
    assert isinstance(bad, SignalNames)
