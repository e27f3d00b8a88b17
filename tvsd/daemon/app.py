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

Its parts: the state and its transition table (tvsd.daemon.state), the fault log
(tvsd.daemon.faults), the scan in progress and the point counts (tvsd.daemon.scan_session), the
recording in progress (tvsd.daemon.session_recording), the status (tvsd.daemon.status). The API
(tvsd.daemon.api) checks each request and calls the command methods below; it never reaches
into these parts.

Faults: each is listed with time, cause and what was done (`faults_list`), marked in the
recording with a full-rate window of the control ticks before it, and published.
- MCU link lost: the control thread holds PWM 0 once the newest state frame is older than
  mcu.link_timeout_ms (tvsd.control.runner FAULT_STALE); the fault names how long after the last
  frame that was. The firmware turns PWM and laser off on its own watchdog.
- IMU lost: status `imu.state` = lost/degraded, scanning continues, points flagged no_imu.
- Control loop overrun streak: safe state (PWM 0).
- SIL devices' process ended: safe state (its MCU link and IMU twins are gone).
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
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.config import Config, Gains
from tvsd.control.runner import LoopFault, Runner
from tvsd.control.setup import Setup
from tvsd.daemon.api import Api
from tvsd.daemon.drive_link import DriveLink
from tvsd.daemon.faults import LOOP_FAULTS, FaultEntry, FaultKind, FaultLog
from tvsd.daemon.identify import IdentifyRun
from tvsd.daemon.notify import Notifier
from tvsd.daemon.rpc import Limits, RpcServer
from tvsd.daemon.scan_session import PointCounters, ScanSession
from tvsd.daemon.session_recording import SessionRecording
from tvsd.daemon.state import DaemonState, StateMachine
from tvsd.daemon.status import Aim, LoopStatus, Status
from tvsd.errors import DeviceError, TvsdError
from tvsd.hw.can.bridge import CanBridge
from tvsd.hw.mcu.link import FaultEvent, PulseEvent
from tvsd.recording.writer import new_recording_dir
from tvsd.scan.points import Point
from tvsd.scan.pulses import OPTICAL

S = DaemonState


