"""The tvsd daemon: components built from config, started in two phases, stopped in order.

Phase 1 (synchronous, `Daemon.__init__`): the control thread (tvsd.control.runner: the SIL plant
and the robust law in one 10 kHz kernel), the JSON-RPC server's method table, systemd notify.
Phase 2 (`Daemon.run`): the socket, the control thread, and two asyncio tasks — `_drain` every
0.1 s moves the control thread's recorded ticks into the recorder and, while scanning, through
the SIL pulse sensors into the point stream; `_heartbeat` every second checks faults, publishes
status and pings the systemd watchdog (only while the control thread ticks). An optional part
that fails to start becomes a fault entry, not a dead daemon.
Stop (SIGTERM, SIGINT, `shutdown`): speed reference to 0 along the ramp, wait for the shaft to
stop (bounded), laser off, recorder closed, socket removed, control thread stopped.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.config import Config, Gains
from tvsd.control import latency as L
from tvsd.control import runner as RN
from tvsd.control.conditions import check_gains, warnings
from tvsd.daemon.can_bridge import CanBridge
from tvsd.daemon.can_frames import Ack, Command, CommandCode, Reason
from tvsd.daemon.notify import Notifier
from tvsd.daemon.recorder import LOOP_CHANNEL, LOOP_FIELDS, Recorder
from tvsd.daemon.rpc import STATE_ERROR, RpcError, RpcServer
from tvsd.daemon.sil_pulses import PulseSensors
from tvsd.scan import geometry
from tvsd.scan.stream import PointStream
from tvsd.sim import runs

DRAIN_S = 0.02  # how often recorded ticks move on: bounds the pulse → point latency from above
RECORD_PERIOD_S = 1e-3  # 10 kHz ticks → a 1 kHz recording (DESIGN.md's sample_rate_hz)
SIL_TARGET_RANGE_M = 2.0  # the SIL scene's targets are 2 m from the PL (tvsd/sim/scene.py)
TIMER_TICK_S = 62.5e-9  # the firmware's input-capture tick (firmware/PROTOCOL.md)


def _sil_spot_beta(phi: float, gamma: float, range_m: float, a: float) -> float:
    """β of the spot the laser lights at φ, γ on a surface `range_m` from the PL (SIL scene)."""
    x = range_m * math.sin(phi)
    y = 0.5 * a - range_m * math.cos(phi)
    z = range_m * math.cos(phi) * math.tan(gamma)
    return float(geometry.inverse(x, y, z, a)[1])


@dataclass(frozen=True)
class Fault:
    t_unix: float
    cause: str
    action: str


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
        self.setup = runs.Setup.from_config(cfg)
        streak = max(1, round(cfg.control.overrun_streak_ms * 1e-3 * cfg.control.rate_hz))
        self.runner = RN.Runner(self.setup, sil=True, realtime=realtime, streak_limit=streak)
        self.notifier = Notifier()
        self.rpc = RpcServer(socket_path, self._methods())
        self.can = CanBridge(cfg.can, self._can_command)
        self.state = "idle"
        self.target_rps = 0.0
        self.faults: list[Fault] = []
        self.recorder: Recorder | None = None
        self.stream: PointStream | None = None
        self.sensors: PulseSensors | None = None
        self.aim_deg = (60.0, 0.0)  # φ, γ: DoE B's middle target
        self.points_total = 0
        self._points_window: deque[tuple[float, int]] = deque()
        self._latency: deque[float] = deque(maxlen=500)  # optical pulse → point published, s
        self._last_tick = 0
        self._carry: np.ndarray = np.zeros((0, RN.N_REC))  # ticks of the recording's open bin
        self._loop_channel: Any = None
        self._recorder_path: Path | None = None
        self._stop = asyncio.Event()

    # --- lifecycle ---------------------------------------------------------------------------------
    async def run(self) -> None:
        await self.rpc.start()
        self.runner.start()
        try:  # optional: a CAN bus that is not there is a fault entry, not a dead daemon
            await self.can.start()
        except Exception as exc:
            self._fault(f"CAN bridge: {exc}", "running without the CAN bridge")
        tasks = [asyncio.create_task(self._drain()), asyncio.create_task(self._heartbeat())]
        self.notifier.ready(status="idle")
        try:
            await self._stop.wait()
        finally:
            await self._shutdown()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    def request_stop(self) -> None:
        self._stop.set()

    async def _shutdown(self) -> None:
        self.state = "stopping"
        self.notifier.stopping()
        # Ramp the aperture down along the speed reference, bounded by the time the ramp needs.
        self.runner.scan(0.0)
        ramp_s = abs(self.measured_rps) / self.cfg.control.scan_accel_rps2 + 1.0
        deadline = time.monotonic() + ramp_s
        while abs(self.measured_rps) > 0.5 and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        self.runner.idle()  # PWM 0 (the laser has no output in SIL; on hardware: laser off here)
        await self._close_recorder()
        await self.can.close()
        await self.rpc.close()
        self.runner.stop(timeout=2.0)

    # --- periodic work -----------------------------------------------------------------------------
    async def _drain(self) -> None:
        while True:
            await asyncio.sleep(DRAIN_S)
            ticks = self.runner.ticks
            n = min(ticks - self._last_tick, self.runner.rec.shape[0])
            self._last_tick = ticks
            if n <= 0:
                continue
            rows = self.runner.recent(n)
            if self.recorder is not None:
                self._record(rows)
            if self.state == "scanning" and self.stream is not None and self.sensors is not None:
                self._scan(rows)

    def _record(self, rows: np.ndarray) -> None:
        """Average the ticks into RECORD_PERIOD_S bins of their own time stamps: the recording's
        time grid is uniform (DESIGN.md's CSV), whatever the wake-up jitter; a stall longer than
        a bin leaves a gap, which `tvsctl export` reports. The last, unfinished bin waits for the
        next drain."""
        assert self.recorder is not None
        rows = np.concatenate([self._carry, rows]) if len(self._carry) else rows
        bins = np.floor(rows[:, RN.R_T] / RECORD_PERIOD_S).astype(np.int64)
        done = bins < bins[-1]
        self._carry = rows[~done]
        if not np.any(done):
            return
        rows, bins = rows[done], bins[done]
        ids, start, count = np.unique(bins, return_index=True, return_counts=True)
        data = np.zeros(len(ids), dtype=np.dtype(list(LOOP_FIELDS)))
        data["t"] = (ids + 1) * RECORD_PERIOD_S
        data["u"] = np.add.reduceat(rows[:, RN.R_U], start) / count
        data["omega"] = np.add.reduceat(rows[:, RN.R_OMEGA], start) / count
        data["phi"] = rows[start + count - 1, RN.R_PHI]
        self._loop_channel.append(data)
        if self.recorder.error is not None:
            self._fault(f"recorder: {self.recorder.error}", "recording stopped")
            self.recorder = None

    def _scan(self, rows: np.ndarray) -> None:
        assert self.stream is not None and self.sensors is not None
        t0 = self.runner.ints[L.K_START_NS] / 1e9  # the loop's start on CLOCK_MONOTONIC
        for kind, ticks in self.sensors.feed(rows[:, RN.R_T], rows[:, RN.R_PHI]):
            for point in self.stream.add_pulse(kind, ticks):
                # The optical pulse's host time: a client on this machine gets the latency from
                # pulse to point as time.monotonic() − t_mono on receipt.
                point["t_mono"] = t0 + float(point["t"])
                self._latency.append(time.monotonic() - point["t_mono"])
                self.points_total += 1
                self.rpc.publish("points", point)
                self.can.publish_point(point)
        self._points_window.append((time.monotonic(), self.points_total))

    async def _heartbeat(self) -> None:
        start = time.monotonic()
        last_ticks = -1
        while True:
            await asyncio.sleep(1.0)
            if self.runner.fault and self.state != "fault":
                self.state = "fault"
                self._fault("control loop overran its deadline streak", "safe state: PWM 0")
            status = self.status_dict()
            self.rpc.publish("status", status)
            self.can.publish_status(status)
            self.notifier.status(self.status_line(status))
            if self.runner.ticks != last_ticks:  # the watchdog proves the control thread ticks
                self.notifier.watchdog()
                last_ticks = self.runner.ticks
            if self.out is not None:
                self.out(f"[{time.monotonic() - start:6.1f} s] {self.status_line(status)}")

    # --- state -------------------------------------------------------------------------------------
    @property
    def measured_rps(self) -> float:
        rows = self.runner.recent(100)
        return float(np.mean(rows[:, RN.R_OMEGA])) / (2 * math.pi) if len(rows) else 0.0

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
            "imu": {"source": "sil", "state": "ok"},
            "link": {"source": "sil", "state": "ok"},
            "points": {"total": self.points_total, "per_s": self.points_per_s(), **self._latency_ms()},
            "recording": str(self.recorder_path) if self.recorder is not None else None,
            "aim_deg": {"phi": self.aim_deg[0], "gamma": self.aim_deg[1]},
            "faults": [asdict(f) for f in self.faults],
            "rpc": self.rpc.stats,
        }

    @staticmethod
    def status_line(s: dict[str, Any]) -> str:
        if not math.isfinite(s["loop"]["jitter_p99_us"] or math.nan):
            s = {**s, "loop": {**s["loop"], "jitter_p99_us": 0.0}}  # no tick yet
        return (
            f"{s['state']:9s} {s['rps']:6.2f} rev/s  jitter p99 {s['loop']['jitter_p99_us']:6.1f} µs  "
            f"missed {s['loop']['missed_ticks']:4d}  points/s {s['points']['per_s']:5.1f}  "
            f"faults {len(s['faults'])}"
        )

    def _fault(self, cause: str, action: str) -> None:
        self.faults.append(Fault(time.time(), cause, action))
        self.rpc.publish("faults", asdict(self.faults[-1]))

    # --- API (JSON-RPC methods) ----------------------------------------------------------------------
    def _methods(self) -> dict[str, Any]:
        return {
            "status": self.api_status,
            "speed": self.api_speed,
            "scan_start": self.api_scan_start,
            "scan_stop": self.api_scan_stop,
            "aim": self.api_aim,
            "aim_xyz": self.api_aim_xyz,
            "gains_get": self.api_gains_get,
            "gains_set": self.api_gains_set,
            "record_start": self.api_record_start,
            "record_stop": self.api_record_stop,
            "faults_list": self.api_faults_list,
            "faults_clear": self.api_faults_clear,
            "shutdown": self.api_shutdown,
        }

    async def api_status(self) -> dict[str, Any]:
        return self.status_dict()

    def _refuse_in_fault(self) -> None:
        if self.state == "fault":
            raise RpcError(
                STATE_ERROR,
                "the drive is in its safe state after a fault; "
                "clear it with faults_clear (tvsctl faults --clear) first",
            )

    async def api_speed(self, rps: float) -> dict[str, Any]:
        self._refuse_in_fault()
        if not math.isfinite(rps) or abs(rps) > 60:
            raise RpcError(-32602, f"rps {rps:g} is outside ±60 rev/s (the drive holds 25 at 5.9 V of 12)")
        self.target_rps = rps
        self.runner.scan(rps)
        if self.state == "idle" and rps != 0:
            self.state = "spinning"
        return {"rps_setpoint": rps}

    async def api_scan_start(self) -> dict[str, Any]:
        self._refuse_in_fault()
        if abs(self.measured_rps) < 1.0:
            raise RpcError(STATE_ERROR, "the aperture is not spinning: set a speed first (tvsctl speed 25)")
        phi, gamma = (math.radians(v) for v in self.aim_deg)
        beta = _sil_spot_beta(phi, gamma, SIL_TARGET_RANGE_M, self.cfg.scan.baseline_m)
        self.sensors = PulseSensors(beta, TIMER_TICK_S)
        self.stream = PointStream(self.cfg.scan, phi, gamma, TIMER_TICK_S, compensate=False)
        self.state = "scanning"
        return {"state": self.state, "beta_deg": math.degrees(beta)}

    async def api_scan_stop(self) -> dict[str, Any]:
        if self.state == "scanning":
            self.state = "spinning"
        self.stream = self.sensors = None
        return {"state": self.state}

    async def api_aim(self, phi_deg: float, gamma_deg: float) -> dict[str, Any]:
        s = self.cfg.scan
        if not s.phi_min_deg <= phi_deg <= s.phi_max_deg or abs(gamma_deg) > s.gamma_max_deg:
            raise RpcError(
                -32602,
                f"φ = {phi_deg:g}°, γ = {gamma_deg:g}° is outside the axes: φ in "
                f"[{s.phi_min_deg:g}, {s.phi_max_deg:g}]°, |γ| ≤ {s.gamma_max_deg:g}°",
            )
        self.aim_deg = (phi_deg, gamma_deg)
        if self.state == "scanning":
            await self.api_scan_start()  # re-aim the running scan
        return {"phi_deg": phi_deg, "gamma_deg": gamma_deg}

    async def api_aim_xyz(self, x: float, y: float, z: float) -> dict[str, Any]:
        from tvsd.errors import UsageError

        try:
            a = geometry.aim(x, y, z, self.cfg.scan)
        except UsageError as exc:
            raise RpcError(-32602, str(exc)) from None
        return await self.api_aim(math.degrees(a.phi), math.degrees(a.gamma))

    async def api_gains_get(self) -> dict[str, Any]:
        g = self.runner.vals[RN.V_GP : RN.V_G0 + 1]
        return {"Gp": float(g[0]), "Gd": float(g[1]), "Gr": float(g[2]), "G0": float(g[3])}

    async def api_gains_set(self, Gp: float, Gd: float, Gr: float, G0: float) -> dict[str, Any]:
        if min(Gp, Gd, Gr) < 0 or G0 <= 0 or not all(math.isfinite(v) for v in (Gp, Gd, Gr, G0)):
            raise RpcError(-32602, "gains must be finite, Gp, Gd, Gr ≥ 0 and G0 > 0")
        gains = Gains(Gp=Gp, Gd=Gd, Gr=Gr, G0=G0)
        conds = check_gains(gains, self.cfg.plant, self.cfg.control.disturbance_bound_rad_s2)
        self.runner.vals[RN.V_GP : RN.V_G0 + 1] = gains.as_tuple()
        return {"gains": {"Gp": Gp, "Gd": Gd, "Gr": Gr, "G0": G0}, "warnings": warnings(conds)}

    @property
    def recorder_path(self) -> Path | None:
        return self._recorder_path

    async def api_record_start(self) -> dict[str, Any]:
        if self.recorder is not None:
            raise RpcError(STATE_ERROR, f"already recording into {self.recorder_path}")
        path = self.data_dir / time.strftime("rec-%Y%m%d-%H%M%S")
        try:
            self.recorder = Recorder(path, self.config_text)
        except OSError as exc:
            raise RpcError(-32001, f"cannot record into {path}: {exc}") from None
        self._recorder_path = path
        self._loop_channel = self.recorder.channel(LOOP_CHANNEL, list(LOOP_FIELDS))
        self._carry = np.zeros((0, RN.N_REC))
        self._last_tick = self.runner.ticks  # record from now on
        return {"recording": str(path)}

    async def api_record_stop(self) -> dict[str, Any]:
        path = self.recorder_path
        await self._close_recorder()
        return {"recorded": str(path) if path else None}

    async def _close_recorder(self) -> None:
        if self.recorder is not None:
            rec, self.recorder = self.recorder, None
            await asyncio.get_running_loop().run_in_executor(None, rec.close)  # fsync off the loop

    async def api_faults_list(self) -> list[dict[str, Any]]:
        return [asdict(f) for f in self.faults]

    async def api_faults_clear(self) -> dict[str, Any]:
        self.faults.clear()
        if self.runner.fault:
            self.runner.clear_fault()
        if self.state == "fault":
            self.state = "idle"
            self.runner.idle()
        return {"state": self.state}

    async def _can_command(self, cmd: Command) -> Ack:
        """A robot's command over CAN: the same methods as the API, a refusal as a refused ack."""
        try:
            if cmd.code == CommandCode.START:
                await self.api_scan_start()
            elif cmd.code == CommandCode.STOP:
                await self.api_scan_stop()
            elif cmd.code == CommandCode.SPEED and cmd.rps is not None:
                await self.api_speed(cmd.rps)
            elif cmd.code == CommandCode.AIM and cmd.phi_deg is not None and cmd.gamma_deg is not None:
                await self.api_aim(cmd.phi_deg, cmd.gamma_deg)
            else:
                return Ack.refused(Reason.REFUSED)
        except RpcError:
            return Ack.refused(Reason.REFUSED)
        return Ack.ok()

    async def api_shutdown(self) -> dict[str, Any]:
        asyncio.get_running_loop().call_later(0.05, self.request_stop)  # reply first
        return {"state": "stopping"}
