"""Dask clusters for Monte Carlo: a ``LocalCluster`` on this machine or an existing scheduler.

:func:`open_client` is the one place that imports ``dask.distributed`` (an optional
dependency: ``pip install 'ftc-verify[dask]'``), so that nothing else pays its import time;
a client's work then goes through :mod:`ftc_verify.simulation.streaming` (reference
backend) or :mod:`ftc_verify.simulation.fmu_workers` (FMU backend).

The contract:

* :func:`check_cluster_options` refuses, before any work, a worker count above
  :func:`max_workers` (cores and memory) and a scheduler address that is not
  ``[PROTOCOL://]HOST:PORT``; it needs no Dask.
* Connecting to ``--scheduler`` is time-boxed (``connect_timeout`` seconds of
  :func:`open_client`, :data:`~ftc_verify.limits.CONNECT_TIMEOUT` by default; connection and handshake
  together): a closed port, a silent server or a server that is not a Dask scheduler (an
  HTTP server) is one :class:`~ftc_verify.errors.ValidationError`.
* A local cluster lives in one run folder (``ftc-verify-cluster-*`` in the temporary
  folder): the scheduler's and workers' ``local_directory`` and the workers' ``TMPDIR``,
  so everything a worker writes (its FMU copies, the FMUs extracted by ``tempfile``) is
  inside it. The folder is removed when the client closes, however it closes (an
  exception, SIGTERM/SIGINT as a ``BaseException``, a worker that was SIGKILLed).
* Interrupting the start or the run of a local cluster shuts it down quietly (no Dask log
  lines, bounded by :data:`CLOSE_TIMEOUT`) and lets the interrupting exception propagate
  unchanged. Worker processes ignore SIGINT (:func:`dask_setup`, their preload): a Ctrl-C
  in a terminal reaches the whole process group, and the client tears them down anyway.
* Local workers are forked from this process's fork server (:func:`start_fork_server`,
  preloaded with :data:`WORKER_PRELOAD`) where it can be used, else spawned (Dask's
  default); either way a worker gets the variables of this process's ``os.environ`` as they
  are when its cluster starts (a forked worker: those the server had at start-up and were
  unset since stay set; the interpreter's start-up ones, such as ``PYTHONHASHSEED``, are the
  server's), and its run folder as ``TMPDIR``. A process killed by SIGKILL leaves the
  server's ``pymp-*`` folder in the temporary folder.
"""

from __future__ import annotations

import asyncio
import importlib.util
import logging
import multiprocessing
import os
import re
import shutil
import signal
import socket
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from ..errors import ValidationError
from ..interrupts import deferred_signals
from ..limits import CONNECT_TIMEOUT, format_bytes, memory_limit

__all__ = ["open_client", "ClusterStart", "start_fork_server", "check_cluster_options", "max_workers", "dask_setup", "CONNECT_TIMEOUT",
           "CLOSE_TIMEOUT", "WORKERS_PER_CORE", "WORKER_MEMORY", "ALLOWED_FAILURES", "WORKER_PRELOAD"]

_INSTALL = "pip install 'ftc-verify[dask]'"
#: Seconds each of the client and the local cluster may take to close.
CLOSE_TIMEOUT = 10.0
#: Seconds an interrupted local cluster start may still take, so that it can be shut down.
START_TIMEOUT = 60.0
#: Local workers per core at most: a worker is one process with one thread running CPU-bound
#: batches, so more workers than cores buy no speed (:doc:`/performance`: 1.36x with 2
#: workers, 1.40x with 4 on 2 cores); a little oversubscription is harmless, thousands of processes are not.
WORKERS_PER_CORE = 4
#: Memory budgeted per local worker process: a Dask worker measured 114 MB resident idle and
#: 140 MB after 100 FMU paths of the paper plant (psutil RSS); the rest is headroom for
#: larger plants and the results in flight.
WORKER_MEMORY = 256 * 1024 ** 2
#: Deaths of the worker running a task before the local scheduler gives the task up
#: (``KilledWorker``): a lost worker is retried twice, a crashing plant FMU is found fast.
ALLOWED_FAILURES = 2
#: Modules imported once by the fork server that local worker processes are forked from (where
#: the platform has one: :func:`start_fork_server`), so that each worker starts with them loaded
#: instead of importing them itself: Dask and numpy, the reference and FMU batch code (which
#: pulls in the simulation and analysis packages) and FMPy's FMI 2 module (skipped if absent).
WORKER_PRELOAD = ("distributed", "numpy", "ftc_verify.simulation.cluster", "ftc_verify.simulation.streaming",
                  "ftc_verify.simulation.fmu_workers", "fmpy.fmi2")
