"""A child process started before the work it overlaps: its imports now, its job later.

Importing python-control (scipy.signal, matplotlib.pyplot) costs about a second, more than
the whole analysis of a small loop, and its per-mode cross-check
(:func:`~ftc_verify.analysis.crossval.cross_validate`) needs nothing but the closed loop.
So ``analyze`` and ``verify`` start :func:`cross_check` first, right after importing their
numerical modules (a forked child shares them: it imports only python-control, and on a
busy machine no import is paid twice) and before any stage: a :class:`Prestarted` child
(a ``fork``, POSIX) that imports python-control at once and then waits. The command hands it the job as soon as the loop exists
(:meth:`Prestarted.submit`: a module-level function, pickled by name, and its argument)
and collects the answer only at the very end (:meth:`Prestarted.result`); nothing in
between waits for it. The answer is the function's on the same pickled argument, so the
numbers are those of a call in this process.

The cross-check child imports python-control without the docstrings that scipy and
matplotlib generate at import time (:func:`skip_docstring_generation`: about 0.3 s of its
1 s of CPU; the child computes, nobody reads a docstring there). Running it as a fresh
``python -OO`` instead does not help: scipy then reads source files to find the comments
that stand in for the missing docstrings (``pydoc.getdoc``), and with
``PYTHONDONTWRITEBYTECODE`` set no ``.opt-2.pyc`` is ever cached (measured, issue 37).

It also imports python-control without the packages it imports but the cross-check
never uses (:func:`defer_modules`, :data:`CROSS_CHECK_DEFERRED`): ``scipy.signal``,
``scipy.interpolate`` and ``scipy.integrate`` (python-control takes a few functions and
classes from them at import time and calls them only for conversions, discretisation,
frequency data and phase plots), ``scipy.stats`` (``scipy.signal`` takes
``scoreatpercentile`` from it), matplotlib and ``pyplot`` (python-control's plotting
modules bind them at import and use them only when plotting) and ``control.grid`` (the
s- and z-plane grids, whose import subclasses an ``mpl_toolkits`` class): in that child
they are stand-ins that import the real package the first time anything of it is used,
so a python-control that does use them still gets them. ``scipy.optimize`` is imported
(python-control subclasses its ``OptimizeResult`` at import). The child's import 0.67 ->
0.13 s of CPU (measured, python-control 0.10.2, scipy 1.17.1, matplotlib's docstrings
switched off in both); the checks' numbers are the same (tested: the same
python-control functions on the same matrices).

This module imports nothing but the standard library (and nothing of ``ftc_verify``), so
a caller can fork wherever it likes. Where ``fork`` is missing,
or when the child ends without an answer (killed, or dead in native code), the job runs in
this process when :meth:`~Prestarted.result` is called: a third-party failure never
decides the command's fate. An exception the job raises in the child is raised again
here. The child ignores SIGINT (a terminal's Ctrl-C goes to the whole group; the parent
ends the child), dies with its parent on Linux, and :meth:`~Prestarted.cancel` (call it
in a ``finally``) kills it if it is still running.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.abc
import importlib.machinery
import os
import pickle
import struct
import sys
import threading
import time
import types
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from .interrupts import die_with_parent

__all__ = ["Prestarted", "cross_check", "skip_docstring_generation", "defer_modules", "DeferredModule",
           "CROSS_CHECK_MODULES", "CROSS_CHECK_DEFERRED", "defer_numpy_tools", "NUMPY_TOOLS"]

#: Held while a :class:`DeferredModule` imports its real package.
_LOAD_LOCK = threading.RLock()

#: What the cross-check child imports first (python-control, then the check itself).
CROSS_CHECK_MODULES = ("control", "ftc_verify.analysis.crossval")
#: What the cross-check child imports only when used (:func:`defer_modules`): module, and the
#: names taken from it by ``from ... import`` while python-control is imported.
CROSS_CHECK_DEFERRED: dict[str, tuple[str, ...]] = {
    "scipy.signal": ("StateSpace", "TransferFunction", "cont2discrete", "tf2zpk", "zpk2tf"),
    "scipy.interpolate": ("splev", "splprep"),
    "scipy.integrate": ("odeint",),
    "scipy.stats": ("scoreatpercentile",),
    "matplotlib": (),
    "matplotlib.pyplot": (),
    "matplotlib.transforms": (),
    "control.grid": ("nogrid", "sgrid", "zgrid"),
}
_SIZE = struct.Struct("<Q")
_PIPE_BYTES = 60_000  # below Linux's 64 KiB pipe buffer: written at once, whatever the child is doing


def _read_exact(fd: int, size: int) -> bytes | None:
    """``size`` bytes from ``fd``, or ``None`` at end of file before that."""
    chunks, left = [], size
    while left:
        chunk = os.read(fd, min(left, 1 << 20))
        if not chunk:
            return None
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def _no_parse(self: Any) -> None:
    """Stands in for scipy's ``NumpyDocString._parse`` (:func:`skip_docstring_generation`)."""


