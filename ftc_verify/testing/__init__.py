"""Stage 9: hypothesis strategies and settings profiles to property-test your own designs.

Requires ``hypothesis`` (the ``test`` extra: ``pip install "ftc-verify[test]"``).
Importing this package only defines functions; nothing is drawn, registered or solved,
and the submodules are imported on first use of one of their names.

Example: every drawn two-mode plant with stable open-loop modes gets a mean-square
stable loop from ``my_design``::

    from hypothesis import given
    from ftc_verify.analysis import closed_loop, mean_square_stability
    from ftc_verify.testing import profile, systems

    @profile("ci")
    @given(systems(n=2, m=2, stability_margin=0.1))
    def test_my_design(system):
        assert mean_square_stability(closed_loop(system, my_design(system))).stable
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names below are loaded on first use (see __getattr__)
    from .loops import MODE_KEYS, DrawnLoop, closed_loops, stable_loops, unstable_loops
    from .illconditioned import PeerLoop, identical_mode_loop, peer_loops
    from .profiles import PROFILE_ENV, PROFILES, load_profile, profile, register_profiles
    from .strategies import (
        GAIN_BOUND,
        chains,
        controllers,
        disturbances,
        lqr_gains,
        matrices,
        observer_gains,
        similarity_transforms,
        state_feedback,
        systems,
    )

#: Public name -> submodule defining it.
_SOURCES = {
    **dict.fromkeys(("systems", "chains", "controllers", "state_feedback", "disturbances", "matrices",
                     "similarity_transforms", "lqr_gains", "observer_gains", "GAIN_BOUND"), "strategies"),
    **dict.fromkeys(("DrawnLoop", "MODE_KEYS", "closed_loops", "stable_loops", "unstable_loops"), "loops"),
    **dict.fromkeys(("PROFILES", "PROFILE_ENV", "register_profiles", "profile", "load_profile"), "profiles"),
    **dict.fromkeys(("PeerLoop", "identical_mode_loop", "peer_loops"), "illconditioned"),
}

__all__ = [
    "systems",
    "chains",
    "controllers",
    "state_feedback",
    "disturbances",
    "matrices",
    "similarity_transforms",
    "lqr_gains",
    "observer_gains",
    "GAIN_BOUND",
    "DrawnLoop",
    "MODE_KEYS",
    "closed_loops",
    "stable_loops",
    "unstable_loops",
    "PROFILES",
    "PROFILE_ENV",
    "register_profiles",
    "profile",
    "load_profile",
    "PeerLoop",
    "identical_mode_loop",
    "peer_loops",
]


def __getattr__(name: str) -> Any:
    """Import the submodule defining ``name`` on first use (PEP 562), so that a
    ``conftest.py`` importing the profiles does not import the analysis stack."""
    if name not in _SOURCES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_SOURCES[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
