"""The PWM frame the daemon sends carries the law's command averaged since the previous frame.

The law ticks at 10 kHz, the frames go at the exchange rate (2 kHz with the ATmega: one frame per 5
ticks; the SIL pty hands the states over each millisecond, so there one frame per 10 ticks). A frame
holding only the last tick's command aliases the command's tick-to-tick swing into
the voltage the drive applies, which the recording's u (the 1 ms mean of the ticks) does not show:
on the SIL daemon's identify runs the two differed by 2.1 V rms below 20 Hz
(docs/measurements/doctor-method.md, model doctor
step 8). These tests drive `DriveLink._send_pwm` with a runner whose last ticks alternate, and a
link that keeps the duty it is given (the wire itself is tested in test_mcu_link.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from tvsd.config import load_config
from tvsd.control.words import TICK_DTYPE
from tvsd.daemon.drive_link import MEAN_MAX_TICKS, DriveLink


class _Runner:
    """The ticks' commands, as `Runner.ticks` and `Runner.recent_ticks` give them."""

    def __init__(self, commands: list[float]) -> None:
        self.rows = np.zeros(len(commands), dtype=TICK_DTYPE)
        self.rows["u"] = commands

    @property
    def ticks(self) -> int:
        return len(self.rows)

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


def _sent_volts(commands: list[float], last_frame_tick: int) -> float:
    """The volts of the PWM frame made after `commands`, the previous frame made at tick
    `last_frame_tick`."""
    cfg = load_config()
    drive = DriveLink(cfg, _Runner(commands), "hardware", on_pulse=print, on_link=print, on_fault=print)  # type: ignore[arg-type]
    link = _Link()
    drive.link = link  # type: ignore[assignment]
    drive._answering = True  # as after start's heartbeat round trip (the firmware armed)
    drive._frame_tick = last_frame_tick
    drive._pwm_due = True  # a state frame came in the batch
    drive._send_pwm()
    assert len(link.duties) == 1
    assert drive._frame_tick == len(commands)
    return link.duties[0] * cfg.drive.u_max_v


def test_the_frame_carries_the_mean_since_the_last_frame() -> None:
    """Ticks alternating 4 V and 8 V since the last frame: the frame carries their mean, 6 V, not
    the last tick's 8 V; the 11 V ticks before the last frame do not count. Ten ticks: the SIL
    pty hands the states over each millisecond, so a frame follows two states' worth of ticks."""
    assert _sent_volts([11.0] * 20 + [4.0, 8.0] * 5, last_frame_tick=20) == pytest.approx(6.0, abs=1e-3)


def test_a_late_frame_averages_at_most_the_longest_exchange_period() -> None:
    """After a stall, the last MEAN_MAX_TICKS ticks (4 ms) only: an old command is not sent."""
    volts = _sent_volts([11.0] * 100 + [5.0] * MEAN_MAX_TICKS, last_frame_tick=0)
    assert volts == pytest.approx(5.0, abs=1e-3)


def test_a_zero_command_is_sent_at_once() -> None:
    """The loop's safe state (a fault, idle) commands exactly 0: the next frame is 0, not the mean
    of the ticks before it."""
    assert _sent_volts([9.0, 9.0, 9.0, 9.0, 0.0], last_frame_tick=0) == 0.0


def test_the_frames_sent_are_recorded_on_the_loops_clock(tmp_path) -> None:
    """`DriveLink.sent_since` hands the frames sent to the recording's `pwm` channel (t on the
    loop's clock: time.monotonic less the runner's start); frames sent before the recording's
    first drain are not recorded, and none twice."""
    from tvsd.daemon.session_recording import SessionRecording
    from tvsd.recording.reader import open_recording

    cfg = load_config()
    runner = _Runner([3.0] * 10)
    drive = DriveLink(cfg, runner, "hardware", on_pulse=print, on_link=print, on_fault=print)  # type: ignore[arg-type]
    drive.link = _Link()  # type: ignore[assignment]
    drive._answering = True  # as after start's heartbeat round trip (the firmware armed)

    def frame() -> None:
        drive._pwm_due = True
        drive._send_pwm()

    frame()  # before the recording: not in it
    start_s = 5.0
    session = SessionRecording(tmp_path / "rec", "plant: {}\n")
    session.pwm_frames(*drive.sent_since(0), start_ns=round(start_s * 1e9))
    frame()
    frame()
    host, volts, end = drive.sent_since(0)
    assert end == 3 and volts.tolist() == pytest.approx([3.0] * 3)
    session.pwm_frames(*drive.sent_since(1), start_ns=round(start_s * 1e9))
    session.pwm_frames(*drive.sent_since(3), start_ns=round(start_s * 1e9))  # nothing new
    session.close()
    rows = open_recording(tmp_path / "rec").channels["pwm"]
    np.testing.assert_allclose(rows["t"], host[1:] - start_s, atol=1e-6)
