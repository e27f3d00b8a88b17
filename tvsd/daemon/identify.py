"""`identify`: a bounded excitation on top of spinning or scanning, recorded for the model doctor.

The daemon's recording of a closed loop holds the command, the measured angle and speed, and the
reference (φ_ref, ω_ref); the doctor uses the reference as an instrument. Plain scanning at a
constant speed gives it little to work with, so `identify` adds an excitation for a set time
(config `identify:`, tvsd/control/excitation.py): steps and a multisine on the speed reference, a
PRBS on the drive voltage. The control thread plays the table at its own tick times
(Runner.set_excitation); this module checks the request, starts a recording if none runs, writes
the planned excitation into it (channel `excitation`, on the loop's time axis; marks
`identify_start` / `identify_end`), and watches once per WATCH_PERIOD_S:
- any fault: the control thread has already dropped the excitation (it plays only without a
  fault); the run ends `aborted`, naming the fault (the daemon calls `abort` from its fault path);
- the daemon leaves spinning/scanning, the speed setpoint changes, or the measured speed strays
  more than identify.abort_error_rps from the reference: the excitation is cleared at once, `aborted`;
- the table runs out: `done`, after SETTLE_S more of recording (the response to the last rows).
A recording that identify started is closed at the end; one already running goes on.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tvsd.config import IdentifySettings
from tvsd.control.excitation import Excitation, build
from tvsd.daemon.rpc import INVALID_PARAMS, STATE_ERROR, RpcError
from tvsd.daemon.state import DaemonState
from tvsd.errors import UsageError

if TYPE_CHECKING:
    from tvsd.daemon.app import Daemon

S = DaemonState
WATCH_PERIOD_S = 0.05
SETTLE_S = 0.5
SETTLED_FRACTION = 0.5  # identify starts once |measured − setpoint| < this × abort_error_rps
EXCITATION_FIELDS = (("t", "<f8"), ("d_rps", "<f8"), ("d_volts", "<f8"))


def settings_for(base: IdentifySettings, **overrides: Any) -> IdentifySettings:
    """The config's settings with a request's overrides (None: keep), checked by the same rules."""
    given: dict[str, Any] = {
        k: (tuple(v) if isinstance(v, list) else v) for k, v in overrides.items() if v is not None
    }
    try:
        return dataclasses.replace(base, **given)
    except UsageError as exc:
        raise RpcError(
            INVALID_PARAMS, f"identify.{exc} (the config's identify: section has the same rules)"
        ) from None
    except TypeError as exc:  # a kinds list of non-strings
        raise RpcError(INVALID_PARAMS, f"identify: {exc}") from None


class IdentifyRun:
    """One excitation run, from `start` to done or aborted; `to_json` is its progress."""

    def __init__(self, d: Daemon, settings: IdentifySettings) -> None:
        self.d = d
        self.settings = settings
        try:
            self.excitation: Excitation = build(settings, d.target_rps, d.cfg.control.scan_accel_rps2)
        except UsageError as exc:  # a reversal that does not fit the run, or no speed to reverse
            raise RpcError(STATE_ERROR if d.target_rps == 0 else INVALID_PARAMS, str(exc)) from None
        self.state = "running"
        self.reason = ""
        self.own_recording = False
        self.recording: Path | None = None
        self.rps_setpoint = d.target_rps
        self.t0_ns = 0
        self.t0_loop_s = math.nan
        self.ended_mono = math.nan
        self.task: asyncio.Task[None] | None = None

    # --- start -------------------------------------------------------------------------------------
    def check(self) -> None:
        """Refuse (STATE_ERROR) unless the aperture spins, settled, with room for the excitation."""
        d, s = self.d, self.settings
        if d.identification is not None and not d.identification.finished:
            raise RpcError(STATE_ERROR, "identify is already running: wait, or tvsctl identify --abort")
        if d.state not in (S.SPINNING, S.SCANNING):
            raise RpcError(
                STATE_ERROR,
                f"identify runs on top of spinning or scanning; the daemon is {d.state}: "
                f"set a speed first (tvsctl speed 20)",
            )
        swing = s.speed_excitation_rps
        if abs(d.target_rps) - swing < s.min_rps:
            raise RpcError(
                STATE_ERROR,
                f"the speed setpoint is {d.target_rps:g} rev/s; with the excitation's ±{swing:g} the "
                f"aperture must keep ≥ {s.min_rps:g} rev/s (identify.min_rps): spin to at least "
                f"{s.min_rps + swing:g} rev/s",
            )
        if abs(d.target_rps) + swing > d.cfg.daemon.max_rps:
            raise RpcError(
                STATE_ERROR,
                f"{d.target_rps:g} rev/s plus the excitation's {swing:g} exceeds daemon.max_rps "
                f"({d.cfg.daemon.max_rps:g}): spin slower",
            )
        error = abs(d.measured_rps - d.target_rps)
        if error > SETTLED_FRACTION * s.abort_error_rps:
            raise RpcError(
                STATE_ERROR,
                f"the aperture turns at {d.measured_rps:.2f} rev/s, not yet at its setpoint "
                f"{d.target_rps:g}: wait until it settles (tvsctl status), then identify",
            )
        if len(self.excitation.d_rps) > d.runner.excitation_capacity_rows:
            raise RpcError(
                INVALID_PARAMS,
                f"seconds {s.seconds:g}: the control thread holds "
                f"{d.runner.excitation_capacity_rows * self.excitation.period_s:g} s (identify.max_seconds "
                "when the daemon started)",
            )

    def start(self) -> None:
        d, exc = self.d, self.excitation
        if d.recording is None:
            self.recording = d.start_recording()
            self.own_recording = True
        else:
            self.recording = d.recording.path
        sign = 1.0 if d.target_rps >= 0 else -1.0  # the excitation moves away from and back to the setpoint
        self.t0_ns = d.runner.set_excitation(sign * exc.d_rps, exc.d_volts, exc.period_s)
        self.t0_loop_s = (self.t0_ns - d.runner.start_ns) / 1e9
        assert d.recording is not None
        d.recording.excitation(self.t0_loop_s + exc.times(), sign * exc.d_rps, exc.d_volts)
        d.mark("identify_start", t0=self.t0_loop_s, rps_setpoint=d.target_rps, **exc.describe())
        self.task = asyncio.create_task(self._watch())

    # --- the run -----------------------------------------------------------------------------------
    @property
    def end_ns(self) -> int:
        return self.t0_ns + round(self.excitation.seconds * 1e9)

    def _trouble(self) -> str | None:
        d, s = self.d, self.settings
        if d.state not in (S.SPINNING, S.SCANNING):
            return f"the daemon left spinning/scanning (now {d.state})"
        if d.runner.fault:
            return f"control thread fault ({d.runner.fault_code.name})"
        if d.target_rps != self.rps_setpoint:
            return f"the speed setpoint changed ({self.rps_setpoint:g} → {d.target_rps:g} rev/s)"
        ticks = d.runner.recent_ticks(100)
        if len(ticks):
            ref = float(np.mean(ticks["omega_ref"])) / (2 * math.pi)
            seen = float(np.mean(ticks["omega"])) / (2 * math.pi)
            if abs(seen - ref) > s.abort_error_rps:
                return (
                    f"the speed strayed {abs(seen - ref):.2f} rev/s from its reference "
                    f"(identify.abort_error_rps {s.abort_error_rps:g})"
                )
        return None

    async def _watch(self) -> None:
        try:
            while self.state == "running":
                await asyncio.sleep(WATCH_PERIOD_S)
                if self.state != "running":
                    break
                # read before the trouble check: the kernel sets its fault, then ends the
                # excitation, so an excitation seen ended here has its fault visible below
                active = self.d.runner.excitation_active
                trouble = self._trouble()
                if trouble is not None:
                    self.abort(trouble)
                elif not active:
                    if time.monotonic_ns() >= self.end_ns - round(2 * self.excitation.period_s * 1e9):
                        self._end("done", "")
                    else:
                        self.abort("the control thread ended the excitation early (a mode change or fault)")
            await asyncio.sleep(SETTLE_S)  # the response to the last rows (or to the abort)
        finally:
            rec = self.d.recording
            if self.own_recording and rec is not None and rec.path == self.recording:
                await self.d.stop_recording()

    def abort(self, reason: str) -> None:
        """End the run now: the excitation off from the next tick on (idempotent)."""
        self.d.runner.clear_excitation()
        if self.state == "running":
            self._end("aborted", reason)

    def _end(self, state: str, reason: str) -> None:
        self.state, self.reason = state, reason
        self.ended_mono = time.monotonic()
        self.d.mark("identify_end", outcome=state, reason=reason)

    # --- progress ------------------------------------------------------------------------------------
    @property
    def finished(self) -> bool:
        """Over, and its recording closed (if it started one)."""
        return self.state != "running" and (self.task is None or self.task.done())

    def to_json(self) -> dict[str, Any]:
        elapsed = max(0.0, (time.monotonic_ns() - self.t0_ns) / 1e9) if self.t0_ns else 0.0
        total = self.excitation.seconds
        return {
            "state": self.state if self.finished or self.state == "running" else "finishing",
            "outcome": None if self.state == "running" else self.state,
            "reason": self.reason,
            "elapsed_s": min(elapsed, total),
            "seconds": total,
            "progress": min(1.0, elapsed / total) if total > 0 else 1.0,
            "recording": str(self.recording) if self.recording else None,
            "t0_s": self.t0_loop_s,
            "rps_setpoint": self.rps_setpoint,
            "excitation": self.excitation.describe(),
        }
