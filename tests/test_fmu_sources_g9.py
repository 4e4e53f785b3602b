"""The C glue every FMU shares (``fmus/common/fmi2_common.h``).

Each builder -- the ``LinearJumpPlant``, the ODE FMUs of FMI 2.0 and 3.0, the exported
controllers of FMI 2.0 and 3.0 -- packs the shared file into the FMU's ``sources/``; the
unpacked ``sources/`` compile alone (gcc, the builders' flags and ``-Werror``) into a library
that exports what the FMU's binary exports; a change of the shared file gives every FMU a
new cache key (or GUID) and a binary compiled from the changed file; and the messages of the
shared functions are those each FMU had before (one per FMU, read through the FMI 2.0 logger).
"""

from __future__ import annotations

import ctypes
import dataclasses
import shutil
import subprocess
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import ftc_verify.export.controller_fmu as controller_fmu
import ftc_verify.plants.ode_fmu as ode_fmu
import ftc_verify.plants.ode_fmu3 as ode_fmu3
from ftc_verify.controllers.files import load_controller
from ftc_verify.errors import FMUError
from ftc_verify.export.ccode import controller_c_source, controller_tables
from ftc_verify.model.files import load_system
from ftc_verify.plants.build import CFLAGS, COMMON_FILES, common_source_dir, fmi2_include_dir, link_flags
from ftc_verify.plants.linear_jump import build_binary, build_fmu, source_dir

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("nm") is None,
                                reason="gcc and nm are needed to compile and inspect the FMU sources")

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
GAINS = ROOT / "examples" / "paper_gains.toml"
KINDS = ("LinearJumpPlant", "ode-fmi2", "ode-fmi3", "ctrl-fmi2", "ctrl-fmi3")
#: The message of fmi2CancelStep, the same in every FMU.
CANCEL = b"fmi2CancelStep: fmi2DoStep never returns fmi2Pending in this FMU"


def _controller(dest: Path, fmi_version: str) -> Path:
    system = load_system(PAPER)
    tables = controller_tables(load_controller(GAINS), 0.01, system.m)
    return controller_fmu.build_controller_fmu(tables, controller_c_source(tables, title="g9"), dest,
                                               fmi_version=fmi_version, description="g9", certificate={},
                                               resources={})


BUILDERS: dict[str, Callable[[Path], Path]] = {
    "LinearJumpPlant": lambda d: build_fmu(load_system(PAPER), d / "plant.fmu"),
    "ode-fmi2": lambda d: ode_fmu.build_ode_fmu(ode_fmu.motor_spec(), d / "DCMotor.fmu"),
    "ode-fmi3": lambda d: ode_fmu.build_ode_fmu(ode_fmu.motor_spec(), d / "DCMotor3.fmu", fmi_version="3.0"),
    "ctrl-fmi2": lambda d: _controller(d / "K.fmu", "2.0"),
    "ctrl-fmi3": lambda d: _controller(d / "K3.fmu", "3.0"),
}
#: The C files a source FMU of each kind is compiled from (in ``sources/``).
MODEL = f"{ode_fmu.motor_spec().model_name}.c"
UNITS = {"LinearJumpPlant": ("model.c", "fmi2_glue.c"), "ode-fmi2": (MODEL, "ode_glue.c"),
         "ode-fmi3": (MODEL, "ode_glue3.c"), "ctrl-fmi2": ("ctrl_glue.c",), "ctrl-fmi3": ("ctrl_glue3.c",)}


@pytest.fixture(scope="module", autouse=True)
def cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    root = tmp_path_factory.mktemp("g9-cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FTC_VERIFY_CACHE", str(root))
        yield root


class Built(dict[str, Path]):
    """The FMU of each kind, built on first use (so that no one test pays for all five)."""

    def __init__(self, folder: Path) -> None:
        super().__init__()
        self.folder = folder

    def __missing__(self, kind: str) -> Path:
        self[kind] = BUILDERS[kind](self.folder)
        return self[kind]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory: pytest.TempPathFactory) -> Built:
    return Built(tmp_path_factory.mktemp("g9-fmus"))


def _exports(lib: Path) -> set[str]:
    out = subprocess.run(["nm", "-D", "--defined-only", str(lib)], capture_output=True, text=True, check=True)
    return {line.split()[-1] for line in out.stdout.splitlines() if line.split()[-1].startswith(("fmi2", "fmi3"))}