class _BlankDoc:
    """Stands in for scipy's ``FunctionDoc`` in ``xp_capabilities`` (:func:`skip_docstring_generation`):
    empty sections, rendered as an empty docstring."""

    def __init__(self, func: Any, *args: Any, **kwargs: Any) -> None:
        self._sections: dict[str, list[Any]] = {}

    def __getitem__(self, key: str) -> list[Any]:
        return self._sections.setdefault(key, [])

    def __str__(self) -> str:
        return "\n"  # ``xp_capabilities`` drops the first line (the signature)


def _no_kwdoc(artist: Any) -> str:
    """Stands in for ``matplotlib.artist.kwdoc`` (:func:`skip_docstring_generation`)."""
    return ""


def skip_docstring_generation() -> None:
    """Switch off the docstring work scipy and matplotlib do at import time, in this process.

    For a child that only computes (the cross-check): scipy's ``xp_capabilities``
    decorator parses the numpydoc docstring of about 650 functions when ``scipy.signal``
    and ``scipy.stats`` are imported (its ``FunctionDoc``; other decorators through
    ``NumpyDocString._parse``), and matplotlib writes the property table of every
    ``Artist`` subclass into its ``set`` docstring (``matplotlib.artist.kwdoc``);
    python-control imports both. Here ``xp_capabilities`` writes an empty docstring, the
    parse leaves the default sections and ``kwdoc`` returns an empty table: only
    ``__doc__`` strings change, no signature, no function, no number (the cross-check's
    answers are the same, tested).
    Both are private names: when one is missing (another version) it is left alone.
    """
    with contextlib.suppress(Exception):
        from scipy._lib import _docscrape

        if callable(getattr(_docscrape.NumpyDocString, "_parse", None)):
            _docscrape.NumpyDocString._parse = _no_parse
    with contextlib.suppress(Exception):
        from scipy._lib import _array_api

        if isinstance(getattr(_array_api, "FunctionDoc", None), type):
            _array_api.FunctionDoc = _BlankDoc
    if isinstance(sys.modules.get("matplotlib"), DeferredModule):  # not imported here (defer_modules)
        return
    with contextlib.suppress(Exception):
        from matplotlib import artist

        if callable(getattr(artist, "kwdoc", None)):
            artist.kwdoc = _no_kwdoc


