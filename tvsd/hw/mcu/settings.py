"""The MCU's settings: the `mcu:` config section, and what McuLink (tvsd/hw/mcu/link.py) runs with.

Three layers of safety hang on its times (tvsd/daemon/drive_link.py): the control thread holds
PWM 0 once the newest state frame is `link_timeout_ms` old; the link reports the loss after
`link_lost_ms` without any frame; the firmware cuts PWM and laser `watchdog_ms` after the last
heartbeat (heartbeats go every watchdog_ms / 4, so an event-loop stall shorter than three
quarters of it is harmless).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tvsd.hw.mcu.clock import ClockSettings
from tvsd.hw.mcu.spec import FRAME_OVERHEAD
from tvsd.schema import FieldError, check, option

HEARTBEATS_PER_WATCHDOG = 4


@dataclass(frozen=True, kw_only=True)
class McuSettings:
    port: str = option("/dev/serial0", doc="serial port of the MCU")
    baud: int = option(2_000_000, doc="line rate; the firmware's", unit="bit/s", ge=9600)
    state_rate_hz: float = option(
        2500.0, doc="state frames per second: the ATmega328P carries 2.5 kHz", unit="Hz", ge=100, le=10000
    )
    encoder_counts_per_rev: int = option(8192, doc="encoder counts per shaft revolution (×4)", ge=4)
    watchdog_ms: int = option(
        50, doc="firmware fail-safe: no heartbeat this long → PWM and laser off", unit="ms", ge=5, le=1000
    )
    link_timeout_ms: float = option(
        40.0, doc="no state frame this long → the control thread holds PWM 0", unit="ms", gt=0, le=1000
    )
    link_lost_ms: float = option(
        50.0, doc="no frame at all this long → the link reports the loss (a fault)", unit="ms", gt=0, le=10000
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
    rtt_history: int = option(256, doc="heartbeat round trips kept for the status's RTT", ge=1)
    clock: ClockSettings = option(ClockSettings(), doc="the MCU clock's fit (tvsd/hw/mcu/clock.py)")
    spec_path: Path | None = option(None, doc="protocol spec (default: the package's)")

    def __post_init__(self) -> None:
        check(self)
        if self.link_timeout_ms > self.link_lost_ms:
            raise FieldError(
                "link_timeout_ms",
                f"must be at most link_lost_ms ({self.link_lost_ms:g} ms), got {self.link_timeout_ms:g}: "
                "the control thread holds PWM 0 before the link reports the loss",
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
