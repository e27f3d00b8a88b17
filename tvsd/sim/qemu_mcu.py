"""The STM32F405 firmware image in QEMU: the real Cortex-M build, its USART1 on a pty.

``qemu-system-arm -M netduinoplus2`` (an STM32F405) runs ``firmware/build/tvsmcu_stm32f405.elf``;
USART1 is a pseudo-terminal that McuLink opens like the board's serial port. The HMP monitor, on a
unix socket, reads the board's ``board_load`` block (time asleep, control ticks run, what it drove
onto the PWM and laser pins: QEMU has no TIM1/GPIO model to read them from) with the VM paused.

With ``icount=True`` QEMU runs ``-icount shift=0``: the guest's clock advances 1 ns per executed
instruction, so the busy time the firmware measures with its 168 MHz SysTick, in ns, is the number
of instructions it executed (tvsd/sim/stm32_bench.py turns that into a cycle estimate).

QEMU is started in its own process group and killed with its parent (PR_SET_PDEATHSIG): a test
that dies leaves no emulator behind.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
from dataclasses import dataclass
from pathlib import Path

from tvsd.errors import DeviceError
from tvsd.sim import emulator

FIRMWARE_DIR = emulator.FIRMWARE_DIR
IMAGE = FIRMWARE_DIR / "build" / "tvsmcu_stm32f405.elf"
QEMU = "qemu-system-arm"
NM = "arm-none-eabi-nm"
CLOCK_HZ = 168_000_000  # the board's HCLK; board_ticks() counts it
START_TIMEOUT_S = 10.0
_PTY_LINE = re.compile(rb"char device redirected to (\S+) \(label (\w+)\)")


class QemuMcuError(DeviceError):
    """The emulator or the image is missing, or QEMU did not come up."""


def missing_tools() -> list[str]:
    """Debian packages whose programs are missing for building and running the image."""
    need = {
        "make": "make",
        "arm-none-eabi-gcc": "gcc-arm-none-eabi",
        NM: "binutils-arm-none-eabi",
        QEMU: "qemu-system-arm",
    }
    return sorted({pkg for prog, pkg in need.items() if shutil.which(prog) is None})


def build_image() -> Path:
    """`make -C firmware stm32`; the image's path, or one clear error."""
    return emulator.make("stm32", IMAGE, QemuMcuError)


def symbols(elf: Path) -> dict[str, int]:
    """Data symbols of the image: name -> address."""
    out = subprocess.run([NM, str(elf)], capture_output=True, text=True, check=True).stdout
    syms: dict[str, int] = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[1] in "bBdD":
            syms[parts[2]] = int(parts[0], 16)
    return syms


@dataclass(frozen=True, slots=True)
class BoardLoad:
    """The image's ``board_load`` block (firmware/board/stm32f405/board_stm32.h)."""

    now: int  # board_ticks() at the last control tick (168 MHz, wraps at 2^32)
    idle_ticks: int  # ticks asleep in WFI (wraps at 2^32)
    ticks_run: int  # control ticks the main loop ran
    pwm_duty: int  # the duty the board last drove (-32767..32767)
    laser: bool
    wakeups: int  # WFI exits (wraps at 2^32)


class QemuMcu(emulator.EmulatedBoard):
    """``with QemuMcu() as q: McuLink(replace(settings, port=q.port))``."""

    def __init__(self, elf: Path | None = None, *, icount: bool = False) -> None:
        super().__init__(elf or IMAGE, "qemu")
        self.icount = icount
        self._monitor_path = os.path.join(self._dir.name, "monitor.sock")
        self._load_addr: int | None = None

    def start(self) -> str:
        """Start QEMU; returns the pty of USART1 once QEMU has printed it."""
        if not self.elf.exists():
            raise QemuMcuError(f"no firmware image at {self.elf}: run make -C {FIRMWARE_DIR} stm32")
        if shutil.which(QEMU) is None:
            raise QemuMcuError(f"{QEMU} is not installed: apt-get install qemu-system-arm (make system-deps)")
        self._load_addr = symbols(self.elf).get("board_load")
        cmd = [QEMU, "-M", "netduinoplus2", "-nographic", "-kernel", str(self.elf)]
        cmd += ["-chardev", "pty,id=usart1", "-serial", "chardev:usart1"]
        cmd += ["-monitor", f"unix:{self._monitor_path},server=on,wait=off"]
        if self.icount:
            cmd += ["-icount", "shift=0,sleep=on"]
        self._proc = emulator.spawn(cmd, self._log_path)

        def ready(log: bytes) -> bool:
            m = _PTY_LINE.search(log)
            self.port = m.group(1).decode() if m else ""
            return bool(self.port) and os.path.exists(self._monitor_path)

        if emulator.wait_started(self._proc, self._log_path, ready, START_TIMEOUT_S) is None:
            said = emulator.log_tail(self._log_path)
            self.close()
            raise QemuMcuError(f"{QEMU} did not start the board within {START_TIMEOUT_S:g} s: {said}")
        return self.port

    def load(self) -> BoardLoad:
        """Read ``board_load`` through the monitor with the VM paused (one consistent snapshot)."""
        if self._load_addr is None:
            raise QemuMcuError(f"{self.elf} has no board_load symbol")
        words = self._monitor(["stop", f"xp /6wx 0x{self._load_addr:08x}", "cont"])[1]
        vals = [int(v, 16) for v in re.findall(r"0x([0-9a-fA-F]{8})\b", words.split(":", 1)[1])]
        if len(vals) != 6:
            raise QemuMcuError(f"unexpected monitor answer: {words!r}")
        duty = vals[3] - (1 << 32) if vals[3] & 0x8000_0000 else vals[3]
        return BoardLoad(vals[0], vals[1], vals[2], duty, bool(vals[4]), vals[5])

    def _monitor(self, commands: list[str]) -> list[str]:
        """Run HMP commands; each one's output."""
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(5.0)
            s.connect(self._monitor_path)

            def until_prompt() -> str:
                buf = b""
                while not buf.endswith(b"(qemu) "):
                    chunk = s.recv(4096)
                    if not chunk:
                        raise QemuMcuError("the QEMU monitor closed")
                    buf += chunk
                return buf.decode(errors="replace")

            until_prompt()
            out = []
            for c in commands:
                s.sendall(c.encode() + b"\n")
                text = until_prompt()
                # the monitor echoes the command line (with terminal escapes) before its output
                lines = [
                    ln for ln in text.replace("\r", "").split("\n")[1:] if ln and not ln.startswith("(qemu)")
                ]
                out.append("\n".join(lines))
            return out
