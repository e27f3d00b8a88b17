"""What the parts of the daemon share: its components and state, declared (typed) once.

`Daemon` (tvsd.daemon.app) builds them in phase 1; each part of the class adds one concern on top
of the one below it, so a method is found by its concern and mypy checks the calls between them:
DaemonParts → RecordingControl (recording_control.py) → FaultPolicy (fault_policy.py) → Commands
(commands.py) → DeviceEvents (device_events.py) → Daemon (app.py: build, start, periodic tasks,
stop).
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from tvsd.config import Config
from tvsd.control.runner import Runner
from tvsd.daemon.drive_link import DriveLink
from tvsd.daemon.faults import FaultLog
from tvsd.daemon.identify import IdentifyRun
from tvsd.daemon.rpc import RpcServer
from tvsd.daemon.scan_session import PointCounters, ScanSession
from tvsd.daemon.session_recording import SessionRecording
from tvsd.daemon.state import DaemonState, StateMachine
from tvsd.hw.can.bridge import CanBridge


class DaemonParts:
    """The components and state every part of `Daemon` reads (assigned in Daemon.__init__)."""

    cfg: Config
    data_dir: Path
    config_text: str
    runner: Runner
    drive: DriveLink
    imu: Any  # tvsd.daemon.imu_service.ImuService once started
    sil: Any  # tvsd.sim.sil_devices.SilDevices while any device is sil
    rpc: RpcServer
    can: CanBridge
    web: Any  # tvsd.daemon.web.server.WebView when cfg.web.enabled
    faults: FaultLog
    recording: SessionRecording | None
    scan: ScanSession | None  # while scanning
    recording_started: asyncio.Event  # set when a recording starts (the drain task waits for it)
    scan_why: str | None  # why that scan's points are not IMU-compensated (None: they are)
    aim_deg: tuple[float, float]  # φ, γ
    points: PointCounters
    identification: IdentifyRun | None  # the latest `identify`
    target_rps: float
    _state: StateMachine

    @property
    def state(self) -> DaemonState:
        return self._state.state
