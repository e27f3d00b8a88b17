"""The tvsd daemon: components built from config, started in two phases, stopped in order.

Phase 1 (synchronous, `Daemon.__init__`): the control thread (tvsd.control.runner, the robust law
in one 10 kHz kernel), the drive link (tvsd.daemon.drive_link: MCU on hardware or the SIL plant
behind a virtual MCU, in the SIL devices' own process: tvsd.sim.sil_devices), the IMU service
(tvsd.daemon.imu_service), the JSON-RPC server's method table (tvsd.daemon.api), the CAN bridge,
systemd notify.
Phase 2 (`Daemon.run`): the socket, the control thread, the drive link (required: a daemon that
cannot reach its MCU exits with a clear message, status 3), then the optional parts — IMU, CAN —
whose failure becomes a fault entry, not a dead daemon; then two asyncio tasks: `_drain` every
20 ms moves the control thread's ticks into the recording, `_heartbeat` every second checks the
faults, publishes status and pings the systemd watchdog (only while the control thread ticks).
Pulses from the MCU become points as they arrive (`_on_pulse`).

The class is built in layers, one concern per module, each on top of the one below
(tvsd.daemon.parts declares the shared components once): the recording in progress
(tvsd.daemon.recording_control), the fault policy (tvsd.daemon.fault_policy), the commands and
the status (tvsd.daemon.commands), the devices' events (tvsd.daemon.device_events); this module
builds, starts and stops them and runs the periodic tasks. Their state lives in its own parts: the
state and its transition table (tvsd.daemon.state), the fault log (tvsd.daemon.faults), the scan in
progress and the point counts (tvsd.daemon.scan_session), the recording (tvsd.daemon.session_recording),
the status (tvsd.daemon.status). The API (tvsd.daemon.api) checks each request and calls the
command methods; it never reaches into these parts.

Stop (SIGTERM, SIGINT, `shutdown`): speed reference to 0 along the ramp, wait for the shaft to
stop (bounded), PWM 0 and laser off, recorder closed, socket removed, control thread stopped.
"""

from __future__ import annotations

import asyncio
import gc
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tvsd.config import Config
from tvsd.control.realtime import not_realtime_warning
from tvsd.control.runner import Runner
from tvsd.control.setup import Setup
from tvsd.daemon.api import Api
from tvsd.daemon.device_events import DeviceEvents
from tvsd.daemon.drive_link import DriveLink
from tvsd.daemon.faults import FaultKind, FaultLog
from tvsd.daemon.identify import IdentifyRun
from tvsd.daemon.notify import Notifier
from tvsd.daemon.rpc import Limits, RpcServer
from tvsd.daemon.scan_session import PointCounters, ScanSession
from tvsd.daemon.session_recording import SessionRecording
from tvsd.daemon.state import DaemonState, StateMachine
from tvsd.errors import TvsdError
from tvsd.hw.can.bridge import CanBridge

S = DaemonState
# what the daemon publishes (rpc.publish): status, points (device_events), faults (fault_policy)
TOPICS = ("status", "points", "faults")


