"""The daemon's commands (the API's and the CAN bridge's) and the status they read.

Each request is checked by the API (tvsd.daemon.api) before it calls these; a command that does
not fit the state is refused by the state machine (tvsd.daemon.state), naming both states.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, replace

import numpy as np

from tvsd.config import Gains
from tvsd.daemon.fault_policy import FaultPolicy
from tvsd.daemon.identify import IdentifyRun
from tvsd.daemon.scan_session import ScanSession
from tvsd.daemon.state import DaemonState
from tvsd.daemon.status import Aim, LoopStatus, PointsStatus, Status

S = DaemonState


class Commands(FaultPolicy):
    """What the API and the CAN bridge call, and the status they read."""

    def set_speed(self, rps: float) -> None:
        """The aperture's speed reference, reached along the ramp."""
        self.target_rps = rps
        self.runner.scan(rps)
        if self.state == S.IDLE and rps != 0:
            self._state.go(S.SPINNING)

    def start_scan(self) -> None:
        """Laser on, a point stream at the current aim."""
        if not self._state.can(S.SCANNING):
            self._state.go(S.SCANNING)  # refused, naming both states: before the laser goes on
        self.drive.laser(True)
        self._new_scan()
        self._state.go(S.SCANNING)

    def stop_scan(self) -> None:
        """No more points; laser off."""
        if self.state == S.SCANNING:
            self._state.go(S.SPINNING)
        self.scan = None
        self.drive.laser(False)

    def aim(self, phi_deg: float, gamma_deg: float) -> None:
        """Move the PL axes; a running scan goes on at the new angles."""
        self.drive.aim(math.radians(phi_deg), math.radians(gamma_deg))
        self.aim_deg = (phi_deg, gamma_deg)
        if self.state == S.SCANNING:
            self._new_scan()

    def set_gains(self, gains: Gains) -> None:
        self.runner.set_gains(gains)
        self.mark("gains", **asdict(gains))

    def clear_faults(self) -> None:
        """Forget the listed faults; out of the safe state, the drive idle."""
        self.faults.clear()
        self.runner.clear_fault()
        if self.state == S.FAULT:
            self.runner.idle()
            self.target_rps = 0.0
            self._state.go(S.IDLE)

    def inject_overrun(self) -> None:
        """Fault injection: every tick burns 3 periods until the overrun streak latches."""
        self.runner.inject_overrun(periods=3.0)

    def start_identify(self, run: IdentifyRun) -> None:
        """Start an excitation run, once `run.check()` passes (one at a time)."""
        run.check()
        self.identification = run
        run.start()

    def _uncompensated_why(self) -> str | None:
        """Why points cannot be IMU-compensated now (None: they can). Compensation needs the IMU
        ok and the MCU clock sync ready: without the host → MCU map the SA samples cannot be
        placed against the pulses, and a compensated stream would wait for them for ever (on a
        loaded machine the sync takes tens of heartbeats: README "Point stream")."""
        if self.imu is None or not self.imu.healthy:
            return f"IMU {self.imu.state if self.imu is not None else 'off'}"
        if not math.isfinite(self.drive.to_mcu_s(time.monotonic())):
            return "MCU clock sync not ready (heartbeat round trips)"
        return None

    def _new_scan(self) -> None:
        """A new scan session at the current aim: IMU-compensated while it can be (ImuFeed
        hands it the SA acceleration and the drive model's), else from the zero pulses alone
        (points flagged no_imu). A switch drops the pulses of the revolution in progress."""
        why = self._uncompensated_why()
        self.scan = ScanSession(
            self.cfg,
            self.aim_deg,
            self.drive.clock_hz,
            compensate=why is None,
            to_mcu_s=self.drive.to_mcu_s,
            sent_volts=self.drive.sent_volts,
        )
        self.scan_why = why

    def _follow_compensation(self) -> None:
        """While scanning: a new session when compensation became possible or impossible."""
        if self.scan is not None and self.state == S.SCANNING:
            why = self._uncompensated_why()
            if self.scan.compensated != (why is None):
                self._new_scan()

    def _points_status(self) -> PointsStatus:
        st = self.points.status()
        if self.scan is None:
            return st
        return replace(st, compensated=self.scan.compensated, uncompensated_why=self.scan_why)

    @property
    def measured_rps(self) -> float:
        rows = self.runner.recent_ticks(100)
        return float(np.mean(rows["omega"])) / (2 * math.pi) if len(rows) else 0.0

    def status(self) -> Status:
        imu = self.imu.status() if self.imu is not None else {"source": self.cfg.devices.imu, "state": "off"}
        age = self.runner.measurement_age_s
        age_ms = None if age is None else round(age * 1e3, 1)
        shown = self.cfg.daemon.status_faults
        return Status(
            state=self.state,
            rps=self.measured_rps,
            rps_setpoint=self.target_rps,
            loop=LoopStatus.of(self.runner.stats()),
            imu=imu,
            link=self.drive.status(),
            points=self._points_status(),
            recording=str(self.recording.path) if self.recording is not None else None,
            aim_deg=Aim(phi=self.aim_deg[0], gamma=self.aim_deg[1]),
            faults=self.faults.entries()[-shown:] if shown else [],
            fault_counts=self.faults.counts(),
            realtime=self.runner.realtime_report,
            rpc=self.rpc.stats,
            measurement_age_ms=age_ms,
            stale=age_ms is None or age_ms > self.cfg.daemon.stale_after_ms,
        )
