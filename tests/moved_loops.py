"""The paper loop in other units (time, states, inputs), for the tests of the sampled
stages in physical units (``test_sampled_units_h31r.py``, ``test_sampled_conditioned_h31k.py``):
the same joint chain with its rates scaled, so the moved loop's periods are the paper
loop's times ``s`` and its one-period spectrum is the paper loop's."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftc_verify.controllers.controller import Controller
from ftc_verify.model.system import FTCSystem

__all__ = ["Units", "moved"]


@dataclass(frozen=True)
class Units:
    """Time ``t -> s t``, states ``x' = S x``, inputs ``u = a u'``."""

    name: str
    s: float = 1.0
    S: np.ndarray | None = None
    a: float = 1.0


def moved(system: FTCSystem, controller: Controller, u: Units) -> tuple[FTCSystem, Controller]:
    """The nominal loop of ``system`` under the state feedback ``controller`` in the units
    of ``u`` (same joint chain, rates times ``s``)."""
    S = np.eye(system.dims[0]) if u.S is None else u.S
    Si = np.linalg.inv(S)
    modes = [{"A": u.s * S @ md.A @ Si, "B": u.s * S @ md.B * u.a, "C": md.C @ Si, "D": u.s * S @ md.D}
             for md in system.modes]
    ch = system.chain
    out = FTCSystem.from_arrays(name=u.name, modes=modes, alpha=u.s * ch.alpha, beta_min=u.s * ch.beta_min,
                                beta_max=u.s * ch.beta_max)
    return out, Controller.state_feedback([K @ Si / u.a for K in controller.Dc])