_START_METHOD = "distributed.worker.multiprocessing-method"
_PROTOCOLS = ("tcp", "tls", "ws", "wss", "ucx")
_ADDRESS = re.compile(r"^(?:(?P<protocol>[A-Za-z][A-Za-z0-9+.-]*)://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[^\s:/\[\]]+)"
                      r":(?P<port>[0-9]{1,5})/?$")
_QUIET = ("distributed", "tornado", "asyncio")
_WORKER_PROCESS = "Dask Worker process"  # the name the Nanny gives its worker processes


def _cores() -> int:
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return max(os.cpu_count() or 1, 1)


def max_workers() -> int:
    """The most local workers this machine takes: ``min(cores x WORKERS_PER_CORE,
    memory limit / WORKER_MEMORY)``, at least 1 (cores: the CPUs this process may use;
    memory limit: :func:`ftc_verify.limits.memory_limit`)."""
    return max(1, min(_cores() * WORKERS_PER_CORE, memory_limit() // WORKER_MEMORY))


def check_cluster_options(workers: int | None, scheduler: str | None) -> None:
    """Refuse ``--workers`` / ``--scheduler`` values before any work (no Dask needed).

    Parameters
    ----------
    workers : int or None
        ``--workers``: at least 1 and at most :func:`max_workers`.
    scheduler : str or None
        ``--scheduler``: ``[PROTOCOL://]HOST:PORT`` with a Dask protocol (``tcp`` by default).

    Raises
    ------
    ValidationError
        Naming the option, the value and what is allowed.
    """
    if workers is not None and scheduler is not None:
        raise ValidationError(f"--workers {workers} --scheduler {scheduler}: give one of them, not both")
    if workers is not None:
        if workers < 1:
            raise ValidationError(f"--workers {workers}: must be at least 1")
        bound = max_workers()
        if workers > bound:
            raise ValidationError(
                f"--workers {workers}: above the bound of {bound} for this machine ({_cores()} cores x "
                f"{WORKERS_PER_CORE}, or {format_bytes(memory_limit())} of memory limit / "
                f"{format_bytes(WORKER_MEMORY)} per worker, whichever is smaller); give at most {bound}")
    if scheduler is not None:
        found = _ADDRESS.match(scheduler.strip())
        if found is None:
            raise ValidationError(f"--scheduler {scheduler!r}: not a scheduler address; give tcp://HOST:PORT "
                                  "(e.g. tcp://10.0.0.5:8786)")
        protocol = (found["protocol"] or "tcp").lower()
        if protocol not in _PROTOCOLS:
            raise ValidationError(f"--scheduler {scheduler!r}: unknown protocol {protocol!r}; use one of "
                                  f"{', '.join(_PROTOCOLS)} (e.g. tcp://10.0.0.5:8786)")
        if not 1 <= int(found["port"]) <= 65535:
            raise ValidationError(f"--scheduler {scheduler!r}: port {found['port']} is not in 1..65535")


def dask_setup(server: Any) -> None:
    """Preload hook of the local cluster (Dask calls it as each server starts). Its
    in-process scheduler: no gc-timing callback (``distributed.gc``: CPython ignores an
    exception raised in a gc callback, so a Ctrl-C landing there was lost), removed before
    any worker is started. A
    worker: the worker process ignores SIGINT, which a terminal's Ctrl-C sends to the whole
    process group; the client shuts the workers down itself."""
    if type(server).__name__ == "Scheduler":
        _no_gc_diagnosis()
    elif threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _fork_server_used() -> bool:
    """Local workers may be forked from a fork server: the platform has one and Dask's
    ``distributed.worker.multiprocessing-method`` is its default, ``spawn``."""
    import dask
    import distributed  # noqa: F401  (registers the ``distributed.*`` settings' defaults)

    return dask.config.get(_START_METHOD) == "spawn" and "forkserver" in multiprocessing.get_all_start_methods()


def _pre_spawn_environment() -> None:
    """Set in this process's environment what Dask's nanny sets in it before it starts
    each worker process (``distributed.nanny.pre-spawn-environ``: one BLAS thread, glibc's
    trim threshold; ``PYTHONHASHSEED`` 6640 unless configured), a variable already set kept
    as the nanny keeps it: the fork server, started before any nanny, inherits them."""
    import dask

    wanted = {k: os.environ.get(k, str(v)) for k, v in dask.config.get("distributed.nanny.pre-spawn-environ").items()
              if v is not None}
    if wanted.get("PYTHONHASHSEED") in (None, "0"):
        wanted["PYTHONHASHSEED"] = "6640"
    os.environ.update(wanted)


def start_fork_server() -> bool:
    """Start this process's fork server for local Dask workers now (it is otherwise started
    by the first local cluster's first worker), preloaded with :data:`WORKER_PRELOAD`.

    A spawned worker is a fresh interpreter importing Dask, numpy and this package (about
    1 s of CPU each on 2 cores); one forked from the server starts with them loaded. The
    server serves every later local cluster of this process and every worker a nanny
    restarts, and ends with the process. ``multiprocessing`` keeps its socket in a folder
    ``pymp-*`` of the temporary folder of the moment, removed when the process exits.

    Returns
    -------
    bool
        Whether local workers are forked from it. False (nothing started; the workers are
        started Dask's way) where the platform has no ``forkserver``, where Dask's
        ``distributed.worker.multiprocessing-method`` is not its default ``spawn`` (a user's
        choice is kept), and where the server is not running and its socket cannot be made
        (``OSError``): a temporary folder whose path leaves no room for the socket's name
        (a Unix socket's path has at most 107 bytes on Linux; Python 3.11 puts it at
        ``TMP/pymp-XXXXXXXX/listener-XXXXXXXX``), or one it cannot write.
    """
    if not _fork_server_used():
        return False
    import dask
    from multiprocessing import forkserver

    from distributed.utils import get_mp_context

    with dask.config.set({_START_METHOD: "forkserver"}):
        get_mp_context().set_forkserver_preload(list(WORKER_PRELOAD))  # read when the server starts
    _pre_spawn_environment()
    try:
        with _sigint_ignored_at_exec():
            forkserver.ensure_running()
    except OSError:  # its socket cannot be made there (a path too long, a folder not writable): spawn
        return False
    return True


@contextmanager
def _sigint_ignored_at_exec() -> Iterator[None]:
    """SIGINT ignored while the fork server is spawned: a new interpreter keeps an ignored
    disposition across ``exec`` (not a handler), so a Ctrl-C to the process group during its
    1-2 s of preload imports does not print the server's ``KeyboardInterrupt`` traceback
    (it ignores SIGINT itself only after them; the client ends it anyway). SIGTERM is held
    and delivered after (:func:`~ftc_verify.interrupts.deferred_signals`); a SIGINT within
    the few milliseconds of the spawn itself is ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with deferred_signals():
        held = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, held)


@contextmanager
def _forked_workers() -> Iterator[None]:
    """Within the block Dask's nannies start worker processes from :func:`start_fork_server`'s
    server (started here if need be) instead of spawning them; unchanged where it returns False."""
    import dask

    if not start_fork_server():
        yield
        return
    with dask.config.set({_START_METHOD: "forkserver"}):
        yield


@contextmanager
def _quiet_logs() -> Iterator[None]:
    """Disable the ``distributed``, ``tornado`` and ``asyncio`` loggers for the block."""
    names = {n for n in logging.root.manager.loggerDict if n.split(".")[0] in _QUIET} | set(_QUIET)
    saved = {n: logging.getLogger(n).disabled for n in names}
    for n in names:
        logging.getLogger(n).disabled = True
    try:
        yield
    finally:
        for n, disabled in saved.items():
            logging.getLogger(n).disabled = disabled


def _shutdown(client: Any, cluster: Any) -> None:
    """Close ``client`` and ``cluster`` (either may be None) quietly, each within
    :data:`CLOSE_TIMEOUT`; their errors are dropped, so that the exception that ended
    the run (if any) is the one that propagates."""
    with _quiet_logs():
        for part in (client, cluster):
            if part is None:
                continue
            try:
                part.close(timeout=CLOSE_TIMEOUT)
            except (Exception, asyncio.CancelledError):
                pass


def _reap_workers(seconds: float, earlier: set[Any]) -> None:
    """Wait up to ``seconds`` for the Dask worker processes this process started since
    ``earlier`` (its children then) to end, then kill the rest: a worker still starting
    when its cluster was shut down could otherwise write into the run folder after it
    was removed."""
    deadline = time.monotonic() + seconds
    for child in multiprocessing.active_children():
        if child not in earlier and child.name.startswith(_WORKER_PROCESS):
            child.join(max(deadline - time.monotonic(), 0.0))
            if child.is_alive():
                child.kill()
                child.join(1.0)


def _reachable(address: str, where: str, timeout: float) -> None:
    """Refuse a ``tcp`` address at once when nothing listens there (Dask's ``connect``
    retries a refused connection until its timeout), its host is unknown, or it does not
    accept a connection within ``timeout`` seconds."""
    found = _ADDRESS.match(address)
    if found is None or (found["protocol"] or "tcp").lower() != "tcp":
        return
    try:
        socket.create_connection((found["host"].strip("[]"), int(found["port"])), timeout=timeout).close()
    except ConnectionRefusedError:
        raise ValidationError(f"{where}: nothing listens at that address (connection refused); start the "
                              "scheduler first (dask scheduler) or give the address it printed") from None
    except socket.gaierror as exc:
        raise ValidationError(f"{where}: unknown host {found['host']!r} ({exc.strerror or exc})") from None
    except TimeoutError:
        raise ValidationError(f"{where}: no connection within {timeout:g} s") from None
    except OSError as exc:
        raise ValidationError(f"{where}: cannot connect ({exc.strerror or exc})") from None


def _connect(address: str, timeout: float) -> Any:
    """A client of the scheduler at ``address``, or a :class:`ValidationError` within
    ``timeout`` seconds (asks for the server's identity first: ``Client`` itself can
    wait forever on a server that accepts and never answers like a scheduler)."""
    from distributed import Client
    from distributed.comm import connect

    async def identity() -> Any:
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    where = f"--scheduler {address}"
    deadline = time.monotonic() + timeout
    _reachable(address, where, timeout)
    try:
        with _quiet_logs():
            reply = asyncio.run(asyncio.wait_for(identity(), max(deadline - time.monotonic(), 1.0)))
    except TimeoutError:
        raise ValidationError(f"{where}: no Dask scheduler answered within {timeout:g} s "
                              "(is it the address the scheduler printed?)") from None
    except OSError as exc:  # closed during the handshake, TLS trouble...
        raise ValidationError(f"{where}: cannot connect to a Dask scheduler ({type(exc).__name__}: "
                              f"{str(exc).strip()[:200] or 'no detail'})") from None
    except Exception as exc:  # an answer that is not Dask's protocol (it can even fail to allocate)
        raise ValidationError(f"{where}: the server there is not a Dask scheduler (its answer could not be read: "
                              f"{type(exc).__name__})") from None
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        raise ValidationError(f"{where}: the server there is not a Dask scheduler (it answered as {kind!r})")
    try:
        return Client(address, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ValidationError(f"{where}: cannot connect ({exc})") from None


def _no_gc_diagnosis() -> None:
    """Remove the garbage-collection callback that the in-process scheduler of a
    ``LocalCluster`` installs (``distributed.gc``, timing logs only). CPython ignores an
    exception raised inside a gc callback: a Ctrl-C that landed there was printed as
    "Exception ignored" and lost, and the command ran on to exit 0."""
    try:
        from distributed.gc import disable_gc_diagnosis
    except ImportError:  # pragma: no cover - an older distributed: its own module name
        return
    disable_gc_diagnosis(force=True)


class ClusterStart:
    """A ``LocalCluster`` of ``workers`` one-thread worker processes living in ``folder``,
    built in a helper thread from the constructor on (:func:`open_client` with
    ``wait=False``): the caller works meanwhile (the reference backend simulates its first
    batches here, :mod:`ftc_verify.simulation.streaming`), asks :meth:`ready`, and takes
    :meth:`client` when it needs the workers. An exception raised in the main thread while
    it waits (SIGTERM, Ctrl-C) propagates; :meth:`close` then waits up to
    ``START_TIMEOUT`` seconds for the half-built cluster and shuts it down quietly."""

    def __init__(self, workers: int, folder: Path) -> None:
        from distributed import LocalCluster

        self._box: dict[str, Any] = {}
        self._finished = threading.Event()  # not Thread.join: an interrupted join marks a live thread as stopped
        self._client: Any = None

        def start() -> None:
            try:
                self._box["cluster"] = LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                    silence_logs=logging.CRITICAL, local_directory=str(folder),
                    env=dict(os.environ) | {"TMPDIR": str(folder)},  # forked workers: this process's environment now
                    preload=[__name__],
                    scheduler_kwargs={"local_directory": str(folder), "allowed_failures": ALLOWED_FAILURES,
                                      "preload": [__name__]})
            except BaseException as exc:  # handed to the main thread
                self._box["error"] = exc
            finally:
                self._finished.set()

        threading.Thread(target=start, name="ftc-verify-cluster-start", daemon=True).start()

    def ready(self) -> bool:
        """The cluster's start has ended (:meth:`client` returns at once)."""
        return self._finished.is_set()

    def cluster(self) -> Any:
        """The started ``LocalCluster`` (waits for it; its start's exception raised here)."""
        while not self._finished.wait(0.1):
            pass
        if "error" in self._box:
            raise self._box["error"]
        return self._box["cluster"]

    def client(self) -> Any:
        """A ``dask.distributed.Client`` of the cluster (made once; waits for the start)."""
        if self._client is None:
            from distributed import Client

            self._client = Client(self.cluster())
        return self._client

    def close(self) -> None:
        """Shut the client and the cluster down quietly, the start waited for first."""
        if not self._finished.is_set():
            with _quiet_logs():
                self._finished.wait(START_TIMEOUT)
        _shutdown(self._client, self._box.get("cluster"))


@contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None, wait: bool = True,
                connect_timeout: float = CONNECT_TIMEOUT) -> Iterator[Any]:
    """A ``dask.distributed.Client``: ``workers`` local worker processes (one thread each),
    or the scheduler at ``scheduler`` (``tcp://host:port``); ``None`` when neither is
    given (module docstring for the contract). ``wait=False``: a local cluster is yielded
    as its :class:`ClusterStart`, still starting, so that the caller works meanwhile.
    ``connect_timeout``: the seconds that connecting to ``scheduler`` may take, handshake
    included (a positive finite number; :data:`~ftc_verify.limits.CONNECT_TIMEOUT` by default), after which
    the address is refused.

    The options are checked first (:func:`check_cluster_options`). The local cluster is
    shut down on exit and its run folder removed; a remote one is only disconnected.
    Whatever ends the block (``KeyboardInterrupt``, a SIGTERM exception) propagates as it is.
    """
    if not workers and not scheduler:
        yield None
        return
    check_cluster_options(workers, scheduler)
    if isinstance(connect_timeout, bool) or not (isinstance(connect_timeout, (int, float))
                                                and 0 < connect_timeout < float("inf")):
        raise ValidationError(f"connect_timeout: must be positive and finite (seconds), got {connect_timeout!r}")
    if importlib.util.find_spec("distributed") is None:
        raise ValidationError(f"--workers/--scheduler: dask.distributed is not installed ({_INSTALL})")
    if scheduler:
        client = _connect(scheduler.strip(), float(connect_timeout))
        try:
            yield client
        finally:
            _shutdown(client, None)
        return
    assert workers is not None
    earlier = set(multiprocessing.active_children())
    start: ClusterStart | None = None
    folder: Path | None = None
    with _forked_workers():
        try:
            # SIGTERM/SIGINT held until both exist: a signal inside ClusterStart (its thread
            # started, the object not yet returned) left a start nobody shut down, which
            # wrote into the removed run folder as the process exited
            with deferred_signals():
                folder = Path(tempfile.mkdtemp(prefix="ftc-verify-cluster-"))
                start = ClusterStart(int(workers), folder)
            yield start if not wait else start.client()
        finally:
            if start is not None:
                start.close()
            _reap_workers(CLOSE_TIMEOUT, earlier)
            if folder is not None:
                shutil.rmtree(folder, ignore_errors=True)
