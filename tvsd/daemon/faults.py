"""The daemon's fault log: what went wrong, when, and what was done about it.

A bounded ring (the newest `capacity` entries: a fault storm cannot grow the status without end)
with counts by kind since the daemon started, which `faults_clear` does not reset. Entries are
listed by `faults_list` and in the status (`faults`), counts in the status (`fault_counts`).
"""

from __future__ import annotations

import enum
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

from tvsd.control.runner import LoopFault


class FaultKind(enum.StrEnum):
    CONTROL_OVERRUN = "control_overrun"  # the control thread's late-tick streak latched PWM 0
    MCU_STALE = "mcu_stale"  # no state frame for mcu.link_lost_ms, or they came back with a gap
    MCU_LATE_INPUT = "mcu_late_input"  # late but complete state frames: PWM 0 held, then resumed
    MCU_LINK_LOST = "mcu_link_lost"  # the link saw no frame at all for mcu.link_lost_ms
    MCU_WATCHDOG = "mcu_watchdog"  # the firmware's heartbeat watchdog cut PWM and laser
    MCU_FAULT = "mcu_fault"  # the firmware reported a fault of its own
    IMU = "imu"  # an IMU lost, degraded or not started
    CAN = "can"  # the CAN bridge did not start
    RECORDER = "recorder"  # the recording failed (disk full, I/O error)
    HOMING = "homing"  # the stepper axes did not home
    CONTROL = "control"  # any other fault code of the control thread
    WEB = "web"  # the live view could not listen where configured


# The control thread's latched faults: their kind, cause and what the safe state does.
LOOP_FAULTS = {
    LoopFault.OVERRUN: (
        FaultKind.CONTROL_OVERRUN,
        "control loop overran its deadline streak",
        "safe state: PWM 0",
    ),
    LoopFault.STALE: (
        FaultKind.MCU_STALE,
        "MCU state frames stopped",
        "safe state: PWM 0 from the control thread",
    ),
    LoopFault.GAP: (
        FaultKind.MCU_STALE,
        "MCU state frames stopped, and came back with a gap (frames missing, or the MCU's "
        "clock jumped: it stopped or restarted)",
        "safe state: PWM 0 from the control thread",
    ),
}


@dataclass(frozen=True)
class FaultEntry:
    """One fault. Its JSON (`to_json`) is a contract: fields are only ever added."""

    t_unix: float
    cause: str  # what happened, with the numbers
    action: str  # what the daemon did about it
    safe_after_ms: float | None = None  # a link loss: PWM 0 this long after the last state frame
    kind: FaultKind = FaultKind.CONTROL

    def to_json(self) -> dict[str, Any]:
        # Field by field, not dataclasses.asdict (its deep copy took ~0.1 ms an entry: 1 ms of
        # every status build with 10 faults listed, on the event loop).
        return {
            "t_unix": self.t_unix,
            "cause": self.cause,
            "action": self.action,
            "safe_after_ms": self.safe_after_ms,
            "kind": str(self.kind),
        }


class FaultLog:
    """The newest `capacity` faults, oldest first, and counts by kind since start."""

    def __init__(self, capacity: int) -> None:
        self._entries: deque[FaultEntry] = deque(maxlen=capacity)
        self._counts: Counter[FaultKind] = Counter()

    def add(self, kind: FaultKind, cause: str, action: str, safe_after_ms: float | None = None) -> FaultEntry:
        entry = FaultEntry(time.time(), cause, action, safe_after_ms, kind)
        self._entries.append(entry)
        self._counts[kind] += 1
        return entry

    def entries(self) -> list[FaultEntry]:
        return list(self._entries)

    def clear(self) -> int:
        """Forget the listed faults (the counts stay); how many there were."""
        n = len(self._entries)
        self._entries.clear()
        return n

    def counts(self) -> dict[str, int]:
        """Faults by kind since start, cleared or not (and those pushed out of the ring)."""
        return {str(k): n for k, n in sorted(self._counts.items())}

    def __len__(self) -> int:
        return len(self._entries)