class DeferredModule(types.ModuleType):
    """Stands in for package ``name`` until something of it is used (:func:`defer_modules`).

    ``from name import f`` for ``f`` in ``names`` gives a function that imports the real
    module and calls its ``f`` (the same arguments, the same answer; so only names that
    the importer uses as callables, never as a base class or in ``isinstance``, may be
    listed); ``import name.sub as x`` for a stand-in ``name.sub`` gives that stand-in; any other attribute
    imports the real module at once and is the real one; after that every attribute is
    the real module's (copied here, so later lookups are plain). Unlike
    :class:`importlib.util.LazyLoader`, a ``from`` import of a listed name does not load
    the module. A submodule import (``import name.sub``) imports the real package first
    (a meta-path finder, ``_DeferredFinder``).
    """

    def __init__(self, name: str, names: Sequence[str]) -> None:
        super().__init__(name, f"stand-in for {name}, imported on first use (ftc_verify.prestart)")
        self.__dict__["__path__"] = []  # a package: ``from name import f`` asks for ``f`` (no submodule search)
        self.__dict__["__spec__"] = importlib.machinery.ModuleSpec(name, None)  # find_spec(name) answers, no error
        self.__dict__["_deferred_names"] = frozenset(names)
        self.__dict__["_deferred_real"] = None

    def _deferred_load(self) -> types.ModuleType:
        """The real module (imported now, once), its attributes copied here (under
        :data:`_LOAD_LOCK`: threads of an in-process caller see one import)."""
        with _LOAD_LOCK:
            return self._deferred_load_locked()

    def _deferred_load_locked(self) -> types.ModuleType:
        real = self.__dict__["_deferred_real"]
        if real is None:
            for name in [k for k, v in sys.modules.items() if v is self or (  # its stand-in submodules too:
                    k.startswith(f"{self.__name__}.") and isinstance(v, DeferredModule))]:  # the real import sees none
                del sys.modules[name]
            real = importlib.import_module(self.__name__)
            self.__dict__["_deferred_real"] = real
            self.__dict__.update({k: v for k, v in vars(real).items() if k not in ("__name__", "__doc__")})
        return real

    def __getattr__(self, attr: str) -> Any:
        sub = sys.modules.get(f"{self.__name__}.{attr}")
        if isinstance(sub, DeferredModule) and not self.__dict__["_deferred_real"]:
            return sub  # ``import name.sub as x``: the submodule's stand-in
        if attr.startswith("__") or attr not in self.__dict__["_deferred_names"] or self.__dict__["_deferred_real"]:
            return getattr(self._deferred_load(), attr)
        load = self._deferred_load

        def deferred(*args: Any, **kwargs: Any) -> Any:
            return getattr(load(), attr)(*args, **kwargs)

        deferred.__name__ = deferred.__qualname__ = attr
        return deferred


class _Present(importlib.abc.Loader):
    """Loads a module that is already in ``sys.modules``: that module, unchanged."""

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        return sys.modules[spec.name]

    def exec_module(self, module: types.ModuleType) -> None:
        """Nothing: the module ran when its package imported it."""


class _DeferredFinder(importlib.abc.MetaPathFinder):
    """``import name.sub`` while ``name`` is a :class:`DeferredModule`: the real package
    first, then ``name.sub`` as usual (or as the real package already imported it).
    ``rerun``: a stand-in with listed names was installed (:func:`_deferring`)."""

    def __init__(self) -> None:
        self.rerun = False

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: types.ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        stand_in = sys.modules.get(fullname.rpartition(".")[0])
        if not isinstance(stand_in, DeferredModule):
            return None
        real = stand_in._deferred_load()
        if fullname in sys.modules:
            return importlib.machinery.ModuleSpec(fullname, _Present())
        return importlib.machinery.PathFinder.find_spec(fullname, getattr(real, "__path__", None), target)


def defer_modules(deferred: Mapping[str, Sequence[str]]) -> None:
    """Put a :class:`DeferredModule` in ``sys.modules`` for each package of ``deferred``
    (its name -> the names ``from`` imports take from it) that is not imported yet.

    For a child that only computes (the cross-check, :data:`CROSS_CHECK_DEFERRED`): a
    package imported by a dependency but never used by the job costs no import; if the
    job does use it, it is imported then, and is the real package.
    """
    finder = next((f for f in sys.meta_path if isinstance(f, _DeferredFinder)), None)
    if finder is None:
        finder = _DeferredFinder()
        sys.meta_path.insert(0, finder)
    finder.rerun = finder.rerun or any(deferred.values())
    for name, names in deferred.items():
        if name not in sys.modules:
            sys.modules[name] = DeferredModule(name, names)


#: numpy's submodules that scipy's ``array_api_compat.numpy`` imports when it copies the
#: ``numpy`` namespace (``clone_module``: every name of ``dir(numpy)``, the lazily loaded
#: submodules too) and that nothing of ``ftc_verify`` uses: the Fortran wrapper generator
#: and the test helpers (with ``charset_normalizer``, ``email``, ``importlib.metadata``).
NUMPY_TOOLS = ("f2py", "testing")


