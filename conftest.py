"""Test-session set-up: BLAS threads and the hypothesis settings profiles.

Profiles are registered here, at the root, so that ``--hypothesis-profile`` works for
``tests/`` and ``properties/`` alike (profiles are process-global in hypothesis):

* ``ci`` (default): derandomized (fixed examples, reproducible), no example database, no
  deadline (an LMI solve takes ~0.1-0.4 s), 15 examples per property unless a property
  sets fewer for cost; the whole suite stays within minutes on two cores.
* ``thorough``: 200 randomized examples per property (tens of minutes); use it to hunt.

Choose with ``--hypothesis-profile thorough`` or ``FTC_HYPOTHESIS_PROFILE=thorough``.
"""

import os

# Single-threaded BLAS unless the caller chose otherwise: on 2 busy cores (pytest -n 2)
# a threaded OpenBLAS made a 5x5 expm take 15-20 ms instead of 8 us (measured here).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from hypothesis import HealthCheck, settings  # noqa: E402

_SUPPRESS = (HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much)

settings.register_profile(
    "ci", derandomize=True, database=None, deadline=None, max_examples=15, print_blob=True,
    suppress_health_check=_SUPPRESS,
)
settings.register_profile(
    "thorough", derandomize=False, database=None, deadline=None, max_examples=200, print_blob=True,
    suppress_health_check=_SUPPRESS,
)
settings.load_profile(os.environ.get("FTC_HYPOTHESIS_PROFILE", "ci"))
