"""The tvsd daemon: components built from config, started in two phases, stopped in order.

Phase 1 (synchronous, `Daemon.__init__`): the control thread (tvsd.control.runner, the robust law
in one 10 kHz kernel), the drive link (tvsd.daemon.drive_link: MCU on hardware or the SIL plant
behind a virtual MCU), the IMU service (tvsd.daemon.imu_service), the JSON-RPC server's method
table (tvsd.daemon.api), the CAN bridge, systemd notify.
Phase 2 (`Daemon.run`): the socket, the control thread, the drive link (required: a daemon that
cannot reach its MCU exits with a clear message, status 3), then the optional parts — IMU, CAN —
whose failure becomes a fault entry, not a dead daemon; then two asyncio tasks: `_drain` every
20 ms moves the control thread's ticks into the recording, `_heartbeat` every second checks the
faults, publishes status and pings the systemd watchdog (only while the control thread ticks).
Pulses from the MCU become points as they arrive (`_on_pulse`).

Faults: each is listed with time, cause and what was done (`faults_list`), marked in the
recording with a full-rate window of the control ticks before it, and published.
- MCU link lost: the control thread holds PWM 0 once the newest state frame is older than
  mcu.link_timeout_ms (tvsd.control.runner FAULT_STALE); the fault names how long after the last
  frame that was. The firmware turns PWM and laser off on its own watchdog.
- IMU lost: status `imu.state` = lost/degraded, scanning continues, points flagged no_imu.
- Control loop overrun streak: safe state (PWM 0).
Stop (SIGTERM, SIGINT, `shutdown`): speed reference to 0 along the ramp, wait for the shaft to
stop (bounded), PWM 0 and laser off, recorder closed, socket removed, control thread stopped.
"""

from __future__ import annotations

import asyncio
import gc
import math
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.config import Config
from tvsd.control.runner import LoopFault, Runner
from tvsd.control.setup import Setup
from tvsd.daemon.api import Api
from tvsd.daemon.drive_link import HOME_TIMEOUT_S, DriveLink
from tvsd.daemon.imu_feed import ImuFeed
from tvsd.daemon.notify import Notifier
from tvsd.daemon.rpc import RpcError, RpcServer
from tvsd.daemon.session_recording import SessionRecording
from tvsd.errors import TvsdError
from tvsd.hw.can.bridge import CanBridge
from tvsd.hw.can.frames import Ack, Command, CommandCode, Reason
from tvsd.hw.mcu.link import FaultEvent, PulseEvent
from tvsd.hw.mpu6050 import DLPF_DELAY_S, SA_AXES
from tvsd.scan.compensation import DriveModel
from tvsd.scan.points import FLAG_NO_IMU, Point
from tvsd.scan.pulses import OPTICAL
from tvsd.scan.stream import PointStream

DRAIN_S = 0.02  # how often recorded ticks move on
FAULT_WINDOW_S = 2.0  # full-rate control ticks recorded before each fault
FAULT_CAUSES = {
    LoopFault.OVERRUN: ("control loop overran its deadline streak", "safe state: PWM 0"),
    LoopFault.STALE: ("MCU state frames stopped", "safe state: PWM 0 from the control thread"),
}


