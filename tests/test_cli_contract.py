"""The command line's contract (README "Exit codes and what they promise").

Each command is run on a catalogue of bad inputs and of hard outcomes, and the test
asserts the exit code, one message naming the field or file and the value, no traceback,
strict JSON, and that nothing is left behind (no output file, no staging folder, no
extracted FMU). The commands run in the test process (``tests/cli_inprocess.py``: the
CLI's ``main`` with the folder, environment and streams a subprocess would have; a fresh
interpreter costs 0.4-1.4 s of CPU each); what is about the process runs as a user runs
it (``python -m ftc_verify``): SIGTERM, a closed pipe, and a sample of the catalogue
whose exit codes and outputs must equal the in-process runs'.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cli_inprocess
import pytest
from plant_stages import wait_for_fmu_steps

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "examples" / "paper.toml")
GAINS = str(ROOT / "examples" / "paper_gains.toml")
PAPER_TEXT = Path(PAPER).read_text(encoding="utf-8")
FIRST_A = "A  = [[1.0, 0.0], [0.0, 0.8]]"


def run_subprocess(args: list[str], cwd: Path, env: dict[str, str] | None = None,
                   timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """``python -m ftc_verify ARGS`` as a user runs it, its temporary folder ``cwd/.tmp``."""
    full_env = os.environ | {"TMPDIR": str(cwd / ".tmp")} | (env or {})
    (cwd / ".tmp").mkdir(exist_ok=True)
    return subprocess.run([sys.executable, "-m", "ftc_verify", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd, env=full_env)


def run_cli(args: list[str], cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """The same in this process (``tests/cli_inprocess.py``: the folder, environment and
    streams the subprocess would have); :func:`test_in_process_runs_are_the_subprocess_runs`
    checks that both give the same exit code and output."""
    (cwd / ".tmp").mkdir(exist_ok=True)
    return cli_inprocess.run_cli(args, cwd, {"TMPDIR": str(cwd / ".tmp")} | (env or {}))


def strict_json(text: str) -> Any:
    """Parse JSON refusing NaN and Infinity (which Python's json would accept)."""
    def refuse(name: str) -> None:
        raise AssertionError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


def files_under(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def write_inputs(folder: Path) -> None:
    """The bad input files of the catalogue."""
    (folder / "malformed.toml").write_text('name = "bad"\n[[chain\n')
    (folder / "nan.toml").write_text(PAPER_TEXT.replace(FIRST_A, "A  = [[nan, 0.0], [0.0, 0.8]]", 1))
    (folder / "nongen.toml").write_text(PAPER_TEXT.replace("[[-0.5, 0.5]", "[[-0.5, 0.7]", 1))
    (folder / "bigint.toml").write_text(PAPER_TEXT.replace(FIRST_A, f"A  = [[1{'0' * 400}, 0.0], [0.0, 0.8]]", 1))
    (folder / "huge.toml").write_text(PAPER_TEXT.replace(FIRST_A, "A  = [[1e200, 0.0], [0.0, 0.8]]", 1))
    head, tail = PAPER_TEXT.rsplit("[[mode]]", 1)
    tail = tail.replace("A1 = [[0.1, 0.0], [0.0, 0.1]]", "A1 = [[0.1], [0.1]]", 1)
    (folder / "delta.toml").write_text(head + "[[mode]]" + tail.replace("A2 = [[0.1, 0.0], [0.0, 0.1]]",
                                                                        "A2 = [[0.1, 0.1]]", 1))
    (folder / "mixed.toml").write_text("[[gain]]\nK = [[1.0, 2.0], [3.0, 4.0]]\n[[controller]]\nAc = [[-1.0]]\n"
                                       "Bc = [[1.0, 0.0]]\nCc = [[1.0], [0.0]]\nDc = [[0.0, 0.0], [0.0, 0.0]]\n")
    (folder / "shape.toml").write_text("[[gain]]\nK = [[1.0, 2.0, 3.0], [3.0, 4.0, 5.0]]\n"
                                       "[[gain]]\nK = [[1.0, 2.0], [3.0, 4.0]]\n")
    (folder / "adir").mkdir()
    (folder / "afile").write_text("")
    (folder / ".tmp").mkdir()


#: (id, arguments, environment, substrings the one error line must contain)
BAD_INPUT = [
    ("malformed TOML", ["analyze", "malformed.toml", "--gains", GAINS], {}, ["malformed.toml", "line 2"]),
    ("NaN entry", ["analyze", "nan.toml", "--gains", GAINS], {}, ["nan.toml", "mode[1].A", "nan"]),
    ("non-generator", ["analyze", "nongen.toml", "--gains", GAINS], {}, ["nongen.toml", "chain.alpha", "0.7"]),
    ("400-digit integer", ["analyze", "bigint.toml", "--gains", GAINS], {}, ["bigint.toml", "mode[1].A", "308"]),
    ("entry 1e200", ["verify", "huge.toml", "--gains", GAINS, "--paths", "5", "--out", "out"], {},
     ["huge.toml", "mode[1].A", "1e+200"]),
    ("Delta shapes differ", ["verify", "delta.toml", "--gains", GAINS, "--paths", "5", "--out", "out"], {},
     ["delta.toml", "mode 2", "Delta1"]),
    ("mixed controller tables", ["analyze", PAPER, "--controller", "mixed.toml"], {},
     ["mixed.toml", "[[gain]]", "[[controller]]"]),
    ("controller shapes", ["analyze", PAPER, "--controller", "shape.toml"], {}, ["shape.toml", "gain[2].K", "2 x 2"]),
    ("missing file", ["analyze", "nowhere.toml", "--gains", GAINS], {}, ["nowhere.toml", "no such file"]),
    ("synthesize -o DIR", ["synthesize", PAPER, "--gamma", "0.8", "--method", "two-step", "-o", "adir"], {},
     ["--output adir", "folder"]),
    ("simulate --plot DIR", ["simulate", PAPER, "--gains", GAINS, "--plot", "adir"], {}, ["--plot adir", "folder"]),
    ("simulate --plot x.xyz", ["simulate", PAPER, "--gains", GAINS, "--plot", "x.xyz"], {}, ["--plot x.xyz", ".xyz"]),
    ("horizon 1e-9", ["simulate", PAPER, "--gains", GAINS, "--horizon", "1e-9"], {}, ["--horizon 1e-09"]),
    ("step over horizon", ["verify", PAPER, "--gains", GAINS, "--step", "2", "--horizon", "1", "--out", "out"], {},
     ["--horizon 1", "--step 2"]),
    ("--paths 1", ["verify", PAPER, "--gains", GAINS, "--paths", "1", "--out", "out"], {}, ["--paths 1"]),
    ("--out under a file", ["verify", PAPER, "--gains", GAINS, "--paths", "5", "--out", "afile/sub"], {},
     ["--out afile/sub", "not a folder"]),
    ("negative seed", ["simulate", PAPER, "--gains", GAINS, "--seed", "-1"], {}, ["--seed", "-1"]),
    ("bad memory limit", ["analyze", PAPER, "--gains", GAINS], {"FTC_VERIFY_MEMORY_LIMIT": "abc"},
     ["FTC_VERIFY_MEMORY_LIMIT", "abc"]),
    ("LMIs above the memory limit", ["analyze", PAPER, "--gains", GAINS], {"FTC_VERIFY_MEMORY_LIMIT": "1M"},
     ["Lemma 4.1", "MB", "1 MB", "--no-lmi"]),
    ("records above the memory limit",
     ["simulate", PAPER, "--gains", GAINS, "--paths", "100000", "--horizon", "1000", "--step", "0.001"], {},
     ["100000 recorded paths", "TB", "--paths"]),
]


@pytest.mark.parametrize("case, args, env, needles", BAD_INPUT, ids=[c[0] for c in BAD_INPUT])
def test_bad_input_exit_2_one_message_nothing_left(tmp_path: Path, case: str, args: list[str],
                                                   env: dict[str, str], needles: list[str]) -> None:
    write_inputs(tmp_path)
    before = files_under(tmp_path)
    t0 = time.perf_counter()
    proc = run_cli(args, tmp_path, env)
    assert proc.returncode == 2, (case, proc.returncode, proc.stderr)
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert files_under(tmp_path) == before  # no output, no staging folder, no extracted FMU
    assert time.perf_counter() - t0 < 60  # refused up front, not after the run


@pytest.mark.slow(17)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_divergence_is_a_result_on_both_backends(tmp_path: Path) -> None:
    """A loop sampled too slowly (h = 10) diverges: exit 1 with strict JSON naming the paths
    and times, the same on both backends; ``verify`` writes a ``fail`` report saying so."""
    found = {}
    for backend in ("reference", "fmu"):
        proc = run_cli(["simulate", PAPER, "--gains", GAINS, "--step", "10", "--horizon", "1000", "--paths", "3",
                        "--backend", backend, "--seed", "1", "--json"], tmp_path)
        assert proc.returncode == 1, proc.stderr
        d = strict_json(proc.stdout)
        assert d["verdict"] == "fail" and d["y_norm"] == [None, None, None]
        assert [p["path"] for p in d["diverged"]] == [1, 2, 3] and "diverged" in d["divergence"]
        found[backend] = [p["t"] for p in d["diverged"]]
    assert found["reference"] == found["fmu"]
    # 100 s: the five paths diverge at t = 31-35 s (seed 3); 1000 s only lengthened the sampled loop's check
    proc = run_cli(["verify", PAPER, "--gains", GAINS, "--step", "10", "--horizon", "100", "--paths", "5",
                    "--seed", "3", "--out", "rep"], tmp_path)
    assert proc.returncode == 1 and "verdict: fail" in proc.stdout, proc.stderr
    report = strict_json((tmp_path / "rep" / "report.json").read_text())
    assert report["verdict"] == "fail" and report["mc"]["diverged"] == 5 and report["mc"]["upper_bound"] is None
    assert "5 of 5 paths diverged" in (tmp_path / "rep" / "report.md").read_text()


@pytest.mark.slow(5)  # seconds measured on 2 busy cores: scheduled first
def test_stale_files_are_replaced_by_the_new_run(tmp_path: Path, paper_verify_run: SimpleNamespace) -> None:
    """A failing run into the folder of a passing one leaves only its own files. The passing
    run's folder is a copy of the session's ``verify`` of the paper's gains (the
    ``paper_verify_run`` fixture: the same command, run once for the tests that read it)."""
    out = tmp_path / "rep"
    ok = paper_verify_run
    assert ok.returncode == 0, ok.stdout + ok.stderr
    shutil.copytree(ok.out, out)
    assert (out / "gamma_bracket.png").is_file() and (out / "report.json").is_file()
    unstable = tmp_path / "unstable.toml"
    unstable.write_text("[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\n[[gain]]\nK = [[0.0, 0.0], [0.0, 0.0]]\n")
    bad = run_cli(["verify", PAPER, "--gains", str(unstable), "--paths", "5", "--horizon", "3", "--out", "rep"],
                  tmp_path)
    assert bad.returncode == 1, bad.stderr
    assert strict_json((out / "report.json").read_text())["verdict"] == "fail"
    assert not (out / "gamma_bracket.png").exists()  # the earlier run's plot is gone
    assert files_under(tmp_path) - files_under(out.parent) == set()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".") and p.name != ".tmp") == []