def defer_numpy_tools() -> None:
    """Stand-ins (:class:`DeferredModule`) for :data:`NUMPY_TOOLS` not imported yet, in
    ``sys.modules`` and as attributes of ``numpy`` (numpy's module ``__getattr__`` imports
    them on first access, and ``import numpy.f2py as f2py`` would otherwise ask it again
    for the stand-in: an endless recursion), and the finder that imports the real package
    before any submodule of a stand-in. For a command that only computes (``analyze``,
    called before scipy is imported): scipy's import of ``scipy.linalg`` copies them
    without using them, about 0.07 s of CPU on the way to the first fork. Anything that
    uses one (an attribute, a submodule) gets the real package, imported then; the same
    numbers. It changes the interpreter for good (``sys.modules``, ``numpy``'s attributes,
    ``sys.meta_path``), so :func:`ftc_verify.cli.main` calls it only for its own process's
    command line, never for an in-process caller."""
    import numpy

    defer_modules({f"numpy.{name}": () for name in NUMPY_TOOLS})
    for name in NUMPY_TOOLS:
        stand_in = sys.modules.get(f"numpy.{name}")
        if isinstance(stand_in, DeferredModule) and name not in vars(numpy):
            setattr(numpy, name, stand_in)


def _deferring() -> bool:
    """Whether :func:`defer_modules` installed a stand-in with listed names in this process
    (its finder says so): a job that failed here may have failed on one (a listed class
    used as a class, a python-control version that imports differently), so the parent
    runs it again with the real modules instead of raising its exception. Stand-ins
    without listed names (:func:`defer_numpy_tools`) load the real package on any use."""
    return any(isinstance(f, _DeferredFinder) and f.rerun for f in sys.meta_path)


def _cross_check_prepare() -> None:
    """The cross-check child's preparation: no generated docstrings
    (:func:`skip_docstring_generation`), :data:`CROSS_CHECK_DEFERRED` imported on first use."""
    defer_modules(CROSS_CHECK_DEFERRED)
    skip_docstring_generation()


def _child(modules: Sequence[str], job_fd: int, answer_fd: int, prepare: Callable[[], None] | None) -> None:
    """The child: ``prepare()``, import ``modules``, wait for the job, answer ``(kind, value,
    seconds, spans)`` (``spans``: ``import`` and ``run`` as ``(start, end)`` of
    :func:`time.perf_counter`, one clock for every process on Linux)."""
    t0 = time.perf_counter()
    payload: tuple[str, Any, dict[str, float], dict[str, tuple[float, float]]]
    try:
        if prepare is not None:
            prepare()
        for name in modules:
            importlib.import_module(name)
        spans = {"import": (t0, time.perf_counter())}
        seconds = {"import": spans["import"][1] - t0}
        head = _read_exact(job_fd, _SIZE.size)
        body = None if head is None else _read_exact(job_fd, _SIZE.unpack(head)[0])
        if body is None:  # the parent never sent a job (it stopped early)
            return
        fn, arg = pickle.loads(body)
        t1 = time.perf_counter()
        try:
            value = fn(arg)
            spans["run"] = (t1, time.perf_counter())
            payload = ("ok", value, seconds | {"run": spans["run"][1] - t1}, spans)
        except Exception as exc:  # the job's own exception: raised again in the parent -- unless
            # stand-ins were in place (defer_modules): then the parent runs it with the real modules
            payload = ("error", repr(exc), seconds, spans) if _deferring() else ("raised", exc, seconds, spans)
    except Exception as exc:  # an import failed: the parent runs the job itself
        payload = ("error", repr(exc), {}, {})
    data = pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
    with contextlib.suppress(Exception), os.fdopen(answer_fd, "wb") as out:
        out.write(data)


