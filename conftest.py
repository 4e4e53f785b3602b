"""Test-session set-up: BLAS threads, and the hypothesis settings profiles (registered at
the root so ``--hypothesis-profile`` works).

* ``ci``: deterministic (derandomized, no example database), few examples per
  property, no deadline -- the whole ``properties/`` run stays within minutes on 2 cores.
* ``thorough``: randomized, many more examples, for local runs.
"""

import os

# Single-threaded BLAS unless the caller chose otherwise: on 2 busy cores (pytest -n 2)
# a threaded OpenBLAS made a 5x5 expm take 15-20 ms instead of 8 us (measured here).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from hypothesis import HealthCheck, settings  # noqa: E402

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
