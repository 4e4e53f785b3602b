"""cvxpy's "Solution may be inaccurate" is handled where the package solves: the status it
repeats is returned and recorded, the warning is not passed on; any other warning is."""

from __future__ import annotations

import warnings
from typing import Any

import pytest

from ftc_verify.analysis.solvers import INACCURATE_WARNING, solve


class _Problem:
    """Stands for a cvxpy problem whose solver ends with ``status`` and warns ``message``."""

    def __init__(self, status: str, message: str) -> None:
        self.status = "unsolved"
        self._final, self._message = status, message

    def solve(self, solver: str, **settings: Any) -> None:
        warnings.warn(self._message, UserWarning, stacklevel=2)
        self.status = self._final


def test_the_inaccurate_warning_becomes_the_recorded_status() -> None:
    message = (f"{INACCURATE_WARNING}. Try another solver, adjusting the solver settings, or solve with "
               "verbose=True for more information.")  # cvxpy's text
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = solve(_Problem("optimal_inaccurate", message), "clarabel")
    assert caught == [] and outcome.status == "optimal_inaccurate" and outcome.solver == "clarabel"
    assert outcome.solved  # the point is used, and the certificate decides


def test_other_warnings_pass() -> None:
    with pytest.warns(UserWarning, match="something else"):
        outcome = solve(_Problem("optimal", "something else"), "clarabel")
    assert outcome.status == "optimal"
