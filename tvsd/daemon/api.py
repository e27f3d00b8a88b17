"""The daemon's JSON-RPC methods: check the request, act through the daemon, say what happened.

Each refusal is an RpcError with what was asked, why not, and what to do; the daemon stays up.
The methods read the daemon's state and call its command methods (tvsd.daemon.app); they never
change its parts themselves. Results become JSON here, at the edge.
Methods (docs/architecture.md, "Daemon API"): status, speed, scan_start, scan_stop, aim, aim_xyz, gains_get,
gains_set, imu_calibrate, record_start, record_stop, record_window, faults_list, faults_clear,
inject_fault (SIL devices only), identify, identify_status, identify_abort, shutdown. The point
stream and status are subscriptions (tvsd/daemon/rpc: `subscribe`).
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from tvsd.config import Gains
from tvsd.control.conditions import check_gains, warnings
from tvsd.daemon.identify import IdentifyRun, settings_for
from tvsd.daemon.rpc import DEVICE_ERROR, INVALID_PARAMS, STATE_ERROR, Encoded, RpcError
from tvsd.daemon.state import DaemonState
from tvsd.errors import TvsdError, UsageError
from tvsd.hw.can.frames import Ack, Command, CommandCode, Reason
from tvsd.hw.imu_calibration import CalibrationRefused
from tvsd.scan import geometry

if TYPE_CHECKING:
    from tvsd.daemon.app import Daemon

STATUS_REUSE_S = 0.02  # a status younger than this is answered again (its age is in it)
# A command that comes while the devices are still coming up (`tvsd --sil &` then `tvsctl speed 25`
# at once) waits for them this long, then is answered as the state is: under tvsctl's 5 s call
# timeout, so the user gets the daemon's answer, not a client time-out. Polled at STARTING_POLL_S.
STARTING_WAIT_S = 4.0
STARTING_POLL_S = 0.02


def _rpc_error(exc: TvsdError) -> RpcError:
    return RpcError(INVALID_PARAMS if isinstance(exc, UsageError) else DEVICE_ERROR, str(exc))


class Api:
    def __init__(self, daemon: Daemon) -> None:
        self.d = daemon
        self._status: tuple[float, Encoded] | None = None  # (monotonic, the status) reused

    def methods(self) -> dict[str, Any]:
        return {
            name.removeprefix("api_"): getattr(self, name) for name in dir(self) if name.startswith("api_")
        }

    async def _refuse_in_fault(self) -> None:
        """Refuse a command the state does not allow; while the devices are still coming up, wait
        for them first (at most STARTING_WAIT_S), so a command typed right after the daemon's
        start is carried out, not refused."""
        deadline = time.monotonic() + STARTING_WAIT_S
        while self.d.state == DaemonState.STARTING and time.monotonic() < deadline:
            await asyncio.sleep(STARTING_POLL_S)
        if self.d.state == DaemonState.STARTING:
            raise RpcError(
                STATE_ERROR,
                f"the devices are still coming up after {STARTING_WAIT_S:g} s (MCU link, IMU): "
                "see `tvsctl status` and the daemon's log, then retry",
            )
        if self.d.state == DaemonState.FAULT:
            raise RpcError(
                STATE_ERROR,
                "the drive is in its safe state after a fault; "
                "clear it with faults_clear (tvsctl faults --clear) first",
            )
        if self.d.state == DaemonState.STOPPING:
            raise RpcError(STATE_ERROR, "the daemon is stopping: the aperture ramps down; start it again")

    async def api_status(self) -> Encoded:
        # Built at most once per STATUS_REUSE_S: 50 clients (or a batch of 50) asking at once
        # cost one build (~1-4 ms), not 50; `measurement_age_ms` and `stale` say how fresh it is.
        # Checked and encoded once per build too (Encoded): each reply splices the text in.
        now = time.monotonic()
        if self._status is None or now - self._status[0] > STATUS_REUSE_S:
            self._status = (now, Encoded(self.d.status().to_json()))
        return self._status[1]

    async def api_speed(self, rps: float) -> dict[str, Any]:
        # The parameter first, the state second: a bad request gets the same answer in every state.
        max_rps = self.d.cfg.daemon.max_rps
        if not math.isfinite(rps) or abs(rps) > max_rps:
            raise RpcError(
                INVALID_PARAMS,
                f"rps {rps:g} is outside ±{max_rps:g} rev/s (daemon.max_rps; the drive holds 25 at "
                "5.9 V of 12)",
            )
        await self._refuse_in_fault()
        self.d.set_speed(rps)
        return {"rps_setpoint": rps}

    async def api_scan_start(self) -> dict[str, Any]:
        await self._refuse_in_fault()
        if abs(self.d.measured_rps) < 1.0:
            raise RpcError(STATE_ERROR, "the aperture is not spinning: set a speed first (tvsctl speed 25)")
        try:
            self.d.start_scan()
        except TvsdError as exc:
            raise _rpc_error(exc) from None
        return {"state": str(self.d.state)}

    async def api_scan_stop(self) -> dict[str, Any]:
        try:
            self.d.stop_scan()
        except TvsdError as exc:
            raise _rpc_error(exc) from None
        return {"state": str(self.d.state)}

    async def api_aim(self, phi_deg: float, gamma_deg: float) -> dict[str, Any]:
        s = self.d.cfg.scan
        if not (math.isfinite(phi_deg) and math.isfinite(gamma_deg)) or not (
            s.phi_min_deg <= phi_deg <= s.phi_max_deg and abs(gamma_deg) <= s.gamma_max_deg
        ):
            raise RpcError(
                INVALID_PARAMS,
                f"φ = {phi_deg:g}°, γ = {gamma_deg:g}° is outside the axes: φ in "
                f"[{s.phi_min_deg:g}, {s.phi_max_deg:g}]°, |γ| ≤ {s.gamma_max_deg:g}°",
            )
        try:
            self.d.aim(phi_deg, gamma_deg)  # a running scan goes on at the new angles
        except TvsdError as exc:
            raise _rpc_error(exc) from None
        return {"phi_deg": phi_deg, "gamma_deg": gamma_deg}

    async def api_aim_xyz(self, x: float, y: float, z: float) -> dict[str, Any]:
        try:
            a = geometry.aim(x, y, z, self.d.cfg.scan)
        except UsageError as exc:
            raise RpcError(INVALID_PARAMS, str(exc)) from None
        return await self.api_aim(math.degrees(a.phi), math.degrees(a.gamma))

    async def api_gains_get(self) -> dict[str, Any]:
        return asdict(self.d.runner.gains())  # what the control thread runs with

    async def api_gains_set(self, Gp: float, Gd: float, Gr: float, G0: float) -> dict[str, Any]:
        try:
            gains = Gains(Gp=Gp, Gd=Gd, Gr=Gr, G0=G0)
        except UsageError as exc:
            raise RpcError(
                INVALID_PARAMS, f"gains: {exc} (control.gains in the config has the same rules)"
            ) from None
        conds = check_gains(gains, self.d.cfg.plant, self.d.cfg.control.disturbance_bound_rad_s2)
        self.d.set_gains(gains)
        return {"gains": asdict(gains), "warnings": warnings(conds)}

    async def api_imu_calibrate(self, seconds: float = 5.0) -> dict[str, Any]:
        # The parameter first, the state second (as api_speed): a bad request gets the same answer
        # with no IMU or a turning aperture as at rest.
        longest = self.d.cfg.imu.calibrate_max_s
        if not 1 <= seconds <= longest:
            raise RpcError(INVALID_PARAMS, f"seconds {seconds:g}: use 1 .. {longest:g} (imu.calibrate_max_s)")
        if self.d.imu is None:
            raise RpcError(
                STATE_ERROR, "no IMU is running (devices.imu is off or it failed to start: see faults)"
            )
        if abs(self.d.measured_rps) > 0.05:
            raise RpcError(
                STATE_ERROR, "the aperture is turning: stop it (tvsctl speed 0) to calibrate at rest"
            )
        try:
            result: dict[str, Any] = await self.d.imu.calibrate(seconds)
        except CalibrationRefused as exc:  # the sensor moved: a result (exit 1), not a broken device
            raise RpcError(STATE_ERROR, str(exc)) from None
        except TvsdError as exc:
            raise _rpc_error(exc) from None
        self.d.mark("imu_calibrated", file=str(result.get("file")))
        return result

    async def api_record_start(self) -> dict[str, Any]:
        if self.d.recording is not None:
            raise RpcError(STATE_ERROR, f"already recording into {self.d.recording.path}")
        try:
            path = self.d.start_recording()
        except TvsdError as exc:
            raise _rpc_error(exc) from None
        return {"recording": str(path)}

    async def api_record_stop(self) -> dict[str, Any]:
        path = await self.d.stop_recording()
        return {"recorded": str(path) if path else None}

    async def api_record_window(self, seconds: float = 1.0) -> dict[str, Any]:
        kept = math.floor(self.d.runner.ring_size / self.d.cfg.control.rate_hz)  # 6 s at 10 kHz
        if not 0 < seconds <= kept:
            raise RpcError(INVALID_PARAMS, f"seconds {seconds:g}: the control thread keeps 0 .. {kept:g} s")
        if self.d.recording is None:
            raise RpcError(STATE_ERROR, "not recording: start a recording first (tvsctl record start)")
        ticks = self.d.record_window(seconds, "request")
        return {"ticks": ticks, "recording": str(self.d.recording.path)}

    async def api_faults_list(self) -> list[dict[str, Any]]:
        return [f.to_json() for f in self.d.faults.entries()]

    async def api_faults_clear(self) -> dict[str, Any]:
        self.d.clear_faults()
        return {"state": str(self.d.state)}

    async def api_inject_fault(self, device: str, fault: str) -> dict[str, Any]:
        """Fault injection for tests and demos. SIL devices only: `mcu` link_loss / link_restore,
        `imu` loss / restore; any backend: `control` overrun (every tick burns 3 periods until
        the overrun streak latches the safe state)."""
        try:
            if device == "control":
                if fault != "overrun":
                    raise UsageError(f"unknown control fault {fault!r}: use overrun")
                self.d.inject_overrun()
                return {"device": device, "fault": fault, "t_mono": time.monotonic()}
            if device == "mcu":
                return self.d.drive.inject(fault)
            if device == "imu":
                if self.d.imu is None:
                    raise UsageError("no IMU is running")
                self.d.imu.inject(fault)
                return {"device": device, "fault": fault, "t_mono": time.monotonic()}
        except TvsdError as exc:
            raise _rpc_error(exc) from None
        raise RpcError(INVALID_PARAMS, f"device {device!r}: use mcu, imu or control")

    async def api_identify(
        self, seconds: float | None = None, kinds: list[str] | None = None, seed: int | None = None
    ) -> dict[str, Any]:
        """A bounded excitation on top of spinning/scanning, recorded (tvsd/daemon/identify.py);
        amplitudes and limits from the config's identify: section. Returns at once: poll
        identify_status."""
        settings = settings_for(self.d.cfg.identify, seconds=seconds, kinds=kinds, seed=seed)
        await self._refuse_in_fault()
        run = IdentifyRun(self.d, settings)
        self.d.start_identify(run)
        return run.to_json()

    async def api_identify_status(self) -> dict[str, Any]:
        run = self.d.identification
        return run.to_json() if run is not None else {"state": "none", "outcome": None}

    async def api_identify_abort(self) -> dict[str, Any]:
        run = self.d.identification
        if run is None or run.state != "running":
            raise RpcError(STATE_ERROR, "no identify is running")
        run.abort("aborted by request")
        return run.to_json()

    async def api_shutdown(self) -> dict[str, Any]:
        asyncio.get_running_loop().call_later(0.05, self.d.request_stop)  # reply first
        return {"state": str(DaemonState.STOPPING)}

    async def can_command(self, cmd: Command) -> Ack:
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