class Daemon:
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
        self.rpc = RpcServer(socket_path, self.api.methods(), limits=limits)
        self.can = CanBridge(cfg.can, self.api.can_command)
        self._state = StateMachine(on_change=self._state_changed)
        self.target_rps = 0.0
        self.faults = FaultLog(cfg.daemon.fault_log_size)
        self.recording: SessionRecording | None = None
        self.scan: ScanSession | None = None  # while scanning
        self.aim_deg = (60.0, 0.0)  # φ, γ: DoE B's middle target
        self.points = PointCounters()
        self.identification: IdentifyRun | None = None  # the latest `identify` (tvsd/daemon/identify.py)
        self._stop = asyncio.Event()
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

    @property
    def state(self) -> DaemonState:
        return self._state.state

    # --- lifecycle ---------------------------------------------------------------------------------
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

    def _on_sil_exit(self, why: str) -> None:
        cause = f"SIL devices' process ended ({why}): the virtual MCU and the IMU twins are gone"
        action = "safe state: PWM 0; restart tvsd --sil (its error is in the log)"
        if self.state not in (S.FAULT, S.STOPPING):
            self._enter_fault(FaultKind.MCU_LINK_LOST, cause, action)
        else:
            self._fault(FaultKind.MCU_LINK_LOST, cause, action)

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

    # --- commands (the API's and the CAN bridge's; each request checked by the API first) ----------
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

    # --- periodic work -----------------------------------------------------------------------------
    async def _drain(self) -> None:
        while True:
            await asyncio.sleep(self.cfg.daemon.drain_period_s)
            if self.recording is not None:
                self.recording.drain(self.runner)
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

    def _check_control_fault(self) -> None:
        code = self.runner.fault_code
        if code and self.state not in (S.FAULT, S.STOPPING):
            kind, cause, action = LOOP_FAULTS.get(
                code, (FaultKind.CONTROL, f"control thread fault {int(code)}", "safe state: PWM 0")
            )
            after = None
            if code == LoopFault.STALE:
                after = round(self.runner.fault_after_measurement_s * 1e3, 2)
                cause += f": none for {self.cfg.mcu.link_timeout_ms:g} ms"
                action += f" {after:.1f} ms after the last frame"
            self.runner.inject_overrun(0)  # an injected overrun ends with its fault
            self._enter_fault(kind, cause, action, after)

    # --- device events (event-loop thread) ---------------------------------------------------------
    def _on_pulse(self, ev: PulseEvent) -> None:
        if self.recording is not None:
            self.recording.pulse(ev.host_time, ev.mcu_ticks, ev.channel)
        if self.state != S.SCANNING or self.scan is None:
            return
        self._publish(self.scan.pulse(ev.channel, ev.mcu_ticks))
        if ev.channel == OPTICAL:
            self.points.optical_pulse()

    def _publish(self, points: list[Point]) -> None:
        for computed in points:
            # The optical pulse's host time: a client on this machine gets the latency from
            # pulse to point as time.monotonic() − t_mono on receipt.
            point = replace(computed, t_mono=self.drive.to_host(round(computed.t * self.drive.clock_hz)))
            self.points.published(point)
            if self.web is not None:
                self.web.point(point)
            record = point.to_json()
            self.rpc.publish("points", record)
            self.can.publish_point(record)
            if self.recording is not None:
                self.recording.point(point)

    def _on_link(self, up: bool) -> None:
        if up:
            self.mark("mcu_link", up=True)
            return
        self._check_control_fault()  # the control thread's stale check latched first (40 < 50 ms)
        cause = f"MCU link lost: no frame for {self.cfg.mcu.link_lost_ms:g} ms"
        if self.state not in (S.FAULT, S.STOPPING):
            self._enter_fault(FaultKind.MCU_LINK_LOST, cause, "safe state: PWM 0")
        else:
            self._fault(
                FaultKind.MCU_LINK_LOST,
                cause,
                "PWM 0 already held; the firmware turns PWM and laser off on its watchdog",
            )

    def _on_mcu_fault(self, ev: FaultEvent) -> None:
        if ev.name == "watchdog_expired":
            # The firmware has cut PWM and laser; the next heartbeat re-arms it and the PWM sent
            # with every state frame resumes: listed, not latched (a lost link latches its own).
            self._fault(
                FaultKind.MCU_WATCHDOG,
                f"MCU watchdog expired: no heartbeat for {ev.detail} ms (the control loop stopped "
                "ticking, or the link's I/O thread was held off the CPU or the GIL)",
                "the firmware cut PWM and laser until the next heartbeat; the drive resumed",
            )
            return
        self._fault(
            FaultKind.MCU_FAULT,
            f"MCU reports {ev.name} (detail {ev.detail})",
            "MCU outputs off; host holds PWM 0",
        )
        if self.state not in (S.FAULT, S.STOPPING, S.STARTING):
            self._enter_fault(FaultKind.MCU_FAULT, f"MCU fault {ev.name}", "safe state: PWM 0")

    def _on_imu_state(self, state: str, detail: str) -> None:
        self.mark("imu_state", state=state, detail=detail)
        if state in ("lost", "degraded"):
            self._fault(FaultKind.IMU, f"IMU {state}: {detail}", "scanning continues; points flagged no_imu")
        if self.state == S.SCANNING and self.scan is not None and self.scan.compensated != (state == "ok"):
            self._new_scan()  # compensated while the IMU is ok, flagged no_imu while it is not

    def _on_imu_batch(self, batch: Any) -> None:
        if self.web is not None:
            self.web.imu_batch(batch)
        if self.recording is not None:
            self.recording.imu_batch(batch.sensor, batch.k, batch.t, batch.accel, batch.gyro)
        if self.scan is not None and self.state == S.SCANNING:
            self._publish(self.scan.imu_batch(batch))

    # --- state and faults --------------------------------------------------------------------------
    def _state_changed(self, old: DaemonState, new: DaemonState) -> None:
        self.mark("state", state=str(new), was=str(old))

    def mark(self, event: str, **data: Any) -> None:
        if self.recording is not None:  # t_loop: on the control ticks' clock, placed by export
            t_loop = (time.monotonic_ns() - self.runner.start_ns) / 1e9
            self.recording.mark(event, t_loop=t_loop, **data)

    def _fault(
        self, kind: FaultKind, cause: str, action: str, safe_after_ms: float | None = None
    ) -> FaultEntry:
        entry = self.faults.add(kind, cause, action, safe_after_ms)
        record = entry.to_json()
        self.rpc.publish("faults", record)
        self.mark("fault", **record)
        return entry

    def _enter_fault(
        self, kind: FaultKind, cause: str, action: str, safe_after_ms: float | None = None
    ) -> None:
        """Safe state: the control thread commands 0 (and stays there until faults_clear)."""
        self.runner.idle()
        self._abort_identify(f"fault: {cause}")
        self.target_rps = 0.0
        self.scan = None
        self._state.go(S.FAULT)
        self._fault(kind, cause, action, safe_after_ms)
        if self.recording is not None:
            self.record_window(self.cfg.daemon.fault_window_s, cause)

    def start_identify(self, run: IdentifyRun) -> None:
        """Start an excitation run, once `run.check()` passes (one at a time)."""
        run.check()
        self.identification = run
        run.start()

    def _abort_identify(self, reason: str) -> None:
        if self.identification is not None:
            self.identification.abort(reason)

    def _new_scan(self) -> None:
        """A new scan session at the current aim: IMU-compensated while the IMU is ok (ImuFeed
        hands it the SA acceleration and the drive model's), else from the zero pulses alone
        (points flagged no_imu). A switch drops the pulses of the revolution in progress."""
        self.scan = ScanSession(
            self.cfg,
            self.aim_deg,
            self.drive.clock_hz,
            compensate=self.imu is not None and self.imu.healthy,
            to_mcu_s=self.drive.to_mcu_s,
            sent_volts=self.drive.sent_volts,
        )

    # --- status ------------------------------------------------------------------------------------
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
            points=self.points.status(),
            recording=str(self.recording.path) if self.recording is not None else None,
            aim_deg=Aim(phi=self.aim_deg[0], gamma=self.aim_deg[1]),
            faults=self.faults.entries()[-shown:] if shown else [],
            fault_counts=self.faults.counts(),
            realtime=self.runner.realtime_report,
            rpc=self.rpc.stats,
            measurement_age_ms=age_ms,
            stale=age_ms is None or age_ms > self.cfg.daemon.stale_after_ms,
        )

    # --- recording ---------------------------------------------------------------------------------
    def start_recording(self) -> Path:
        """A new recording in the data directory, of everything from now on (none may run)."""
        assert self.recording is None, "one recording at a time"
        try:  # a fresh directory made now (rec-…-2 within the same second), never one planted
            path = new_recording_dir(self.data_dir, time.strftime("rec-%Y%m%d-%H%M%S"))
            self.recording = SessionRecording(path, self.config_text, from_tick=self.runner.ticks)
        except OSError as exc:
            raise DeviceError(f"cannot record into {self.data_dir}: {exc}; check --data-dir") from None
        self.mark("state", state=str(self.state), was=None)
        return path

    def record_window(self, seconds: float, reason: str) -> int:
        """The last `seconds` of control ticks at full rate into the recording; how many."""
        assert self.recording is not None, "record_window needs a recording"
        rows = self.runner.recent_ticks(round(seconds * self.cfg.control.rate_hz))
        self.recording.window(rows, reason)
        return len(rows)

    def _check_recording(self) -> None:
        if self.recording is not None and self.recording.error is not None:
            err = self.recording.error
            self.recording = None
            self._fault(FaultKind.RECORDER, f"recorder: {err}", "recording stopped")

    async def stop_recording(self) -> Path | None:
        """Close the recording (fsync off the event loop); its path, or None if none ran."""
        if self.recording is None:
            return None
        rec, self.recording = self.recording, None
        await asyncio.get_running_loop().run_in_executor(None, rec.close)
        return rec.path