class Prestarted:
    """A forked child that imports ``modules`` now and runs one job later (module docstring);
    ``prepare()``, when given, runs in the child before the imports.

    Attributes
    ----------
    seconds : dict
        After :meth:`result`: ``import`` (the child's imports), ``run`` (the job) and
        ``wait`` (how long :meth:`result` waited: the part that did not overlap the
        caller's work).
    spans : dict
        After :meth:`result`: ``import``, ``run`` and ``wait`` as ``(start, end)`` of
        :func:`time.perf_counter` (stages that overlap the caller's).
    """

    def __init__(self, modules: Sequence[str], prepare: Callable[[], None] | None = None) -> None:
        self.seconds: dict[str, float] = {}
        self.spans: dict[str, tuple[float, float]] = {}
        self._job: tuple[Callable[[Any], Any], Any] | None = None
        self.pid = 0
        self._job_w = self._answer_r = -1
        if not hasattr(os, "fork"):
            return
        job_r, job_w = os.pipe()
        answer_r, answer_w = os.pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        parent = os.getpid()
        pid = os.fork()
        if pid == 0:  # child
            try:
                import signal

                signal.signal(signal.SIGINT, signal.SIG_IGN)
                signal.signal(signal.SIGTERM, signal.SIG_DFL)
                die_with_parent(parent)
                os.close(job_w)
                os.close(answer_r)
                _child(tuple(modules), job_r, answer_w, prepare)
            finally:
                os._exit(0)
        os.close(job_r)
        os.close(answer_w)
        self.pid, self._job_w, self._answer_r = pid, job_w, answer_r

    def submit(self, fn: Callable[[Any], Any], arg: Any) -> None:
        """Hand the job ``fn(arg)`` to the child (once); ``fn`` a module-level function."""
        self._job = (fn, arg)
        if self._job_w < 0:
            return
        data = pickle.dumps(self._job, protocol=pickle.HIGHEST_PROTOCOL)
        fd, self._job_w = self._job_w, -1

        def send() -> None:
            with contextlib.suppress(OSError), os.fdopen(fd, "wb") as out:  # a child gone: result() runs it here
                out.write(_SIZE.pack(len(data)) + data)

        if len(data) < _PIPE_BYTES:
            send()
        else:  # more than a pipe holds: written while the child still imports, never waited for here
            threading.Thread(target=send, name="ftc-verify-prestarted", daemon=True).start()

    def result(self) -> Any:
        """``fn(arg)`` of :meth:`submit`: the child's answer, or computed here when it gave none."""
        if self._job is None:
            raise ValueError("Prestarted.result: no job was submitted")
        t0 = time.perf_counter()
        data = b""
        if self._answer_r >= 0:
            with os.fdopen(self._answer_r, "rb") as src:
                self._answer_r = -1
                data = src.read()
            with contextlib.suppress(ChildProcessError):
                os.waitpid(self.pid, 0)
            self.pid = 0
        kind, value, seconds, spans = pickle.loads(data) if data else ("error", "no answer", {}, {})
        if kind == "raised":
            raise value
        if kind != "ok":
            fn, arg = self._job
            t1 = time.perf_counter()
            value = fn(arg)
            spans = {"run": (t1, time.perf_counter())}
            seconds = {"run": spans["run"][1] - t1}
        self.spans = dict(spans) | {"wait": (t0, time.perf_counter())}
        self.seconds = dict(seconds) | {"wait": self.spans["wait"][1] - t0}
        return value

    def cancel(self) -> None:
        """Kill and reap the child if it is still running; close the pipes."""
        import signal

        for fd in (self._job_w, self._answer_r):
            if fd >= 0:
                os.close(fd)
        self._job_w = self._answer_r = -1
        if self.pid:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(self.pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(self.pid, 0)
            self.pid = 0


def cross_check() -> Prestarted:
    """The child of python-control's per-mode cross-check (:data:`CROSS_CHECK_MODULES`,
    imported without generated docstrings, :func:`skip_docstring_generation`, and without
    :data:`CROSS_CHECK_DEFERRED` until used, :func:`defer_modules`), started now; submit
    ``(cross_validate, loop)`` to it."""
    return Prestarted(CROSS_CHECK_MODULES, _cross_check_prepare)
