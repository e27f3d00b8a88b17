"""The daemon's fault policy: what each fault does, listed, published and marked.

Each fault is listed with time, cause and what was done (`faults_list`), marked in the recording
with a full-rate window of the control ticks before it, and published.
- MCU link lost: the control thread holds PWM 0 once the newest state frame is older than
  mcu.link_timeout_ms, and latches it (LoopFault.STALE) when none reaches the present within
  mcu.link_lost_ms, or when those that come show a gap (LoopFault.GAP); the fault names how long
  after the last frame PWM 0 began. The firmware turns PWM and laser off on its own watchdog.
- Late input (the frames came late but complete: the host's tty input was delayed, not the MCU):
  listed, not latched (control resumed; counted in the status's link.late_input_*).
- MCU watchdog expired: listed, not latched (the next heartbeat re-arms it).
- Control loop overrun streak: safe state (PWM 0).
- SIL devices' process ended: safe state (its MCU link and IMU twins are gone).
- The recorder failed: the recording stops.
The IMU's faults come with its events (tvsd.daemon.device_events).
"""

from __future__ import annotations

import asyncio
import contextlib

from tvsd.control.runner import LoopFault
from tvsd.daemon.faults import LOOP_FAULTS, FaultEntry, FaultKind
from tvsd.daemon.recording_control import RecordingControl
from tvsd.daemon.state import DaemonState
from tvsd.hw.mcu.events import FaultEvent

S = DaemonState
HOLD_LATCH_LOOK_S = 0.02  # after the link's loss, when to look for the control thread's latch


class FaultPolicy(RecordingControl):
    """Faults listed (`_fault`) or latched into the safe state (`_enter_fault`), by source."""

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

    def _abort_identify(self, reason: str) -> None:
        if self.identification is not None:
            self.identification.abort(reason)

    _holds_listed = 0  # the control thread's late-input holds already listed

    def _check_late_input(self) -> None:
        """The holds that ended in a resume since the last look: one entry for them all."""
        holds = self.runner.holds()
        new = holds.resumed - self._holds_listed
        if new <= 0:
            return
        self._holds_listed = holds.resumed
        self._fault(
            FaultKind.MCU_LATE_INPUT,
            f"MCU state frames late: {new} hold(s) of PWM 0 from {self.cfg.mcu.link_timeout_ms:g} ms "
            f"without a frame (the longest hold since start lasted {holds.longest_s * 1e3:.1f} ms); "
            "the MCU sent every frame on time "
            "(no gap in its stamps): the host's serial input was delayed",
            "not latched: control resumed from the measurement (status link.late_input_holds)",
        )

    def _check_control_fault(self) -> None:
        self._check_late_input()
        code = self.runner.fault_code
        if code and self.state not in (S.FAULT, S.STOPPING):
            kind, cause, action = LOOP_FAULTS.get(
                code, (FaultKind.CONTROL, f"control thread fault {int(code)}", "safe state: PWM 0")
            )
            after = None
            if code in (LoopFault.STALE, LoopFault.GAP):
                m = self.cfg.mcu
                after = round(self.runner.fault_after_measurement_s * 1e3, 2)
                if code == LoopFault.STALE:
                    cause += f": none for {m.link_lost_ms if m.late_input_hold else m.link_timeout_ms:g} ms"
                action += f" {after:.1f} ms after the last frame"
            self.runner.inject_overrun(0)  # an injected overrun ends with its fault
            self._enter_fault(kind, cause, action, after)

    def _check_recording(self) -> None:
        if self.recording is not None and self.recording.error is not None:
            err = self.recording.error
            self.recording = None
            self._fault(FaultKind.RECORDER, f"recorder: {err}", "recording stopped")

    def _on_link(self, up: bool) -> None:
        if up:
            self.mark("mcu_link", up=True)
            return
        self._check_control_fault()  # the control thread's stale check holds PWM 0 since 40 ms
        cause = f"MCU link lost: no frame for {self.cfg.mcu.link_lost_ms:g} ms"
        if self.runner.held and self.state not in (S.FAULT, S.STOPPING):
            # The control thread latches its hold at this same bound (tvsd.control.hold), a tick
            # from now if not yet: its verdict (mcu_stale, with when PWM 0 began) is the fault.
            self._fault(
                FaultKind.MCU_LINK_LOST, cause, "PWM 0 held by the control thread, which latches it"
            )
            with contextlib.suppress(RuntimeError):  # no loop: the next status period looks
                asyncio.get_running_loop().call_later(HOLD_LATCH_LOOK_S, self._check_control_fault)
            return
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

    def _on_sil_exit(self, why: str) -> None:
        cause = f"SIL devices' process ended ({why}): the virtual MCU and the IMU twins are gone"
        action = "safe state: PWM 0; restart tvsd --sil (its error is in the log)"
        if self.state not in (S.FAULT, S.STOPPING):
            self._enter_fault(FaultKind.MCU_LINK_LOST, cause, action)
        else:
            self._fault(FaultKind.MCU_LINK_LOST, cause, action)
