"""Dask clusters for Monte Carlo: a ``LocalCluster`` on this machine or an existing scheduler.

:func:`open_client` is the one place that imports ``dask.distributed`` (an optional
dependency: ``pip install 'ftc-verify[dask]'``), so that nothing else pays its import time;
a client's work then goes through :mod:`ftc_verify.simulation.streaming` (reference
backend) or :mod:`ftc_verify.simulation.fmu_workers` (FMU backend).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from ..errors import ValidationError

__all__ = ["open_client"]

_INSTALL = "pip install 'ftc-verify[dask]'"


@contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A ``dask.distributed.Client``: ``workers`` local worker processes (one thread each),
    or the scheduler at ``scheduler`` (``tcp://host:port``); ``None`` when neither is
    given. The local cluster is shut down on exit; a remote one is only disconnected."""
    if not workers and not scheduler:
        yield None
        return
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise ValidationError(f"--workers/--scheduler: dask.distributed is not installed ({_INSTALL})") from None
    if scheduler:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise ValidationError(f"--scheduler {scheduler!r}: cannot connect ({exc})") from None
        try:
            yield client
        finally:
            client.close()
        return
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client
