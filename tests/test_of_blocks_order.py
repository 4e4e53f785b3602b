"""The output-feedback blocks keep the controller's order (a hypothesis case: a static
output-feedback controller scaled onto --k-max came back with the plant's order)."""

from __future__ import annotations

import numpy as np
import pytest

from ftc_verify.controllers.controller import Controller
from ftc_verify.model.files import load_system
from ftc_verify.synthesis.of_blocks import bounded_blocks, controller_blocks, controller_from_blocks


@pytest.mark.parametrize("order", [0, 1, 2, 3])
def test_blocks_round_trip_keeps_the_order(order: int) -> None:
    system = load_system("examples/paper.toml")
    _, nu, _, _ = system.dims
    ny = system.ny_measured
    rng = np.random.default_rng(order)
    ctrl = Controller.dynamic([rng.standard_normal((order, order)) for _ in range(system.m)],
                              [rng.standard_normal((order, ny)) for _ in range(system.m)],
                              [rng.standard_normal((nu, order)) for _ in range(system.m)],
                              [rng.standard_normal((nu, ny)) for _ in range(system.m)], name="k")
    back = controller_from_blocks(system, controller_blocks(ctrl), "k").check(system)
    for a, b in zip((ctrl.Ac, ctrl.Bc, ctrl.Cc, ctrl.Dc), (back.Ac, back.Bc, back.Cc, back.Dc)):
        assert all(x.shape == y.shape and np.array_equal(x, y) for x, y in zip(a, b))
    scaled, _ = bounded_blocks(controller_blocks(ctrl), 0.5)  # the --k-max projection keeps it too
    assert controller_from_blocks(system, scaled, "k").check(system).Dc[0].shape == (nu, ny)
