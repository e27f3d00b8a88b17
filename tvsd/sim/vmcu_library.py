"""Where the virtual MCU's firmware core comes from: find, build and load the host library.

Owner of the one binary boundary of the SIL's MCU: the firmware's C core (``firmware/core``)
compiled with a host board layer into a shared library, in a source checkout
``firmware/build/libtvsmcu_host.so`` (``make -C firmware host-lib``; the top Makefile's ``run`` and
``pytest`` build it), in an installed wheel ``tvsd/sim/_vmcu*.so`` (compiled by setup.py when the
wheel was built). tvsd never compiles it while it runs (:func:`build_library` is for the test
suite and developers). :func:`load_library` loads a private copy with its ctypes signatures
declared once here; :class:`tvsd.sim.virtual_mcu.VirtualMcu` drives it.
"""

from __future__ import annotations

import ctypes
import importlib.util
import shutil
import subprocess
import tempfile
from pathlib import Path

from tvsd.errors import DeviceError

FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware"
LIBRARY = FIRMWARE_DIR / "build" / "libtvsmcu_host.so"  # the checkout's (make -C firmware host-lib)
PACKAGED_MODULE = "tvsd.sim._vmcu"  # the wheel's (setup.py's build_ext)


class VirtualMcuError(DeviceError):
    """The virtual MCU cannot be built, loaded or used as asked."""


def packaged_library() -> Path | None:
    """The core compiled into the installed package (a ctypes library: never imported)."""
    try:
        found = importlib.util.find_spec(PACKAGED_MODULE)
    except (ImportError, ValueError):
        return None
    return Path(found.origin) if found is not None and found.origin else None


def default_library() -> Path:
    """The library to load: the checkout's build when this is a source checkout, else the wheel's.

    Raises VirtualMcuError with the fix when neither exists (nothing is compiled here)."""
    if (FIRMWARE_DIR / "Makefile").is_file():  # a source checkout
        if LIBRARY.is_file():
            return LIBRARY
        packaged = packaged_library()
        if packaged is not None and packaged.is_file():
            return packaged  # `pip install -e .` compiled it from these sources
        raise VirtualMcuError(
            f"the virtual MCU library {LIBRARY} is not built. Fix: make -C {FIRMWARE_DIR} host-lib "
            "(or `make run` / `make test`, which build it)"
        )
    packaged = packaged_library()
    if packaged is not None and packaged.is_file():
        return packaged
    raise VirtualMcuError(
        f"this tvsd install has no virtual MCU library ({PACKAGED_MODULE.replace('.', '/')}*.so): "
        "the wheel was built without it. Fix: reinstall from a wheel built on a machine with a C "
        "compiler (pip wheel . in the source tree; README, On the scanner)"
    )


def build_library(path: Path = LIBRARY) -> Path:
    """Build the checkout's library with ``make -C firmware host-lib`` if it is missing: for the
    test suite and developers, never called by tvsd itself."""
    if path.exists():
        return path
    missing = [tool for tool in ("make", "gcc") if shutil.which(tool) is None]
    if missing:
        raise VirtualMcuError(
            f"{path} is missing and cannot be built: {', '.join(missing)} not found. "
            "Fix: install the build tools (apt-get install build-essential), or run "
            "`make -C firmware host-lib` on a machine that has them and copy the library."
        )
    proc = subprocess.run(
        ["make", "-C", str(FIRMWARE_DIR), "host-lib"], capture_output=True, text=True, check=False
    )
    if proc.returncode != 0 or not path.exists():
        raise VirtualMcuError(
            f"building {path} failed (make -C {FIRMWARE_DIR} host-lib, status "
            f"{proc.returncode}):\n{proc.stderr.strip()[-2000:]}"
        )
    return path


def load_library(path: Path) -> tuple[ctypes.CDLL, Path]:
    """Load a private copy of the library: the core is a singleton per loaded image, and a
    copy under another name gets its own, so several virtual MCUs can live in one process."""
    tmpdir = Path(tempfile.mkdtemp(prefix="tvsmcu-"))
    copy = tmpdir / path.name
    shutil.copyfile(path, copy)
    try:
        lib = ctypes.CDLL(str(copy))
    except OSError as exc:
        shutil.rmtree(tmpdir, ignore_errors=True)
        raise VirtualMcuError(f"cannot load {path}: {exc}. Fix: make -C firmware clean host-lib") from exc
    u8, u64, i32 = ctypes.c_uint8, ctypes.c_uint64, ctypes.c_int32
    buf = ctypes.POINTER(ctypes.c_uint8)
    for name, res, args in (
        ("vmcu_init", None, []),
        ("vmcu_clock_hz", ctypes.c_uint32, []),
        ("vmcu_now", u64, []),
        ("vmcu_advance_to", None, [u64]),
        ("vmcu_rx_bytes", None, [buf, ctypes.c_size_t]),
        ("vmcu_rx_bytes_at", None, [buf, ctypes.c_size_t, u64]),
        ("vmcu_watchdog", ctypes.c_int, [ctypes.POINTER(u64), ctypes.POINTER(u64)]),
        ("vmcu_watchdog_defer", None, [ctypes.c_int]),
        ("vmcu_watchdog_check", None, []),
        ("vmcu_tx_bytes", ctypes.c_size_t, [buf, ctypes.c_size_t]),
        ("vmcu_set_encoder", None, [i32]),
        ("vmcu_encoder_ramp", None, [u64, ctypes.c_double, u64, ctypes.c_double]),
        ("vmcu_pulse", None, [u8, u64]),
        ("vmcu_set_limit", None, [u8, ctypes.c_int, i32]),
        ("vmcu_pwm", ctypes.c_int16, []),
        ("vmcu_laser", ctypes.c_int, []),
        ("vmcu_stepper_position", i32, [u8]),
        ("vmcu_step_count", ctypes.c_uint32, [u8]),
    ):
        fn = getattr(lib, name)
        fn.restype = res
        fn.argtypes = args
    return lib, tmpdir
