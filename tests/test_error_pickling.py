"""Every error of :mod:`ftc_verify.errors` survives the trip back from a forked stage,
however pickle is set up in the process (found by the in-process CLI tests: once Dask had
installed tblib's reducers in the test process, ``analyze`` over the memory limit ended in
an internal error instead of exit 2)."""

from __future__ import annotations

import copyreg
import importlib
import pickle
import pkgutil
from collections.abc import Iterator

import pytest

import ftc_verify
from ftc_verify.analysis.solvers import ForkedCall
from ftc_verify.errors import FTCError, MemoryLimitError


def _subclasses(cls: type) -> Iterator[type]:
    for sub in cls.__subclasses__():
        yield sub
        yield from _subclasses(sub)


def _all_errors() -> list[type]:
    for mod in pkgutil.walk_packages(ftc_verify.__path__, "ftc_verify."):
        importlib.import_module(mod.name)
    return sorted(set(_subclasses(FTCError)) | {FTCError}, key=lambda c: (c.__module__, c.__qualname__))


def test_every_error_class_can_be_made_by_its_own_new() -> None:
    """``cls.__new__(cls)``: what copyreg's and tblib's reconstructors call."""
    errors = _all_errors()
    assert MemoryLimitError in errors and len(errors) >= 8
    for cls in errors:
        assert isinstance(cls.__new__(cls), cls), cls


def _by_new(exc: BaseException) -> tuple[object, ...]:
    """A reducer of the kind tblib installs: rebuild by ``cls.__new__(cls, *args)``."""
    return _rebuild_by_new, (type(exc), exc.args, exc.__dict__)


def _rebuild_by_new(cls: type, args: tuple[object, ...], attrs: dict[str, object]) -> BaseException:
    inst: BaseException = cls.__new__(cls, *args)  # type: ignore[call-overload]
    inst.args = args
    inst.__dict__.update(attrs)
    return inst


def test_memory_limit_error_comes_back_from_a_forked_stage_under_a_new_based_reducer(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(copyreg.dispatch_table, MemoryLimitError, _by_new)
    back = pickle.loads(pickle.dumps(MemoryLimitError("about 105 kB needed, above the limit of 60 kB")))
    assert type(back) is MemoryLimitError and "60 kB" in str(back)

    def over_the_limit() -> None:
        raise MemoryLimitError("the sampled-data analysis: about 105 kB needed, above the limit of 60 kB")

    with pytest.raises(MemoryLimitError, match="above the limit of 60 kB"):
        ForkedCall(over_the_limit, "a stage over the memory limit").result()
