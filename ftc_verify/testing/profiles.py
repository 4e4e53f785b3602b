"""Hypothesis settings profiles for property tests of FTC designs: ``ci`` and ``thorough``.

Nothing happens at import time: :func:`register_profiles` registers the profiles (it is
idempotent, and cheap), :func:`profile` returns one as a :class:`hypothesis.settings`
object usable as a decorator, and :func:`load_profile` makes one the session default.

* ``ci``: derandomized (the same examples on every run), no example database, no
  deadline (one LMI solve takes 0.1-0.4 s), 15 examples, the health checks ``too_slow``,
  ``data_too_large`` and ``filter_too_much`` suppressed (the strategies reject draws
  whose Riccati equations fail or whose loops miss a stability margin).
* ``thorough``: the same with 200 randomized examples; use it to hunt for counterexamples.

A property whose every example costs seconds (a synthesis per example) is capped in
``ci`` with :func:`capped` (and given its own, smaller count in ``thorough``).
"""

from __future__ import annotations

import os
from typing import Any

from hypothesis import HealthCheck, settings

__all__ = ["PROFILES", "PROFILE_ENV", "register_profiles", "profile", "load_profile", "capped"]

#: Name of each profile and the options that differ between them.
PROFILES: dict[str, dict[str, Any]] = {
    "ci": {"derandomize": True, "max_examples": 15},
    "thorough": {"derandomize": False, "max_examples": 200},
}

#: Environment variable read by :func:`load_profile` when no name is given.
PROFILE_ENV = "FTC_HYPOTHESIS_PROFILE"


def _common() -> dict[str, Any]:
    """Options shared by every profile."""
    return {
        "database": None,
        "deadline": None,
        "print_blob": True,
        "suppress_health_check": (HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much),
    }


def register_profiles() -> tuple[str, ...]:
    """Register the ``ci`` and ``thorough`` profiles with hypothesis.

    Registering again replaces them by identical profiles, so calling this from several
    ``conftest.py`` files is harmless.

    Returns
    -------
    tuple of str
        The registered profile names.

    Examples
    --------
    >>> from hypothesis import settings
    >>> register_profiles()
    ('ci', 'thorough')
    >>> settings.get_profile("ci").max_examples
    15
    """
    for name, options in PROFILES.items():
        settings.register_profile(name, **_common(), **options)
    return tuple(PROFILES)


def profile(name: str = "ci", *, max_examples: int | None = None, derandomize: bool | None = None) -> settings:
    """The settings of profile ``name`` (registered first), with the given options on top.

    Use it as a decorator of one test, without changing the session's default profile.
    For any other option, wrap the result: ``settings(profile("ci"), deadline=1000)``.

    Parameters
    ----------
    name : str
        ``"ci"``, ``"thorough"`` or a profile registered by the caller (hypothesis raises
        ``InvalidArgument`` for an unknown name).
    max_examples : int, optional
        Examples per property (default: the profile's).
    derandomize : bool, optional
        Draw the same examples on every run (default: the profile's).

    Returns
    -------
    hypothesis.settings

    Examples
    --------
    >>> from hypothesis import given, strategies as st
    >>> @profile("ci", max_examples=3)
    ... @given(st.integers())
    ... def test_int(x):
    ...     assert isinstance(x, int)
    >>> test_int()
    >>> profile("thorough").max_examples
    200
    """
    register_profiles()
    base = settings.get_profile(name)
    if max_examples is None and derandomize is None:
        return base
    return settings(base,
                    max_examples=base.max_examples if max_examples is None else max_examples,
                    derandomize=base.derandomize if derandomize is None else derandomize)


def load_profile(name: str | None = None) -> str:
    """Register the profiles and load ``name`` as hypothesis's default.

    Parameters
    ----------
    name : str, optional
        A profile name; default ``$FTC_HYPOTHESIS_PROFILE``, else ``"ci"``.

    Returns
    -------
    str
        The loaded profile's name.

    Examples
    --------
    In a ``conftest.py``::

        from ftc_verify.testing import load_profile
        load_profile()  # "ci" unless FTC_HYPOTHESIS_PROFILE says otherwise
    """
    chosen = name if name is not None else os.environ.get(PROFILE_ENV, "ci")
    register_profiles()
    settings.load_profile(chosen)
    return chosen


def capped(ci_examples: int, thorough_examples: int | None = None) -> settings:
    """The loaded profile's settings, with at most ``ci_examples`` examples when it is
    derandomized (``ci``), and ``thorough_examples`` (default: its own count) when it is
    randomized (``thorough``).

    For properties dominated by a few expensive examples (a synthesis each, seconds to
    tens of seconds): the ``ci`` run checks the property on that many fixed examples, the
    hunt with ``thorough`` on many more. Read when the decorator is applied (test modules
    are imported after ``--hypothesis-profile`` is loaded).

    Parameters
    ----------
    ci_examples : int
        Examples per property under a derandomized profile (at least 1).
    thorough_examples : int, optional
        Examples per property under a randomized profile (at least 1).

    Returns
    -------
    hypothesis.settings

    Raises
    ------
    ValueError
        For a count below 1.

    Examples
    --------
    >>> from hypothesis import settings
    >>> loaded = settings.default
    >>> capped(2, 20).max_examples == (min(2, loaded.max_examples) if loaded.derandomize else 20)
    True
    """
    for name, count in (("ci_examples", ci_examples), ("thorough_examples", thorough_examples)):
        if count is not None and count < 1:
            raise ValueError(f"{name}: must be at least 1, got {count!r}")
    base = settings.default
    if base is None:  # pragma: no cover - hypothesis always has a default profile
        base = settings()
    if not base.derandomize:
        return settings(base, max_examples=base.max_examples if thorough_examples is None else thorough_examples)
    return settings(base, max_examples=min(ci_examples, base.max_examples))