@pytest.mark.parametrize("kind", KINDS)
def test_sources_carry_the_shared_glue_and_compile_alone(kind: str, fmus: dict[str, Path], tmp_path: Path) -> None:
    with zipfile.ZipFile(fmus[kind]) as zf:
        zf.extractall(tmp_path)
        binaries = [n for n in zf.namelist() if n.startswith("binaries/")]
    sources = tmp_path / "sources"
    for name in COMMON_FILES:
        assert (sources / name).read_bytes() == (ROOT / "fmus" / "common" / name).read_bytes()
    lib = tmp_path / "alone.so"
    cmd = ["gcc", *CFLAGS, "-Werror", "-I", str(fmi2_include_dir()), "-I", str(sources),
           *(str(sources / unit) for unit in UNITS[kind]), "-o", str(lib), *link_flags()]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""  # warnings-clean
    (binary,) = binaries
    exported = _exports(lib)
    assert exported == _exports(tmp_path / binary)
    assert ("fmi3InstantiateCoSimulation" if kind.endswith("fmi3") else "fmi2Instantiate") in exported
    assert not any(n.startswith("fmi2") for n in exported) if kind.endswith("fmi3") else True
    assert CANCEL in lib.read_bytes()


def _changed_common(folder: Path) -> Path:
    """A copy of the shared glue whose fmi2CancelStep message ends in ``(changed)``."""
    folder.mkdir()
    for name in COMMON_FILES:
        text = (common_source_dir() / name).read_bytes()
        assert text.count(CANCEL) == 1
        (folder / name).write_bytes(text.replace(CANCEL, CANCEL + b" (changed)"))
    return folder


def test_a_changed_shared_file_rebuilds_the_plant(tmp_path: Path) -> None:
    copy = tmp_path / "src"
    shutil.copytree(source_dir(), copy)
    for name in COMMON_FILES:
        shutil.copy(common_source_dir() / name, copy / name)
    original = build_binary()
    assert build_binary(sources=copy).name == original.name  # the same bytes: the same key
    _changed_common(tmp_path / "common")
    for name in COMMON_FILES:
        shutil.copy(tmp_path / "common" / name, copy / name)
    changed = build_binary(sources=copy)
    assert changed.name != original.name
    assert CANCEL + b" (changed)" in changed.read_bytes() and CANCEL + b" (changed)" not in original.read_bytes()


@pytest.mark.parametrize("kind", ["ode-fmi2", "ode-fmi3", "ctrl-fmi2", "ctrl-fmi3"])
def test_a_changed_shared_file_rebuilds_the_other_fmus(kind: str, fmus: dict[str, Path], tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    before = fmus[kind]  # built now, from the shared file as shipped (the fixture builds on first use)
    common = _changed_common(tmp_path / "common")
    for module in (ode_fmu, controller_fmu):
        monkeypatch.setattr(module, "common_source_dir", lambda beside=None: common)
    rebuilt = BUILDERS[kind](tmp_path)
    with zipfile.ZipFile(before) as old, zipfile.ZipFile(rebuilt) as new:
        md_old, md_new = old.read("modelDescription.xml"), new.read("modelDescription.xml")
        assert md_old != md_new  # another GUID (instantiation token)
        for name in COMMON_FILES:
            assert new.read(f"sources/{name}") == (common / name).read_bytes()
        (lib_old,) = [old.read(n) for n in old.namelist() if n.startswith("binaries/")]
        (lib_new,) = [new.read(n) for n in new.namelist() if n.startswith("binaries/")]
    assert CANCEL + b" (changed)" in lib_new and CANCEL + b" (changed)" not in lib_old  # compiled again


# ------------------------------------------------------------------------------------------
# The shared functions' messages, per FMU (as before the glue was shared)
# ------------------------------------------------------------------------------------------

LOGGER = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_char_p)
ALLOC = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_size_t, ctypes.c_size_t)
FREE = ctypes.CFUNCTYPE(None, ctypes.c_void_p)


class Callbacks(ctypes.Structure):
    _fields_ = [("logger", LOGGER), ("allocateMemory", ALLOC), ("freeMemory", FREE),
                ("stepFinished", ctypes.c_void_p), ("componentEnvironment", ctypes.c_void_p)]


EXPECTED = {  # (fmi2SetRealInputDerivatives, fmi2GetRealStatus(fmi2DoStepStatus)) messages
    "LinearJumpPlant": "fmi2SetRealInputDerivatives is not supported (canInterpolateInputs=false; inputs are "
                       "held constant over a step)",
    "ode-fmi2": "fmi2SetRealInputDerivatives is not supported (canInterpolateInputs=false)",
    "ctrl-fmi2": "fmi2SetRealInputDerivatives is not supported (canInterpolateInputs=false)",
}


