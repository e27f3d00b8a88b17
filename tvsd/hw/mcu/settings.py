"""The MCU's settings: the `mcu:` config section, and what McuLink (tvsd/hw/mcu/link.py) runs with.

Three layers of safety hang on its times (tvsd/daemon/drive_link.py): the control thread holds
PWM 0 once the newest state frame is `link_timeout_ms` old; the link reports the loss after
`link_lost_ms` without any frame; the firmware cuts PWM and laser `watchdog_ms` after the last
heartbeat (heartbeats go every watchdog_ms / 4, so an event-loop stall shorter than three
quarters of it is harmless). Between the first two the hold is not latched (`late_input_hold`,
tvsd.control.hold): frames that come late but complete — the host's tty input was delayed, the
MCU sent them on time — resume control; a gap in them, or none by `link_lost_ms`, latches.

`board` names the MCU board (firmware/board/<name>): identify must report it, and it sets how
many state + PWM exchanges per second the daemon runs (`exchange_hz`): what each board carries
with room to spare (ATmega328P 2 kHz at 80 % CPU in simavr with protocol v2's CRC-32, where
2.5 kHz would be 92 %: `make -C firmware test`; STM32F405 10 kHz: `make -C firmware
bench-stm32`). `state_rate_hz` overrides it, up to the board's rate.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tvsd.hw.mcu.clock import ClockSettings
from tvsd.hw.mcu.spec import FRAME_OVERHEAD
from tvsd.hw.mcu.tty_workers import MODES as TTY_WORKER_MODES
from tvsd.schema import FieldError, check, option

HEARTBEATS_PER_WATCHDOG = 4
# board -> state + PWM exchanges per second it carries (firmware/board/stm32f405/README.md)
BOARD_EXCHANGE_HZ = {"atmega328p": 2000.0, "stm32f405": 10000.0}
# identify's board name of the SIL's virtual MCU (the core built for the host, firmware/board/host)
SIL_BOARD = "host"


@dataclass(frozen=True, kw_only=True)
class McuSettings:
    port: str = option("/dev/serial0", doc="serial port of the MCU")
    baud: int = option(2_000_000, doc="line rate; the firmware's", unit="bit/s", ge=9600)
    board: str = option(
        "atmega328p",
        doc="the MCU board: identify must report it; its exchange rate (ATmega 2 kHz, STM32 10 kHz)",
        choices=tuple(BOARD_EXCHANGE_HZ),
    )
    state_rate_hz: float | None = option(
        None, doc="state + PWM exchanges per second; default: the board's", unit="Hz", ge=100, le=10000
    )
    encoder_counts_per_rev: int = option(8192, doc="encoder counts per shaft revolution (×4)", ge=4)
    watchdog_ms: int = option(
        50, doc="firmware fail-safe: no heartbeat this long → PWM and laser off", unit="ms", ge=5, le=1000
    )
    link_timeout_ms: float = option(
        40.0, doc="no state frame this long → the control thread holds PWM 0", unit="ms", gt=0, le=1000
    )
    link_lost_ms: float = option(
        500.0,
        doc="no frame at all this long → the link is lost (a fault; the late-input hold's bound)",
        unit="ms",
        gt=0,
        le=10000,
    )
    late_input_hold: bool = option(
        True,
        doc="at link_timeout_ms hold PWM 0 unlatched; resume if the frames that follow show the MCU "
        "sent every one (false: latch at once)",
    )
    identify_timeout_ms: float = option(
        500.0, doc="the MCU answers identify within this (3 tries share it)", unit="ms", gt=0
    )
    tx_buffer_bytes: int = option(
        4096,
        doc="output pending beyond what the driver took (~20 ms at 2 Mbaud); a frame must fit",
        unit="B",
        ge=FRAME_OVERHEAD + 32,
    )
    tty_workers: str = option(
        "nice",
        doc="under --realtime, the kernel's tty workers (kworker/u*, which hand the MCU's bytes to the "
        "link) while the link is open: nice -20, SCHED_FIFO 1, or off (tvsd/hw/mcu/tty_workers.py)",
        choices=TTY_WORKER_MODES,
    )
    rtt_history: int = option(256, doc="heartbeat round trips kept for the status's RTT", ge=1)
    clock: ClockSettings = option(ClockSettings(), doc="the MCU clock's fit (tvsd/hw/mcu/clock.py)")
    spec_path: Path | None = option(None, doc="protocol spec (default: the package's)")

    def __post_init__(self) -> None:
        check(self)
        board_hz = BOARD_EXCHANGE_HZ[self.board]
        if self.state_rate_hz is not None and self.state_rate_hz > board_hz:
            raise FieldError(
                "state_rate_hz",
                f"the {self.board} carries at most {board_hz:g} exchanges/s, got {self.state_rate_hz:g}: "
                "lower it, or set mcu.board to the board you have",
            )
        if self.link_timeout_ms > self.link_lost_ms:
            raise FieldError(
                "link_timeout_ms",
                f"must be at most link_lost_ms ({self.link_lost_ms:g} ms), got {self.link_timeout_ms:g}: "
                "the control thread holds PWM 0 before the link reports the loss",
            )

    @property
    def exchange_hz(self) -> float:
        """State + PWM exchanges per second: state_rate_hz, else the board's rate."""
        return self.state_rate_hz if self.state_rate_hz is not None else BOARD_EXCHANGE_HZ[self.board]

    def board_problem(self, reported: str, sil: bool = False) -> str | None:
        """None if identify's board name is the configured one (or, in SIL, the virtual MCU's);
        else one line: what was seen and the fix."""
        if reported == self.board or (sil and reported == SIL_BOARD):
            return None
        return (
            f"the MCU on {self.port} reports board {reported} but mcu.board is {self.board}: set "
            f"mcu.board: {reported} in the config, or flash the {self.board} image (hil/README.md)"
        )

    @property
    def heartbeat_period_s(self) -> float:
        return self.watchdog_ms / HEARTBEATS_PER_WATCHDOG / 1e3

    @property
    def link_lost_s(self) -> float:
        return self.link_lost_ms / 1e3

    @property
    def identify_timeout_s(self) -> float:
        return self.identify_timeout_ms / 1e3
