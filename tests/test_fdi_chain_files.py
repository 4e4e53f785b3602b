"""The FDI model's keys in system files and plant maps (issue 23): validation and round trips.

Every new ``[chain]`` key -- ``delay_phases``, ``false_alarm_min``, ``false_alarm_max`` --
is refused with one error naming the file, the key and the value when it is malformed
(wrong shape, negative rate, reversed interval, one end only, a phase count that is not a
whole number >= 1), also on the command line (exit 2, one line, nothing written); a
valid file round-trips exactly; the paper's model writes none of them; a plant map's
``[chain]`` takes the same keys; the joint chain's size and its one-line description.
"""

from __future__ import annotations

from pathlib import Path

import cli_inprocess
import numpy as np
import pytest

from ftc_verify.errors import ProblemFileError
from ftc_verify.model.chain import MAX_DELAY_PHASES
from ftc_verify.model.files import dump_system, load_system, save_system

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
PAPER_TEXT = PAPER.read_text()
CHAIN_LINE = "beta_max = [[0.0, 3.0], [3.5, 0.0]]"
FA_MIN = "false_alarm_min = [[0.0, 0.05], [0.05, 0.0]]"
FA_MAX = "false_alarm_max = [[0.0, 0.2], [0.2, 0.0]]"


def _with(tmp_path: Path, *lines: str) -> Path:
    assert CHAIN_LINE in PAPER_TEXT
    p = tmp_path / "system.toml"
    p.write_text(PAPER_TEXT.replace(CHAIN_LINE, "\n".join((CHAIN_LINE, *lines)), 1))
    return p


@pytest.mark.parametrize("lines, fragments", [
    (["delay_phases = 0"], ["chain.delay_phases", "from 1 to", "got 0"]),
    (["delay_phases = -3"], ["chain.delay_phases", "got -3"]),
    (["delay_phases = 2.5"], ["[chain].delay_phases", "whole number", "2.5"]),
    (["delay_phases = 2.0"], ["[chain].delay_phases", "whole number", "2.0"]),
    (["delay_phases = true"], ["[chain].delay_phases", "whole number", "True"]),
    (['delay_phases = "4"'], ["[chain].delay_phases", "whole number", "'4'"]),
    ([f"delay_phases = {MAX_DELAY_PHASES + 1}"], ["chain.delay_phases", f"got {MAX_DELAY_PHASES + 1}"]),
    ([FA_MIN], ["chain.false_alarm_min is given without chain.false_alarm_max"]),
    ([FA_MAX], ["chain.false_alarm_max is given without chain.false_alarm_min"]),
    ([FA_MIN, "false_alarm_max = [[0.0, 0.01], [0.2, 0.0]]"],
     ["chain.false_alarm_min[1][2] = 0.05 exceeds chain.false_alarm_max[1][2] = 0.01", "reversed"]),
    (["false_alarm_min = [[0.0, -0.1], [0.0, 0.0]]", FA_MAX], ["chain.false_alarm_min[1][2]", ">= 0", "-0.1"]),
    ([FA_MIN, "false_alarm_max = [[0.0, 0.2, 0.1], [0.2, 0.0, 0.1]]"], ["chain.false_alarm_max", "(2, 2)", "(2, 3)"]),
    ([FA_MIN, 'false_alarm_max = [[0.0, "x"], [0.2, 0.0]]'], ["chain.false_alarm_max", "'x'"]),
    (["false_alarms = 3"], ["[chain]", "unknown key", "false_alarms"]),
])
def test_each_bad_key_is_one_error_naming_it(tmp_path: Path, lines: list[str], fragments: list[str]) -> None:
    bad = _with(tmp_path, *lines)
    with pytest.raises(ProblemFileError) as caught:
        load_system(bad)
    message = str(caught.value)
    assert message.startswith(str(bad)), message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


def test_the_command_line_refuses_with_exit_2(tmp_path: Path) -> None:
    bad = _with(tmp_path, "delay_phases = 0")
    out = cli_inprocess.run_cli(["analyze", str(bad), "--gains", str(ROOT / "examples" / "paper_gains.toml")])
    assert out.returncode == 2 and out.stdout == "" and out.stderr.count("\n") == 1, out
    assert "delay_phases" in out.stderr and "Traceback" not in out.stderr


def test_missed_detections_are_accepted(tmp_path: Path) -> None:
    """A ``beta_min`` of 0: the FDI may never detect that fault (a vertex of the box)."""
    p = tmp_path / "missed.toml"
    p.write_text(PAPER_TEXT.replace("beta_min = [[0.0, 2.0], [2.5, 0.0]]", "beta_min = [[0.0, 0.0], [2.5, 0.0]]", 1))
    chain = load_system(p).chain
    assert any(v[0, 1] == 0.0 for v in chain.vertices())
    assert "missed detections" in chain.describe()


def test_round_trip_and_the_paper_model_writes_no_new_key(tmp_path: Path) -> None:
    system = load_system(_with(tmp_path, "delay_phases = 4", FA_MIN, FA_MAX))
    chain = system.chain
    assert chain.delay_phases == 4 and chain.rate_shape == (2, 2, 2)
    assert chain.n_states == 2 + 2 * 1 * 4 == len(chain.states)
    save_system(system, tmp_path / "again.toml")
    again = load_system(tmp_path / "again.toml")
    assert again == system and again.name == system.name
    np.testing.assert_array_equal(again.chain.false_alarm_max, [[0.0, 0.2], [0.2, 0.0]])
    text = dump_system(load_system(PAPER))
    for key in ("delay_phases", "false_alarm"):
        assert key not in text
    assert load_system(PAPER).chain.describe() == "FDI: exponential detection delays (the paper's model)"
    assert chain.describe().startswith("FDI: Erlang-4 detection delays") and "false alarms" in chain.describe()


def test_a_plant_map_chain_takes_the_same_keys(tmp_path: Path) -> None:
    from ftc_verify.plants.plant_map import load_plant_map

    text = (ROOT / "examples" / "motor.plant.toml").read_text()
    line = "beta_max = [[0.0, 3.0], [3.5, 0.0]]"
    assert line in text
    p = tmp_path / "motor.plant.toml"
    (tmp_path / "Motor.fmu").write_bytes(b"")  # the map is read, the FMU not opened
    p.write_text(text.replace(line, f"{line}\ndelay_phases = 3\n{FA_MIN}\n{FA_MAX}", 1))
    chain = load_plant_map(p).chain
    assert chain is not None and chain.delay_phases == 3 and chain.has_false_alarms
    p.write_text(text.replace(line, f"{line}\ndelay_phases = 1.5", 1))
    with pytest.raises(ProblemFileError, match=r"\[chain\]\.delay_phases: expected a whole number"):
        load_plant_map(p)