class Daemon(DeviceEvents):
    def __init__(
        self,
        cfg: Config,
        socket_path: Path,
        data_dir: Path,
        *,
        realtime: bool = False,
        out: Callable[[str], None] | None = None,
        config_text: str = "",
    ) -> None:
        self.cfg = cfg
        self.data_dir = data_dir
        self.out = out  # the foreground status line (make run); None under systemd
        self.config_text = config_text
        self.runner = Runner(
            Setup.from_config(cfg),
            sil=False,
            realtime=realtime,
            streak_limit=cfg.control.overrun_streak_ticks,
            excitation_rows=round(cfg.identify.max_seconds * cfg.identify.table_rate_hz),
        )
        self.drive = DriveLink(
            cfg,
            self.runner,
            cfg.devices.mcu,
            on_pulse=self._on_pulse,
            on_link=self._on_link,
            on_fault=self._on_mcu_fault,
            # runtime state beside the socket (/run/tvsd): what the link did to the kernel's tty
            # workers, undone by the next start if this daemon is killed (tvsd.hw.mcu.tty_worker_state)
            state_dir=socket_path.parent,
        )
        self.imu: Any = None  # tvsd.daemon.imu_service.ImuService once started
        self.sil: Any = None  # tvsd.sim.sil_devices.SilDevices while any device is sil
        if cfg.devices.imu != "off":  # import now: at start-up it would stall the link's heartbeats
            import tvsd.daemon.imu_service  # noqa: F401
        self.notifier = Notifier()
        self.api = Api(self)
        d = cfg.daemon
        limits = Limits(
            d.rpc_max_batch, d.rpc_max_reply_bytes, d.rpc_rate_per_s, d.rpc_burst,
            d.rpc_max_concurrent, d.rpc_max_clients, d.rpc_rate_total_per_s,
        )  # fmt: skip
        # the topics it publishes: `subscribe` to any other (a typo) is a -32602 naming them
        self.rpc = RpcServer(socket_path, self.api.methods(), limits=limits, topics=TOPICS)
        self.can = CanBridge(cfg.can, self.api.can_command)
        self._state = StateMachine(on_change=self._state_changed)
        self.target_rps = 0.0
        self.faults = FaultLog(cfg.daemon.fault_log_size)
        self.recording: SessionRecording | None = None
        self.scan: ScanSession | None = None  # while scanning
        self.scan_why: str | None = None
        self.aim_deg = (60.0, 0.0)  # φ, γ: DoE B's middle target
        self.points = PointCounters()
        self.identification: IdentifyRun | None = None  # the latest `identify` (tvsd/daemon/identify.py)
        self._stop = asyncio.Event()
        self.recording_started = asyncio.Event()  # wakes _drain
        self.web: Any = None  # tvsd.daemon.web.server.WebView when cfg.web.enabled
        if cfg.web.enabled:  # built now: aiohttp's import and the floor kernel's load hold the GIL
            from tvsd.daemon.web.server import WebView

            self.web = WebView(
                cfg.web,
                lambda: self.status().to_json(),
                data_dir,
                imu_rate_hz=cfg.imu.sample_rate_hz,
                control_period_s=1.0 / cfg.control.rate_hz,
            )

    async def run(self) -> None:
        await self.rpc.start()
        self.runner.start()
        tasks: list[asyncio.Task[None]] = []
        try:
            # The kernel loads from numba's cache holding the GIL: let that pass before the link's
            # heartbeats start, or the firmware's watchdog sees the pause.
            while not self.runner.is_running and self.runner.alive:
                await asyncio.sleep(0.01)
            rt = self.runner.realtime_report
            if rt is not None:  # asked for: say plainly what was granted and what was not
                print(
                    f"tvsd: control thread SCHED_FIFO {rt.sched_fifo}; affinity {rt.affinity}; "
                    f"memory lock {rt.mlockall}",
                    file=sys.stderr,
                )
                if rt.sched_fifo.startswith("refused"):  # asked, not granted: as without it
                    print(not_realtime_warning("with --realtime refused"), file=sys.stderr)
            # What is built by now lives as long as the daemon: out of the collector's sight. A
            # full collection over it held the GIL 45–71 ms (measured in SIL), stopping the link,
            # the IMU reader and the event loop past the 40 ms link timeout and 50 ms watchdog.
            gc.collect()
            gc.freeze()
            await self._start_sil()
            await self.drive.start(self.sil)
            await self._start_optional()
            tasks.append(asyncio.create_task(self._initial_aim()))
            tasks += [asyncio.create_task(self._drain()), asyncio.create_task(self._heartbeat())]
            if self.state == S.STARTING:  # a fault while the devices came up stays latched
                self._state.go(S.IDLE)
            gc.freeze()  # the devices' objects too (no collection now: the link is running)
            self.notifier.ready(status=str(self.state))
            await self._stop.wait()
        finally:
            await self._shutdown()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _start_sil(self) -> None:
        """The SIL devices' own process (the drive model behind the virtual MCU, the IMU twins),
        when any device is sil; its end while running is a fault."""
        devices = self.cfg.devices
        if "sil" not in (devices.mcu, devices.imu):
            return
        from tvsd.daemon.drive_link import spot_beta
        from tvsd.daemon.imu_service import STILL_RPS
        from tvsd.sim.sil_devices import SilDevices
        from tvsd.sim.sil_process import SilParams

        phi, gamma = (math.radians(v) for v in self.aim_deg)
        params = SilParams(self.cfg, spot_beta(self.cfg, phi, gamma), devices.mcu == "sil", STILL_RPS)
        self.sil = await SilDevices.start(params, realtime=self.runner.realtime)
        self.sil.watch(self._on_sil_exit)

    async def _start_optional(self) -> None:
        if self.cfg.devices.imu != "off":
            try:
                from tvsd.daemon.imu_service import ImuService

                imu = ImuService.for_daemon(self.cfg, self.cfg.devices.imu, self.sil)
                imu.on_state = self._on_imu_state
                imu.on_batch = self._on_imu_batch
                await imu.start()
                self.imu = imu
            except TvsdError as exc:
                self._fault(FaultKind.IMU, f"IMU: {exc}", "running without the IMU: points flagged no_imu")
        try:  # a CAN bus that is not there is a fault entry, not a dead daemon
            await self.can.start()
        except Exception as exc:
            self._fault(FaultKind.CAN, f"CAN bridge: {exc}", "running without the CAN bridge")
        if self.web is not None:
            try:
                await self.web.start()
            except TvsdError as exc:
                self.web = None
                self._fault(FaultKind.WEB, f"live view: {exc}", "running without the live view")

    async def _initial_aim(self) -> None:
        """Once the axes are homed, point the laser at the configured aim."""
        timeout = self.cfg.daemon.home_timeout_s
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                self.aim(*self.aim_deg)
                return
            except TvsdError:
                await asyncio.sleep(0.1)
        self._fault(
            FaultKind.HOMING,
            f"stepper axes not homed within {timeout:g} s (daemon.home_timeout_s)",
            "laser not aimed: check the home switches and the stepper drivers, then aim again",
        )

    def request_stop(self) -> None:
        self._stop.set()

    async def _shutdown(self) -> None:
        self._abort_identify("the daemon is stopping")
        self._state.go(S.STOPPING)
        self.notifier.stopping()
        # Ramp the aperture down along the speed reference, bounded by the time the ramp needs.
        if self.drive.link is not None and not self.runner.fault:
            self.runner.scan(0.0)
            d = self.cfg.daemon
            ramp_s = abs(self.measured_rps) / self.cfg.control.scan_accel_rps2 + d.stop_margin_s
            deadline = time.monotonic() + ramp_s
            while abs(self.measured_rps) > d.stopped_rps and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
        self.runner.idle()
        await self.drive.close()  # PWM 0 and laser off on the wire
        if self.imu is not None:
            await self.imu.stop()
        if self.sil is not None:  # after the link and the IMU reader let go of it
            await self.sil.aclose()
        await self.stop_recording()
        await self.can.close()
        if self.web is not None:
            await self.web.close()
        await self.rpc.close()
        self.runner.stop(timeout=2.0)

    async def _drain(self) -> None:
        while True:
            if self.recording is None:  # no timer to run 50 times a second for nothing
                self.recording_started.clear()
                await self.recording_started.wait()
            await asyncio.sleep(self.cfg.daemon.drain_period_s)
            if self.recording is not None:
                self.recording.drain(self.runner, self.drive)
                self._check_recording()

    async def _heartbeat(self) -> None:
        start = time.monotonic()
        last_ticks = -1
        while True:
            await asyncio.sleep(self.cfg.daemon.status_period_s)
            self._check_control_fault()
            status = self.status()
            record = status.to_json()
            self.rpc.publish("status", record)
            self.can.publish_status(record)
            self.notifier.status(status.line())
            if self.runner.ticks != last_ticks:  # the watchdog proves the control thread ticks
                self.notifier.watchdog()
                last_ticks = self.runner.ticks
            if self.out is not None:
                self.out(f"[{time.monotonic() - start:6.1f} s] {status.line()}")