@pytest.mark.parametrize("kind", sorted(EXPECTED))
def test_shared_functions_answer_as_before(kind: str, fmus: dict[str, Path], tmp_path: Path) -> None:
    with zipfile.ZipFile(fmus[kind]) as zf:
        zf.extractall(tmp_path)
        (binary,) = [n for n in zf.namelist() if n.startswith("binaries/")]
        md = zf.read("modelDescription.xml").decode()
    guid = md.split('guid="', 1)[1].split('"', 1)[0]
    messages: list[tuple[bytes, int, bytes, bytes]] = []
    libc = ctypes.CDLL(None)
    libc.calloc.restype, libc.calloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t, ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    cb = Callbacks(LOGGER(lambda env, name, status, cat, msg: messages.append((name, status, cat, msg))),
                   ALLOC(lambda n, size: libc.calloc(n, size)), FREE(lambda p: libc.free(p)), None, None)
    dll = ctypes.CDLL(str(tmp_path / binary))
    dll.fmi2Instantiate.restype = ctypes.c_void_p
    dll.fmi2Instantiate.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_char_p,
                                    ctypes.POINTER(Callbacks), ctypes.c_int, ctypes.c_int]
    resources = (tmp_path / "resources").as_uri().encode()
    comp = dll.fmi2Instantiate(None, 1, guid.encode(), resources, ctypes.byref(cb), 0, 0)
    assert comp, messages
    c = ctypes.c_void_p(comp)
    try:
        vr, order, value = (ctypes.c_uint * 1)(1), (ctypes.c_int * 1)(1), (ctypes.c_double * 1)(0.0)
        real = ctypes.c_double(-1.0)
        assert dll.fmi2SetRealInputDerivatives(c, vr, ctypes.c_size_t(0), order, value) == 0
        assert dll.fmi2SetRealInputDerivatives(c, vr, ctypes.c_size_t(1), order, value) == 3
        assert dll.fmi2GetRealStatus(c, 0, ctypes.byref(real)) == 3
        assert dll.fmi2GetRealStatus(c, 2, ctypes.byref(real)) == 0 and real.value == 0.0
        assert dll.fmi2GetBooleanStatus(c, 3, ctypes.byref(ctypes.c_int(7))) == 0
        assert dll.fmi2CancelStep(c) == 3
        assert dll.fmi2DoStep(c, ctypes.c_double(0.0), ctypes.c_double(0.01), 1) == 3  # not in Step Mode
        assert dll.fmi2SetupExperiment(c, 0, ctypes.c_double(0.0), ctypes.c_double(float("nan")), 0,
                                       ctypes.c_double(0.0)) == 3
        assert dll.fmi2EnterInitializationMode(c) == 0
        assert dll.fmi2EnterInitializationMode(c) == 3
        assert dll.fmi2Reset(c) == 0
        # the controller may be terminated in any phase, the plants not before initialization
        assert dll.fmi2Terminate(c) == (0 if kind == "ctrl-fmi2" else 3)
    finally:
        dll.fmi2FreeInstance.argtypes = [ctypes.c_void_p]
        dll.fmi2FreeInstance(c)
    default_name = {"LinearJumpPlant": b"LinearJumpPlant", "ode-fmi2": ode_fmu.motor_spec().model_name.encode(),
                    "ctrl-fmi2": b"K"}[kind]
    assert {m[0] for m in messages} == {default_name}  # no instance name given: the model's
    assert all(m[1] == 3 and m[2] == b"logStatusError" for m in messages)
    assert [m[3].decode().replace("%%", "%") for m in messages] == [
        EXPECTED[kind],
        "fmi2GetRealStatus: only fmi2LastSuccessfulTime is available",
        CANCEL.decode(),
        "fmi2DoStep must not be called in Instantiated",
        "fmi2SetupExperiment: startTime nan is not finite",
        "fmi2EnterInitializationMode must not be called in Initialization Mode",
        *([] if kind == "ctrl-fmi2" else ["fmi2Terminate must not be called in Instantiated"]),
    ]


@pytest.mark.parametrize("build", [ode_fmu.build_ode_binary, ode_fmu3.build_ode_binary3])
def test_the_probe_of_either_fmi_version_names_the_mismatch(build: Callable[..., Path]) -> None:
    spec = dataclasses.replace(ode_fmu.motor_spec(), model_name="MismatchG9", states=(ode_fmu.OdeVariable("omega"),))
    with pytest.raises(FMUError, match=r"^MismatchG9\.c: the model file does not match its OdeFmuSpec: .*"
                                       r"ODE_NX \(states\) = 2 but the FMU spec has 1"):
        build(spec)