@pytest.mark.slow(10)  # seconds on 2 busy cores (--durations at load 9, / 4): scheduled first
def test_sigterm_cleans_up_like_ctrl_c(tmp_path: Path) -> None:
    """SIGTERM in the FMU Monte Carlo stage: exit 143, one line, no staging folder beside
    ``--out``, no ``--out``, no extracted FMU left in the temporary folder."""
    (tmp_path / ".tmp").mkdir()
    env = os.environ | {"TMPDIR": str(tmp_path / ".tmp")}
    proc = subprocess.Popen([sys.executable, "-m", "ftc_verify", "verify", PAPER, "--gains", GAINS,
                             "--paths", "3000", "--horizon", "30", "--out", "rep"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for_fmu_steps(proc, tmp_path / ".tmp", 0.1)  # the FMU extracted and stepping (a 0.5 s sleep before)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, (out, err)
    assert err.strip() == "ftc-verify: terminated" and "Traceback" not in err
    assert list((tmp_path / ".tmp").iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == [".tmp"]


def test_closed_pipe_exit_141_without_traceback(tmp_path: Path) -> None:
    """``analyze --json | head -1``: the reader leaves; exit 141, no traceback."""
    proc = subprocess.Popen([sys.executable, "-m", "ftc_verify", "analyze", PAPER, "--gains", GAINS, "--json"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # before the answer is printed (analysis takes about a second)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141
    assert "Traceback" not in err and "pipe closed" in err


def test_corrupted_cached_binary_is_rebuilt(tmp_path: Path) -> None:
    """A truncated cached FMU binary is detected by its recorded hash and compiled again."""
    env = {"FTC_VERIFY_CACHE": str(tmp_path / "cache")}
    first = run_cli(["build-fmus"], tmp_path, env)
    assert first.returncode == 0, first.stderr
    binaries = [p for p in (tmp_path / "cache").rglob("LinearJumpPlant-*") if not p.name.endswith((".sha256", ".lock"))]
    assert len(binaries) == 1
    data = binaries[0].read_bytes()
    binaries[0].write_bytes(data[: len(data) // 3])
    proc = run_cli(["simulate", PAPER, "--gains", GAINS, "--paths", "2", "--horizon", "1", "--backend", "fmu",
                    "--json"], tmp_path, env)
    assert proc.returncode == 0, proc.stderr
    assert strict_json(proc.stdout)["verdict"] == "done"
    assert binaries[0].read_bytes() == data  # compiled again, identical


def test_stable_without_certificate_exits_3(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Exit 3 = stable by the exact spectral test, no LMI certificate found (never 1). The
    Theorem 3.1 stage is replaced by one that finds nothing, in process: both its solve
    (``mes_lmi``) and its no-solve check on Theorem 3.2's ``P`` (``mes_known``, which
    ``analyze`` tries first on an uncertain loop)."""
    import dataclasses
    import importlib

    from ftc_verify.cli.main import main

    analysis = importlib.import_module("ftc_verify.analysis.analyze")  # the module, not the function

    real = analysis.mes_lmi

    def nothing_found(loop: Any, *, solver: str | None = None, known: Any = ()) -> Any:
        return dataclasses.replace(real(loop, solver=solver, known=known), outcome="infeasible", certificate=None)

    monkeypatch.setattr(analysis, "mes_lmi", nothing_found)
    monkeypatch.setattr(analysis, "mes_known", lambda loop, known: None)
    assert main(["analyze", PAPER, "--gains", GAINS]) == 3
    out = capsys.readouterr().out
    assert "stable by the exact spectral test, but NO LMI certificate found" in out


def test_no_lmi_answers_from_the_exact_test(tmp_path: Path) -> None:
    proc = run_cli(["analyze", PAPER, "--gains", GAINS, "--no-lmi", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    d = strict_json(proc.stdout)
    assert d["lmi_requested"] is False and d["mss"]["stable"] is True and d["mes_lmi"]["outcome"] == "not requested"


#: Catalogue cases run again as subprocesses: an argparse error, a file error, an
#: environment error, an error of ``verify``'s output checks.
SAMPLE = ["missing file", "--paths 1", "bad memory limit", "--out under a file"]


def test_in_process_runs_are_the_subprocess_runs(tmp_path: Path) -> None:
    """The in-process runner gives what ``python -m ftc_verify`` gives: the same exit
    code, stdout and stderr, for a sample of the bad-input catalogue (one line each, no
    traceback) and a run that succeeds (``analyze --no-lmi``, stdout compared without its
    timings)."""
    write_inputs(tmp_path)
    cases = {c[0]: c for c in BAD_INPUT}
    for case in SAMPLE:
        _, args, env, _needles = cases[case]
        real, here = run_subprocess(args, tmp_path, env), run_cli(args, tmp_path, env)
        assert (real.returncode, real.stdout, real.stderr) == (here.returncode, here.stdout, here.stderr), case
        assert real.returncode == 2 and len(real.stderr.strip().splitlines()) == 1, (case, real.stderr)
    args = ["analyze", PAPER, "--gains", GAINS, "--no-lmi", "--json"]
    real, here = run_subprocess(args, tmp_path), run_cli(args, tmp_path)
    assert real.returncode == here.returncode == 0 and real.stderr == here.stderr == "", (real.stderr, here.stderr)
    a, b = strict_json(real.stdout), strict_json(here.stdout)
    assert a["timings"].keys() == b["timings"].keys()
    assert untimed(a) == untimed(b)


def untimed(value: Any) -> Any:
    """``value`` without its ``timings`` and ``seconds`` entries (at every depth)."""
    if isinstance(value, dict):
        return {k: untimed(v) for k, v in value.items() if k not in ("timings", "seconds")}
    if isinstance(value, list):
        return [untimed(v) for v in value]
    return value
