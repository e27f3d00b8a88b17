"""The PWM frame the daemon sends carries the law's command averaged over the exchange period.

The law ticks at 10 kHz, the frames go at the exchange rate (2 kHz with the ATmega: one frame per 5
ticks). A frame holding only the last tick's command aliases the command's tick-to-tick swing into
the voltage the drive applies, which the recording's u (the 1 ms mean of the ticks) does not show:
on the SIL daemon's identify runs the two differed by 2.1 V rms below 20 Hz (README, model doctor
step 8). These tests drive `DriveLink._send_pwm` with a runner whose last ticks alternate, and a
link that keeps the duty it is given (the wire itself is tested in test_mcu_link.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from tvsd.config import load_config
from tvsd.control.words import TICK_DTYPE
from tvsd.daemon.drive_link import DriveLink


class _Runner:
    """The last ticks' commands, as `Runner.recent_ticks` gives them (oldest first)."""

    def __init__(self, commands: list[float]) -> None:
        self.rows = np.zeros(len(commands), dtype=TICK_DTYPE)
        self.rows["u"] = commands

    @property
    def command(self) -> float:
        return float(self.rows["u"][-1])

    def recent_ticks(self, n: int) -> np.ndarray:
        return self.rows[-n:].copy()


class _Link:
    def __init__(self) -> None:
        self.duties: list[float] = []

    def send_pwm(self, duty: float) -> bool:
        self.duties.append(duty)
        return True


def _sent_volts(commands: list[float]) -> tuple[float, DriveLink]:
    cfg = load_config()
    drive = DriveLink(cfg, _Runner(commands), "hardware", on_pulse=print, on_link=print, on_fault=print)  # type: ignore[arg-type]
    link = _Link()
    drive.link = link  # type: ignore[assignment]
    drive._pwm_due = True  # a state frame came in the batch
    drive._send_pwm()
    assert len(link.duties) == 1
    return link.duties[0] * cfg.drive.u_max_v, drive


def test_the_frame_carries_the_mean_of_the_exchange_period() -> None:
    """Ticks alternating 4 V and 8 V: the frame carries the mean of the last state_div ticks
    (exchange 2 kHz → 5 ticks: 8, 4, 8, 4, 8 → 6.4 V), not the last tick's 8 V; the 11 V ticks
    before the exchange period do not count."""
    old = [11.0] * 20  # before the exchange period: not in the frame
    volts, drive = _sent_volts([*old, 4.0, 8.0, 4.0, 8.0, 4.0, 8.0])
    assert drive.state_div == 5
    assert volts == pytest.approx(np.mean([8.0, 4.0, 8.0, 4.0, 8.0]), abs=1e-3)  # 6.4 V; the last tick: 8 V


def test_a_zero_command_is_sent_at_once() -> None:
    """The loop's safe state (a fault, idle) commands exactly 0: the next frame is 0, not the mean
    of the ticks before it."""
    volts, _ = _sent_volts([9.0, 9.0, 9.0, 9.0, 0.0])
    assert volts == 0.0
