"""Resource limits: refuse a problem, with the estimate and the limit, before allocating it.

The limit is ``FTC_VERIFY_MEMORY_LIMIT`` (bytes; suffixes ``K``, ``M``, ``G`` allowed)
when set, else 80 % of the memory the kernel reports available (``MemAvailable`` in
``/proc/meminfo``; 80 % of physical memory where that file is missing). Estimates come
from measurements quoted where they are made (LMI stage: ``ftc_verify.analysis.lmi_analysis``;
simulation records: ``ftc_verify.cli``).
"""

from __future__ import annotations

import os
import time

from .errors import MemoryLimitError, ValidationError

__all__ = ["memory_limit", "check_memory", "format_bytes", "dense_generator_estimate", "GENERATOR_COPIES",
           "CONNECT_TIMEOUT", "GAMMA_MAX", "cpu_clock"]

#: Seconds for connecting to a Dask ``--scheduler``, handshake included (the default of
#: :func:`~ftc_verify.simulation.cluster.open_client`'s ``connect_timeout`` and of the
#: commands' ``--connect-timeout``; here, not in the cluster module, so that building the
#: command line's help imports neither asyncio nor Dask).
CONNECT_TIMEOUT = 10.0

#: The largest attenuation level ``gamma`` accepted (``--gamma``, the synthesis APIs'
#: ``gamma``): the code forms ``gamma**2`` (Monte Carlo's comparison with ``gamma**2``,
#: the LMIs' ``g`` below a level of 1), which overflows float64 above ~1.3e154 (exit 4
#: at 1e155 before this limit); 1e150 leaves room for the products with it.
GAMMA_MAX = 1e150

_SUFFIX = {"K": 1024, "M": 1024 ** 2, "G": 1024 ** 3, "T": 1024 ** 4}


def cpu_clock() -> float:
    """CPU seconds (user + system) of this process and of its children that ended and were
    waited for (the forked analysis stages): the clock of the synthesis budgets and of the
    box verdict's (:mod:`ftc_verify.analysis.box`), so that a design or a verdict depends
    much less on what else the machine runs (a wall-clock budget gave the
    descent's ``hinf`` route a third of its iterations at load 14). It counts every thread
    of the process: with a multi-threaded BLAS a budget is spent sooner (the CLI sets one
    thread). The process's own seconds come from :func:`time.process_time` (nanoseconds;
    ``os.times`` ticks every 10 ms here, so a budget of 0 was not spent at once)."""
    t = os.times()
    return time.process_time() + t.children_user + t.children_system


def format_bytes(value: float) -> str:
    """``1.5 GB`` style (powers of 1024)."""
    for unit, size in (("TB", 1024 ** 4), ("GB", 1024 ** 3), ("MB", 1024 ** 2), ("kB", 1024)):
        if value >= size:
            return f"{value / size:.3g} {unit}"
    return f"{value:.0f} B"


#: Peak memory of one dense eigen-decomposition (left and right vectors) of the
#: second-moment generator, in float64 copies of it (``rows^2`` entries), and of the
#: duplication matrices, in copies of ``n^2 x h``: ``(8, 4)``. Measured with
#: ``ftc_verify.synthesis.descent.abscissa_gradient`` (peak RSS): n = 20 and 4 joint
#: states (840 rows) +38 MB, the model says 41 MB; n = 30, 2 states (930 rows) +50 MB,
#: model 58 MB; n = 60, 1 state (1830 rows) +362 MB, model 425 MB.
GENERATOR_COPIES = (8, 4)


def dense_generator_estimate(n: int, joint_states: int) -> float:
    r"""Bytes of a dense eigen-decomposition of the second-moment generator of a loop of
    order ``n`` on ``joint_states`` joint states: with :math:`h = n(n+1)/2` and
    :math:`r = N h` rows, :math:`8\,(c_1 r^2 + c_2 n^2 h)` for the copies
    :data:`GENERATOR_COPIES` (Python integers: no overflow for any order)."""
    h = n * (n + 1) // 2
    rows = joint_states * h
    return float(8 * (GENERATOR_COPIES[0] * rows * rows + GENERATOR_COPIES[1] * n * n * h))


def _available() -> int:
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def memory_limit() -> int:
    """The memory a single problem may take (module docstring)."""
    text = os.environ.get("FTC_VERIFY_MEMORY_LIMIT", "").strip()
    if not text:
        return int(0.8 * _available())
    factor = _SUFFIX.get(text[-1].upper(), 1)
    digits = text[:-1] if factor != 1 else text
    try:
        value = float(digits) * factor
    except ValueError:
        raise ValidationError(f"FTC_VERIFY_MEMORY_LIMIT: not a size: {text!r} (e.g. 8G)") from None
    if not value > 0:
        raise ValidationError(f"FTC_VERIFY_MEMORY_LIMIT: must be positive, got {text!r}")
    return int(value)


def check_memory(estimate: float, what: str, *, hint: str = "reduce the problem") -> None:
    """Raise :class:`MemoryLimitError` naming ``what``, the estimate, the limit and ``hint``
    when ``estimate`` bytes exceed :func:`memory_limit`."""
    limit = memory_limit()
    if estimate > limit:
        source = "FTC_VERIFY_MEMORY_LIMIT" if os.environ.get("FTC_VERIFY_MEMORY_LIMIT", "").strip() \
            else "80 % of available memory; set FTC_VERIFY_MEMORY_LIMIT to change it"
        raise MemoryLimitError(
            f"{what}: about {format_bytes(estimate)} of memory needed, above the limit of "
            f"{format_bytes(limit)} ({source}); {hint}"
        )
