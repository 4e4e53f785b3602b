"""Hypothesis settings profiles for the property suite.

* ``ci`` (default): derandomized (fixed examples, reproducible), no example database,
  no deadline (an LMI solve takes ~0.1-0.4 s), 12 examples per property; the whole
  ``properties/`` run takes about a minute on two cores.
* ``thorough``: 200 randomized examples per property (tens of minutes); use it to hunt.

Choose with ``pytest properties --hypothesis-profile thorough`` (hypothesis's pytest
plugin loads it after this file is imported) or ``FTC_HYPOTHESIS_PROFILE=thorough``.
Without either, ``ci`` is loaded, with or without the ``CI`` environment variable.

Note: hypothesis profiles are process-global, so when ``tests/`` and ``properties/`` run
in one pytest process the loaded profile applies to hypothesis tests in both.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

_SUPPRESS = (HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much)

settings.register_profile(
    "ci",
    derandomize=True,
    database=None,
    deadline=None,
    max_examples=12,
    print_blob=True,
    suppress_health_check=_SUPPRESS,
)
settings.register_profile(
    "thorough",
    derandomize=False,
    database=None,
    deadline=None,
    max_examples=200,
    print_blob=True,
    suppress_health_check=_SUPPRESS,
)
settings.load_profile(os.environ.get("FTC_HYPOTHESIS_PROFILE", "ci"))
