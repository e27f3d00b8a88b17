"""What the daemon records, channel by channel, into one Recorder (tvsd/recording/writer.py).

Channels of a daemon recording (numpy structured rows; `tvsctl export REC --csv` writes `loop` as
docs/architecture.md's recording CSV, and `tvsd.recording.writer.open_recording(REC).channels[name]` gives
any of them to numpy/pandas users):

- `loop`       1 kHz bins of the control thread's ticks: t, u, omega, phi (docs/architecture.md's CSV).
- `loop_full`  every 10 kHz tick of a window: on request (`record_window`) and on every fault,
               the seconds before it (the control thread keeps 6.5 s); the fields of the runner's
               TICK_DTYPE (tvsd.control.runner).
- `reference`  1 kHz bins of phi_ref, omega_ref and the feedforward u_ff: the daemon's own
               reference, which the model doctor can use as an instrument in closed loop.
- `pulses`     every pulse event from the MCU: host time, MCU ticks, channel (0 zero, 1 optical).
- `points`     every point published, fields of tvsd.scan.points plus t_mono.
- `imu`        every IMU sample: sensor (0 PL, 1 SA), sample number, host time, accel, gyro.
- `pwm`        every PWM frame the daemon sent to the MCU: t (the loop's time axis, as `loop`)
               and the volts it carried (duty × drive.u_max_v): what the drive was told to
               apply, which `tvsctl export` writes as `u` (the law's 1 ms mean is `u_law`).
- `states`     every encoder state frame from the MCU: t (its sampling instant, from the MCU's tick
               stamp by the link's clock sync, on the loop's time axis; NaN before the sync),
               mcu_ticks, encoder (count), phi (rad). `tvsctl export` makes `phi` and `omega`
               from them: the angle where and when the MCU sampled it, whatever the frames'
               way to the control thread (docs/measurements/doctor-method.md, step 8). 32 B a frame: 64 kB/s
               at the ATmega's 2 kHz (a quarter of a SIL identify recording), 320 kB/s at 10 kHz.
- `excitation` what `identify` played (tvsd/daemon/identify.py): t (the loop's time axis, as
               `loop`), d_rps added to the speed reference, d_volts added to the command.
Marks: state changes, faults, windows, with their time.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tvsd.control.runner import TICK_DTYPE, Runner
from tvsd.recording.format import LOOP_CHANNEL, LOOP_FIELDS
from tvsd.recording.writer import Recorder
from tvsd.scan.points import FIELDS as POINT_FIELDS
from tvsd.scan.points import Point

if TYPE_CHECKING:
    from tvsd.daemon.drive_link import DriveLink

RECORD_PERIOD_S = 1e-3  # 10 kHz ticks → a 1 kHz recording (docs/architecture.md: sample_rate_hz)
REFERENCE_FIELDS = (("t", "<f8"), ("phi_ref", "<f8"), ("omega_ref", "<f8"), ("u_ff", "<f8"))
PULSE_FIELDS = (("t_host", "<f8"), ("mcu_ticks", "<i8"), ("channel", "<i2"))
IMU_FIELDS = (
    ("sensor", "<u1"), ("k", "<i8"), ("t", "<f8"),
    ("ax", "<f4"), ("ay", "<f4"), ("az", "<f4"), ("gx", "<f4"), ("gy", "<f4"), ("gz", "<f4"),
)  # fmt: skip
PWM_FIELDS = (("t", "<f8"), ("volts", "<f8"))
STATE_FIELDS = (("t", "<f8"), ("mcu_ticks", "<i8"), ("encoder", "<i8"), ("phi", "<f8"))
IMU_SENSORS = {"pl": 0, "sa": 1}


class SessionRecording:
    """One recording of the running daemon; every method is for the event-loop thread."""

    def __init__(self, path: Path, config_text: str, *, from_tick: int = 0) -> None:
        """Record into `path` (created), the control ticks from tick number `from_tick` on."""
        self.path = path
        self._next_tick = from_tick  # the number of the next control tick to record
        self.lost_ticks = 0  # overwritten in the runner's ring before a drain read them
        self.recorder = Recorder(path, config_text)
        r = self.recorder
        self.loop = r.channel(LOOP_CHANNEL, list(LOOP_FIELDS))
        self.reference = r.channel("reference", list(REFERENCE_FIELDS))
        self.full = r.channel("loop_full", TICK_DTYPE.descr)
        self.pulses = r.channel("pulses", list(PULSE_FIELDS))
        point_fields = [(f, "<i8" if f == "flags" else "<f8") for f in POINT_FIELDS]
        self.points = r.channel("points", [*point_fields, ("t_mono", "<f8")])
        self.imu = r.channel("imu", list(IMU_FIELDS))
        self.pwm = r.channel("pwm", list(PWM_FIELDS))
        self._next_frame = -1  # the number of the next PWM frame to record (-1: from the first seen)
        self.states = r.channel("states", list(STATE_FIELDS))
        self._next_state = -1  # the number of the next state frame to record (as _next_frame)
        self._carry = np.zeros(0, dtype=TICK_DTYPE)  # ticks of the open bin

    @property
    def error(self) -> BaseException | None:
        return self.recorder.error

    def drain(self, runner: Runner, drive: DriveLink | None = None) -> None:
        """The control ticks since the last drain, by tick number (`Runner.ticks_since`): none
        twice, none skipped; ticks the ring overwrote first are counted and marked `ticks_lost`.
        With the drive link, the PWM frames it sent since (`pwm`)."""
        if drive is not None:
            self.pwm_frames(*drive.sent_since(max(self._next_frame, 0)), start_ns=runner.start_ns)
            ticks, enc, host, end = drive.states_since(max(self._next_state, 0))
            self.state_frames(
                ticks, enc, host, end, rad_per_count=drive.rad_per_count, start_ns=runner.start_ns
            )
        batch = runner.ticks_since(self._next_tick)
        self._next_tick = batch.next
        if batch.lost:
            self.lost_ticks += batch.lost
            self.recorder.mark("ticks_lost", ticks=batch.lost, first=batch.first - batch.lost)
        if len(batch.rows):
            self.loop_ticks(batch.rows)

    def loop_ticks(self, rows: np.ndarray) -> None:
        """Average ticks (TICK_DTYPE rows) into RECORD_PERIOD_S bins of their own time stamps: a
        uniform time grid whatever the wake-up jitter; a stall longer than a bin leaves a gap,
        which `tvsctl export` reports. The last, unfinished bin waits for the next batch."""
        rows = np.concatenate([self._carry, rows]) if len(self._carry) else rows
        if not len(rows):
            return
        bins = np.floor(rows["t"] / RECORD_PERIOD_S).astype(np.int64)
        done = bins < bins[-1]
        self._carry = rows[~done]
        if not np.any(done):
            return
        rows, bins = rows[done], bins[done]
        ids, start, count = np.unique(bins, return_index=True, return_counts=True)
        t = (ids + 1) * RECORD_PERIOD_S

        def mean(field: str) -> np.ndarray:
            return np.add.reduceat(rows[field], start) / count

        last = rows[start + count - 1]
        self.loop.append({"t": t, "u": mean("u"), "omega": mean("omega"), "phi": last["phi"]})
        ref = {"phi_ref": last["phi_ref"], "omega_ref": mean("omega_ref"), "u_ff": mean("u_ff")}
        self.reference.append({"t": t, **ref})

    def pwm_frames(self, host: np.ndarray, volts: np.ndarray, end: int, *, start_ns: int) -> None:
        """PWM frames sent (host times, time.monotonic; the loop's t is CLOCK_MONOTONIC since
        the runner's start), up to frame number `end`; those sent before the recording began
        are left out (the first drain only notes where the count stands)."""
        first = self._next_frame
        self._next_frame = end
        if first < 0 or not len(host):
            return
        self.pwm.append({"t": host - start_ns / 1e9, "volts": volts})

    def state_frames(
        self,
        ticks: np.ndarray,
        enc: np.ndarray,
        host: np.ndarray,
        end: int,
        *,
        rad_per_count: float,
        start_ns: int,
    ) -> None:
        """Encoder state frames received (MCU ticks, counts, sampling instants on time.monotonic)
        up to frame number `end`. The first call's are kept too (the ring's last 0.8 s): the loop's
        first bins lie before the first drain, and the export places every bin among frames."""
        self._next_state = end
        if not len(ticks):
            return
        t = host - start_ns / 1e9
        self.states.append({"t": t, "mcu_ticks": ticks, "encoder": enc, "phi": enc * rad_per_count})

    def window(self, rows: np.ndarray, reason: str) -> None:
        """A full-rate window of control ticks (TICK_DTYPE rows), marked with why it was taken."""
        if len(rows):
            self.recorder.mark("window", reason=reason, t0=float(rows["t"][0]), ticks=len(rows))
            self.full.append(rows)

    def pulse(self, t_host: float, mcu_ticks: int, channel: int) -> None:
        self.pulses.append({"t_host": t_host, "mcu_ticks": mcu_ticks, "channel": channel})

    def point(self, point: Point) -> None:
        self.points.append({f: getattr(point, f) for f in self.points.dtype.names or ()})

    def imu_batch(
        self, sensor: str, k: np.ndarray, t: np.ndarray, accel: np.ndarray, gyro: np.ndarray
    ) -> None:
        self.imu.append(
            {
                "sensor": np.full(len(k), IMU_SENSORS.get(sensor, 255)),
                "k": k, "t": t,
                "ax": accel[:, 0], "ay": accel[:, 1], "az": accel[:, 2],
                "gx": gyro[:, 0], "gy": gyro[:, 1], "gz": gyro[:, 2],
            }
        )  # fmt: skip

    def excitation(self, t: np.ndarray, d_rps: np.ndarray, d_volts: np.ndarray) -> None:
        """The excitation table identify plays, each row at its time on the loop's axis."""
        ch = self.recorder.channel("excitation", [("t", "<f8"), ("d_rps", "<f8"), ("d_volts", "<f8")])
        ch.append({"t": t, "d_rps": d_rps, "d_volts": d_volts})

    def mark(self, event: str, **data: Any) -> None:
        self.recorder.mark(event, **data)

    def close(self) -> None:
        self.recorder.close()
