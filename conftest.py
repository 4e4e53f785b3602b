"""Test-session set-up: BLAS threads and the hypothesis settings profiles.

The profiles are defined once, in :mod:`ftc_verify.testing.profiles`, and registered
here, at the root, so that ``--hypothesis-profile`` works for ``tests/`` and
``properties/`` alike (profiles are process-global in hypothesis):

* ``ci`` (default): derandomized (fixed examples, reproducible), no example database, no
  deadline (an LMI solve takes ~0.1-0.4 s), 15 examples per property unless a property
  sets fewer for cost; the whole suite stays within minutes on two cores.
* ``thorough``: 200 randomized examples per property (tens of minutes); use it to hunt.

Choose with ``--hypothesis-profile thorough`` or ``FTC_HYPOTHESIS_PROFILE=thorough``.

Scheduling (``pytest -n 2``): tests marked ``slow(seconds)`` run first, longest first, and
pytest-xdist hands each worker one test at a time (``--maxschedchunk 1``), so the two
workers share the long tests instead of one of them finishing a tail of them alone.
"""

import os

# Single-threaded BLAS unless the caller chose otherwise: on 2 busy cores (pytest -n 2)
# a threaded OpenBLAS made a 5x5 expm take 15-20 ms instead of 8 us (measured here).
# Set before numpy is first imported (ftc_verify.testing imports it).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from ftc_verify.testing.profiles import load_profile  # noqa: E402

load_profile()  # "ci" unless $FTC_HYPOTHESIS_PROFILE names another


def pytest_configure(config) -> None:
    config.addinivalue_line("markers", "slow(seconds): a long test (seconds measured on 2 busy cores); runs first")
    if getattr(config.option, "maxschedchunk", "no xdist") is None:  # xdist's default: chunks of ~1/4 per worker
        config.option.maxschedchunk = 1


def pytest_collection_modifyitems(config, items) -> None:
    """Longest first (the ``slow`` marks), the rest in collection order (a stable sort)."""

    def seconds(item) -> float:
        mark = item.get_closest_marker("slow")
        return float(mark.args[0]) if mark is not None else 0.0

    items.sort(key=seconds, reverse=True)