@dataclass(frozen=True)
class Fault:
    t_unix: float
    cause: str
    action: str
    safe_after_ms: float | None = None  # a link loss: PWM 0 this long after the last state frame


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
        if cfg.devices.imu != "off":  # import now: at start-up it would stall the link's heartbeats
            import tvsd.daemon.imu_service  # noqa: F401
        self.notifier = Notifier()
        self.api = Api(self)
        self.rpc = RpcServer(socket_path, self.api.methods())
        self.can = CanBridge(cfg.can, self._can_command)
        self.state = "starting"
        self.target_rps = 0.0
        self.faults: list[Fault] = []
        self.recording: SessionRecording | None = None
        self.stream: PointStream | None = None
        self.feed: ImuFeed | None = None  # the IMU's samples into a compensating stream
        self.aim_deg = (60.0, 0.0)  # φ, γ: DoE B's middle target
        self.points_total = 0
        self.points_no_imu = 0
        self._points_window: deque[tuple[float, int]] = deque()
        self._latency: deque[float] = deque(maxlen=500)  # optical pulse → point published, s
        self._last_tick = 0
        self._stop = asyncio.Event()

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
            await self.drive.start(*(math.radians(v) for v in self.aim_deg))
            await self._start_optional()
            tasks.append(asyncio.create_task(self._initial_aim()))
            tasks += [asyncio.create_task(self._drain()), asyncio.create_task(self._heartbeat())]
            self.set_state("idle")
            gc.freeze()  # the devices' objects too (no collection now: the link is running)
            self.notifier.ready(status="idle")
            await self._stop.wait()
        finally:
            await self._shutdown()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _start_optional(self) -> None:
        if self.cfg.devices.imu != "off":
            try:
                from tvsd.daemon.imu_service import ImuService

                imu = ImuService.for_daemon(self.cfg, self.cfg.devices.imu, self.drive.plant)
                imu.on_state = self._on_imu_state
                imu.on_batch = self._on_imu_batch
                await imu.start()
                self.imu = imu
            except TvsdError as exc:
                self._fault(f"IMU: {exc}", "running without the IMU: points flagged no_imu")
        try:  # a CAN bus that is not there is a fault entry, not a dead daemon
            await self.can.start()
        except Exception as exc:
            self._fault(f"CAN bridge: {exc}", "running without the CAN bridge")

    async def _initial_aim(self) -> None:
        """Once the axes are homed, point the laser at the configured aim."""
        deadline = time.monotonic() + HOME_TIMEOUT_S
        while time.monotonic() < deadline:
            try:
                await self.api.api_aim(*self.aim_deg)
                return
            except RpcError:
                await asyncio.sleep(0.1)
        self._fault(
            f"stepper axes not homed within {HOME_TIMEOUT_S:g} s",
            "laser not aimed: check the home switches and the stepper drivers, then aim again",
        )

    def request_stop(self) -> None:
        self._stop.set()

    async def _shutdown(self) -> None:
        self.set_state("stopping")
        self.notifier.stopping()
        # Ramp the aperture down along the speed reference, bounded by the time the ramp needs.
        if self.drive.link is not None and not self.runner.fault:
            self.runner.scan(0.0)
            ramp_s = abs(self.measured_rps) / self.cfg.control.scan_accel_rps2 + 1.0
            deadline = time.monotonic() + ramp_s
            while abs(self.measured_rps) > 0.5 and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
        self.runner.idle()
        await self.drive.close()  # PWM 0 and laser off on the wire
        if self.imu is not None:
            await self.imu.stop()
        await self.close_recording()
        await self.can.close()
        await self.rpc.close()
        self.runner.stop(timeout=2.0)

    # --- periodic work -----------------------------------------------------------------------------
    async def _drain(self) -> None:
        while True:
            await asyncio.sleep(DRAIN_S)
            ticks = self.runner.ticks
            n = min(ticks - self._last_tick, self.runner.ring_size)
            self._last_tick = ticks
            if n > 0 and self.recording is not None:
                self.recording.loop_ticks(self.runner.recent_ticks(n))
                self._check_recording()

    async def _heartbeat(self) -> None:
        start = time.monotonic()
        last_ticks = -1
        while True:
            await asyncio.sleep(1.0)
            self._check_control_fault()
            status = self.status_dict()
            self.rpc.publish("status", status)
            self.can.publish_status(status)
            self.notifier.status(self.status_line(status))
            if self.runner.ticks != last_ticks:  # the watchdog proves the control thread ticks
                self.notifier.watchdog()
                last_ticks = self.runner.ticks
            if self.out is not None:
                self.out(f"[{time.monotonic() - start:6.1f} s] {self.status_line(status)}")

    def _check_control_fault(self) -> None:
        code = self.runner.fault_code
        if code and self.state not in ("fault", "stopping"):
            cause, action = FAULT_CAUSES.get(code, (f"control thread fault {code}", "safe state: PWM 0"))
            after = None
            if code == LoopFault.STALE:
                after = round(self.runner.fault_after_measurement_s * 1e3, 2)
                cause += f": none for {self.cfg.mcu.link_timeout_ms:g} ms"
                action += f" {after:.1f} ms after the last frame"
            self.runner.inject_overrun(0)  # an injected overrun ends with its fault
            self._enter_fault(cause, action, after)

    # --- device events (event-loop thread) ---------------------------------------------------------
    def _on_pulse(self, ev: PulseEvent) -> None:
        if self.recording is not None:
            self.recording.pulse(ev.host_time, ev.mcu_ticks, ev.channel)
        if self.state != "scanning" or self.stream is None:
            return
        self._publish(self.stream.add_pulse(ev.channel, ev.mcu_ticks))
        if ev.channel == OPTICAL:
            self._points_window.append((time.monotonic(), self.points_total))

    def _publish(self, points: list[Point]) -> None:
        for computed in points:
            # The optical pulse's host time: a client on this machine gets the latency from
            # pulse to point as time.monotonic() − t_mono on receipt.
            point = replace(computed, t_mono=self.drive.to_host(round(computed.t * self.drive.clock_hz)))
            if point.flags & FLAG_NO_IMU:
                self.points_no_imu += 1
            if math.isfinite(point.t_mono):
                self._latency.append(time.monotonic() - point.t_mono)
            self.points_total += 1
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
        if self.state not in ("fault", "stopping"):
            self._enter_fault("MCU link lost: no frame for 50 ms", "safe state: PWM 0")
        else:
            self._fault(
                "MCU link lost: no frame for 50 ms",
                "PWM 0 already held; the firmware turns PWM and laser off on its watchdog",
            )

    def _on_mcu_fault(self, ev: FaultEvent) -> None:
        if ev.name == "watchdog_expired":
            # The firmware has cut PWM and laser; the next heartbeat re-arms it and the PWM sent
            # with every state frame resumes: listed, not latched (a lost link latches its own).
            self._fault(
                f"MCU watchdog expired: no heartbeat for {ev.detail} ms (the host's event loop stalled)",
                "the firmware cut PWM and laser until the next heartbeat; the drive resumed",
            )
            return
        self._fault(f"MCU reports {ev.name} (detail {ev.detail})", "MCU outputs off; host holds PWM 0")
        if self.state not in ("fault", "stopping", "starting"):
            self._enter_fault(f"MCU fault {ev.name}", "safe state: PWM 0")

    def _on_imu_state(self, state: str, detail: str) -> None:
        self.mark("imu_state", state=state, detail=detail)
        if state in ("lost", "degraded"):
            self._fault(f"IMU {state}: {detail}", "scanning continues; points flagged no_imu")
        if self.state == "scanning" and (self.feed is not None) != (state == "ok"):
            self.start_stream()  # compensated while the IMU is ok, flagged no_imu while it is not

    def _on_imu_batch(self, batch: Any) -> None:
        if self.recording is not None:
            self.recording.imu_batch(batch.sensor, batch.k, batch.t, batch.accel, batch.gyro)
        if self.feed is not None and self.state == "scanning":
            self._publish(self.feed.push(batch))

    # --- state -------------------------------------------------------------------------------------
    def set_state(self, state: str) -> None:
        if state != self.state:
            self.mark("state", state=state, was=self.state)
            self.state = state

    def mark(self, event: str, **data: Any) -> None:
        if self.recording is not None:
            self.recording.mark(event, **data)

    def _fault(self, cause: str, action: str, safe_after_ms: float | None = None) -> None:
        self.faults.append(Fault(time.time(), cause, action, safe_after_ms))
        self.rpc.publish("faults", asdict(self.faults[-1]))
        self.mark("fault", **asdict(self.faults[-1]))

    def _enter_fault(self, cause: str, action: str, safe_after_ms: float | None = None) -> None:
        """Safe state: the control thread commands 0 (and stays there until faults_clear)."""
        self.runner.idle()
        self.target_rps = 0.0
        self.stream = self.feed = None
        self.set_state("fault")
        self._fault(cause, action, safe_after_ms)
        if self.recording is not None:
            self.full_window(FAULT_WINDOW_S, cause)

    def start_stream(self) -> None:
        """A new point stream at the current aim: IMU-compensated while the IMU is ok (ImuFeed
        hands it the SA acceleration and the drive model's), else from the zero pulses alone
        (points flagged no_imu). A switch drops the pulses of the revolution in progress."""
        phi, gamma = (math.radians(v) for v in self.aim_deg)
        compensate = self.imu is not None and self.imu.healthy
        p = self.cfg.plant
        model = DriveModel.from_plant(p.kM, p.ku, p.R, p.J, p.kv + p.sigma2, p.kb, p.L)
        tick = 1.0 / self.drive.clock_hz
        self.stream = PointStream(
            self.cfg.scan, phi, gamma, tick, compensate=compensate, damping=model.damping
        )
        self.feed = None
        if compensate:
            imu = self.cfg.imu
            self.feed = ImuFeed(
                self.stream,
                self.drive.to_mcu_s,
                self.drive.sent_volts,
                model,
                rate_hz=self.cfg.scan.imu_rate_hz,
                axis=SA_AXES[imu.sa_axis],
                delay_s=DLPF_DELAY_S.get(imu.dlpf_cfg, 0.0),
            )

    @property
    def measured_rps(self) -> float:
        rows = self.runner.recent_ticks(100)
        return float(np.mean(rows["omega"])) / (2 * math.pi) if len(rows) else 0.0

    def _latency_ms(self) -> dict[str, float]:
        if not self._latency:
            return {}
        lat = np.asarray(self._latency) * 1e3
        return {"latency_p50_ms": float(np.median(lat)), "latency_max_ms": float(lat.max())}

    def points_per_s(self) -> float:
        w = self._points_window
        now = time.monotonic()
        while w and now - w[0][0] > 2.0:
            w.popleft()
        if len(w) < 2 or w[-1][0] == w[0][0]:
            return 0.0
        return (w[-1][1] - w[0][1]) / (w[-1][0] - w[0][0])

    def status_dict(self) -> dict[str, Any]:
        j = self.runner.stats()
        imu = self.imu.status() if self.imu is not None else {"source": self.cfg.devices.imu, "state": "off"}
        return {
            "state": self.state,
            "rps": self.measured_rps,
            "rps_setpoint": self.target_rps,
            "loop": {
                "rate_hz": j.rate_hz,
                "missed_ticks": j.missed_ticks,
                "jitter_p99_us": j.p99_us,
                "jitter_max_us": j.max_us,
                "ticks": j.ticks,
            },
            "imu": imu,
            "link": self.drive.status(),
            "points": {
                "total": self.points_total,
                "no_imu": self.points_no_imu,
                "per_s": self.points_per_s(),
                **self._latency_ms(),
            },
            "recording": str(self.recording.path) if self.recording is not None else None,
            "aim_deg": {"phi": self.aim_deg[0], "gamma": self.aim_deg[1]},
            "faults": [asdict(f) for f in self.faults],
            "realtime": asdict(self.runner.realtime_report) if self.runner.realtime_report else None,
            "rpc": self.rpc.stats,
        }

    @staticmethod
    def status_line(s: dict[str, Any]) -> str:
        if not math.isfinite(s["loop"]["jitter_p99_us"] or math.nan):
            s = {**s, "loop": {**s["loop"], "jitter_p99_us": 0.0}}  # no tick yet
        return (
            f"{s['state']:9s} {s['rps']:6.2f} rev/s  jitter p99 {s['loop']['jitter_p99_us']:6.1f} µs  "
            f"missed {s['loop']['missed_ticks']:4d}  points/s {s['points']['per_s']:5.1f}  "
            f"link {s['link']['state']}  imu {s['imu']['state']}  faults {len(s['faults'])}"
        )

    # --- recording ---------------------------------------------------------------------------------
    def open_recording(self, path: Path) -> None:
        self.recording = SessionRecording(path, self.config_text)
        self._last_tick = self.runner.ticks  # record from now on
        self.mark("state", state=self.state, was=None)

    def full_window(self, seconds: float, reason: str) -> int:
        assert self.recording is not None
        rows = self.runner.recent_ticks(round(seconds * self.cfg.control.rate_hz))
        self.recording.window(rows, reason)
        return len(rows)

    def _check_recording(self) -> None:
        if self.recording is not None and self.recording.error is not None:
            err = self.recording.error
            self.recording = None
            self._fault(f"recorder: {err}", "recording stopped")

    async def close_recording(self) -> None:
        if self.recording is not None:
            rec, self.recording = self.recording, None
            await asyncio.get_running_loop().run_in_executor(None, rec.close)  # fsync off the loop

    # --- CAN ---------------------------------------------------------------------------------------
    async def _can_command(self, cmd: Command) -> Ack:
        """A robot's command over CAN: the same methods as the API, a refusal as a refused ack."""
        try:
            if cmd.code == CommandCode.START:
                await self.api.api_scan_start()
            elif cmd.code == CommandCode.STOP:
                await self.api.api_scan_stop()
            elif cmd.code == CommandCode.SPEED and cmd.rps is not None:
                await self.api.api_speed(cmd.rps)
            elif cmd.code == CommandCode.AIM and cmd.phi_deg is not None and cmd.gamma_deg is not None:
                await self.api.api_aim(cmd.phi_deg, cmd.gamma_deg)
            else:
                return Ack.refused(Reason.REFUSED)
        except RpcError:
            return Ack.refused(Reason.REFUSED)
        return Ack.ok()
