"""Test-session set-up: BLAS threads and the hypothesis settings profiles.

The profiles are defined once, in :mod:`ftc_verify.testing.profiles`, and registered
here, at the root, so that ``--hypothesis-profile`` works for ``tests/`` and
``properties/`` alike (profiles are process-global in hypothesis):

* ``ci`` (default): derandomized (fixed examples, reproducible), no example database, no
  deadline (an LMI solve takes ~0.1-0.4 s), 15 examples per property unless a property
  sets fewer for cost; the whole suite stays within minutes on two cores.
* ``thorough``: 200 randomized examples per property (tens of minutes); use it to hunt.

Choose with ``--hypothesis-profile thorough`` or ``FTC_HYPOTHESIS_PROFILE=thorough``.

Scheduling (``pytest -n 2``): tests marked ``slow(seconds)`` run first, longest first.
pytest-xdist runs with ``--dist loadgroup`` (set here when ``-n`` alone chose ``load``,
without its reordering by group size): the tests of one ``xdist_group`` go to one worker,
so a module-scoped fixture they share (one CLI run, one synthesis) is computed once; a
group is ordered by the sum of its members' seconds. Every other test is its own unit,
handed out one at a time, so the two workers share the long tests instead of one of
them finishing a tail of them alone.
"""

import os

import pytest

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
    if getattr(config.option, "dist", None) == "load":  # -n without --dist: group the xdist_group tests
        config.option.dist = "loadgroup"
        config.option.loadscopereorder = False  # keep the order below (longest first)
    if hasattr(config, "workerinput") and config.workerinput.get("ftc_loadgroup"):
        config.option.loadgroup = True  # the worker names each grouped test's group in its id


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node) -> None:
    """xdist hook, controller side: tell the workers the controller chose ``loadgroup``."""
    node.workerinput["ftc_loadgroup"] = node.config.option.dist == "loadgroup"


def _seconds(item) -> float:
    mark = item.get_closest_marker("slow")
    return float(mark.args[0]) if mark is not None else 0.0


def _group(item) -> str | None:
    mark = item.get_closest_marker("xdist_group")
    return None if mark is None else str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))


def pytest_collection_modifyitems(config, items) -> None:
    """Longest first (the ``slow`` marks; an ``xdist_group`` by its members' sum, its
    members together, longest first), the rest in collection order (a stable sort)."""
    total: dict[str, float] = {}
    for item in items:
        name = _group(item)
        if name is not None:
            total[name] = total.get(name, 0.0) + _seconds(item)

    def key(item) -> tuple[float, str, float]:
        name = _group(item)
        return (total[name], name, _seconds(item)) if name is not None else (_seconds(item), "", 0.0)

    items.sort(key=key, reverse=True)
