"""The ATmega328P firmware image in simavr: the real AVR build, its USART0 on a pty.

``firmware/build/simavr_pty`` (firmware/sim/simavr_pty.c) runs ``tvsmcu_atmega328p.elf`` at
16 MHz, paced to wall time, and prints the pty McuLink opens like the board's serial port. It also
prints what the board drives (Timer0's OC0A on the PWM pin, the direction and laser pins), read
from the simulated registers at each change, and how far the simulation fell behind wall time.
"""

from __future__ import annotations

import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from tvsd.errors import DeviceError
from tvsd.sim import emulator

IMAGE = emulator.FIRMWARE_DIR / "build" / "tvsmcu_atmega328p.elf"
RUNNER = emulator.FIRMWARE_DIR / "build" / "simavr_pty"
CLOCK_HZ = 16_000_000
START_TIMEOUT_S = 10.0
_PTY_LINE = re.compile(rb"^pty (\S+)$", re.M)
_OUT_LINE = re.compile(rb"^out t_us=(\d+) pwm=(\d) ocr0a=(\d+) dir=(\d) laser=(\d)$", re.M)
_PACE_LINE = re.compile(rb"^pace sim_ms=([\d.]+) wall_ms=([\d.]+) slipped_ms=([\d.]+)$", re.M)


class SimavrMcuError(DeviceError):
    """The simulator, the toolchain or the image is missing, or the runner did not come up."""


def missing_tools() -> list[str]:
    """Debian packages whose programs or headers are missing for building and running the image."""
    need = {"make": "make", "avr-gcc": "gcc-avr", "gcc": "gcc"}
    missing = {pkg for prog, pkg in need.items() if shutil.which(prog) is None}
    if not Path("/usr/lib/avr/include/avr/io.h").exists():
        missing.add("avr-libc")
    if not Path("/usr/include/simavr/sim_avr.h").exists():
        missing.add("libsimavr-dev")
    return sorted(missing)


def build() -> Path:
    """`make -C firmware sim-pty`: the image and its runner; the image's path, or one clear error."""
    emulator.make("sim-pty", RUNNER, SimavrMcuError)  # its prerequisites include the image
    return IMAGE


@dataclass(frozen=True, slots=True)
class Outputs:
    """What the board drives, read from the simulated registers."""

    t_us: int  # simulated time of the change
    pwm: bool  # OC0A connected to the PWM pin (off: disconnected and driven low)
    ocr0a: int  # Timer0's compare value: duty = ocr0a / 256 when pwm
    reverse: bool  # the H-bridge direction pin
    laser: bool


@dataclass(frozen=True, slots=True)
class Pace:
    """The simulation against wall time; slipped: simulated ms given up to stay near wall time."""

    sim_ms: float
    wall_ms: float
    slipped_ms: float


def duty_to_ocr0a(duty: int) -> int:
    """The compare value board_set_pwm writes for a pwm_set duty (firmware/board/atmega328p)."""
    return min(255, (abs(duty) + 64) >> 7)


class SimavrMcu(emulator.EmulatedBoard):
    """``with SimavrMcu() as m: McuLink(replace(settings, port=m.port))``."""

    def __init__(self, elf: Path | None = None) -> None:
        super().__init__(elf or IMAGE, "simavr")

    def start(self) -> str:
        """Start the runner; returns the pty of USART0 once it has printed it."""
        fix = f"run make -C {emulator.FIRMWARE_DIR} sim-pty"
        if not self.elf.exists():
            raise SimavrMcuError(f"no firmware image at {self.elf}: {fix}")
        if not RUNNER.exists():
            raise SimavrMcuError(f"no simavr runner at {RUNNER}: {fix}")
        self._proc = emulator.spawn([str(RUNNER), str(self.elf)], self._log_path)
        log = emulator.wait_started(
            self._proc, self._log_path, lambda seen: _PTY_LINE.search(seen) is not None, START_TIMEOUT_S
        )
        if log is None:
            said = emulator.log_tail(self._log_path).strip()
            status = self._proc.poll()
            self.close()
            if status is not None:
                raise SimavrMcuError(f"{RUNNER.name} exited with status {status}: {said}")
            raise SimavrMcuError(f"simavr did not start the board within {START_TIMEOUT_S:g} s: {said}")
        m = _PTY_LINE.search(log)
        assert m is not None
        self.port = m.group(1).decode()
        return self.port

    def _log(self) -> bytes:
        with open(self._log_path, "rb") as f:
            return f.read()

    def outputs(self) -> Outputs | None:
        """The outputs as last reported (None before the first report)."""
        found = _OUT_LINE.findall(self._log())
        if not found:
            return None
        t, pwm, ocr, rev, laser = (int(v) for v in found[-1])
        return Outputs(t, bool(pwm), ocr, bool(rev), bool(laser))

    def pace(self) -> Pace | None:
        """The last pace report (one a wall second)."""
        found = _PACE_LINE.findall(self._log())
        return Pace(*(float(v) for v in found[-1])) if found else None
