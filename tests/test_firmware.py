"""The firmware's own checks, from pytest: `make -C firmware all test`.

That builds the ATmega328P and STM32F405 images (and fails if one outgrows its flash or RAM),
runs the core's C unit tests and the STM32 board layer's register-level tests on the host, and
runs the AVR image in simavr (identify handshake, fail-safe timing, load);
tests/test_mcu_stm32.py runs the STM32 image in QEMU.
The top Makefile installs the toolchain; where it is absent and cannot be installed (not root),
the test is skipped and says which packages and command are missing.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # builds both images and runs the AVR one in simavr (~30 s)

FIRMWARE = Path(__file__).resolve().parents[1] / "firmware"
TOOLS = {
    "make": "make",
    "gcc": "gcc",
    "avr-gcc": "gcc-avr",
    "simavr": "simavr",
    "arm-none-eabi-gcc": "gcc-arm-none-eabi",
}
HEADERS = {Path("/usr/include/simavr/sim_avr.h"): "libsimavr-dev"}


def _missing_packages() -> list[str]:
    missing = [pkg for tool, pkg in TOOLS.items() if shutil.which(tool) is None]
    missing += [pkg for path, pkg in HEADERS.items() if not path.exists()]
    return missing


def test_firmware_builds_and_passes() -> None:
    missing = _missing_packages()
    if missing and os.geteuid() != 0:
        pytest.skip(
            f"firmware toolchain missing: {' '.join(missing)}; "
            f"fix: sudo apt-get install -y {' '.join(missing)} (or run `make system-deps`)"
        )
    proc = subprocess.run(
        ["make", "-C", str(FIRMWARE), "all", "test"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"make -C firmware all test failed:\n{out[-4000:]}"
    assert "0 failed" in out, "the C unit tests did not report"
    assert "simavr smoke: 0 failure(s)" in out, "the simavr smoke test did not report"
    assert "stm32 board tests:" in out and out.count(" 0 failed") >= 2, "the STM32 board tests did not report"
