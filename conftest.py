"""Hypothesis settings profiles, registered at the root so ``--hypothesis-profile`` works.

* ``ci``: deterministic (derandomized, no example database), few examples per
  property, no deadline -- the whole ``properties/`` run stays within minutes on 2 cores.
* ``thorough``: randomized, many more examples, for local runs.
"""

from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci",
    derandomize=True,
    database=None,
    deadline=None,
    max_examples=10,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much, HealthCheck.data_too_large],
)
settings.register_profile(
    "thorough",
    deadline=None,
    max_examples=200,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)
settings.load_profile("ci")
