"""The daemon's status as typed values, turned into JSON only at the edges (RPC, CAN, notify).

`Status.to_json()` is the object `tvsctl status --json` prints and the `status` subscription
carries: a contract (docs/architecture.md, "Daemon API"): fields are added, never renamed or
removed. `imu` and `link` are their components' own status objects (tvsd.daemon.imu_service,
tvsd.daemon.drive_link), already JSON.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from tvsd.control.latency import Jitter
from tvsd.control.runner import Realtime
from tvsd.daemon.faults import FaultEntry
from tvsd.daemon.state import DaemonState


@dataclass(frozen=True)
class LoopStatus:
    """The control thread's timing (tvsd.control.latency.Jitter, the fields the status shows)."""

    rate_hz: float
    missed_ticks: int
    jitter_p99_us: float
    jitter_max_us: float
    ticks: int

    @classmethod
    def of(cls, j: Jitter) -> LoopStatus:
        return cls(j.rate_hz, j.missed_ticks, j.p99_us, j.max_us, j.ticks)


@dataclass(frozen=True)
class PointsStatus:
    total: int  # points published since start
    no_imu: int  # of them flagged no_imu
    per_s: float  # over the last 2 s
    latency_p50_ms: float | None = None  # optical pulse → point published (none yet: absent)
    latency_max_ms: float | None = None
    compensated: bool | None = None  # while scanning: the points are IMU-compensated
    uncompensated_why: str | None = None  # while scanning uncompensated: why

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items() if v is not None or k in ("total", "no_imu", "per_s")}


@dataclass(frozen=True)
class Aim:
    phi: float  # deg
    gamma: float  # deg


@dataclass(frozen=True)
class Status:
    state: DaemonState
    rps: float  # measured, mean of the last 100 ticks
    rps_setpoint: float
    loop: LoopStatus
    imu: dict[str, Any]
    link: dict[str, Any]
    points: PointsStatus
    recording: str | None  # the recording's path, while one runs
    aim_deg: Aim
    faults: list[FaultEntry]  # the newest daemon.status_faults (faults_list has the whole ring)
    fault_counts: dict[str, int]  # by kind since start (faults_clear keeps them)
    realtime: Realtime | None  # what the control thread asked the OS for and got (--realtime)
    rpc: dict[str, int]
    # The newest measurement's age: beyond daemon.stale_after_ms `stale` is true and rps is the
    # last value seen, not the shaft's speed now (a lost link; None before the first frame).
    measurement_age_ms: float | None = None
    stale: bool = False

    def to_json(self) -> dict[str, Any]:
        # Flat dataclasses by their __dict__, not dataclasses.asdict (a recursive deep copy: with
        # the faults' it made each status build ~2 ms of the event loop, now ~0.1 ms).
        return {
            "state": str(self.state),
            "rps": self.rps,
            "rps_setpoint": self.rps_setpoint,
            "loop": dict(vars(self.loop)),
            "imu": self.imu,
            "link": self.link,
            "points": self.points.to_json(),
            "recording": self.recording,
            "aim_deg": dict(vars(self.aim_deg)),
            "faults": [f.to_json() for f in self.faults],
            "fault_counts": self.fault_counts,
            "realtime": dict(vars(self.realtime)) if self.realtime is not None else None,
            "rpc": self.rpc,
            "measurement_age_ms": self.measurement_age_ms,
            "stale": self.stale,
        }

    def line(self) -> str:
        """One line for the foreground status print and systemd's STATUS=."""
        p99 = self.loop.jitter_p99_us
        p99 = p99 if math.isfinite(p99 or math.nan) else 0.0  # no tick yet
        stale = " STALE" if self.stale else ""
        stale += " HELD" if self.link.get("input_held") else ""  # PWM 0 for late input (not latched)
        return (
            f"{self.state:9s} {self.rps:6.2f} rev/s{stale}  jitter p99 {p99:6.1f} µs  "
            f"missed {self.loop.missed_ticks:4d}  points/s {self.points.per_s:5.1f}  "
            f"link {self.link['state']}  imu {self.imu['state']}  faults {len(self.faults)}"
        )
