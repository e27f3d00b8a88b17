"""The daemon's state and the transitions it may take, in one table.

```
 starting ─> idle ─> spinning ─> scanning     scanning ─> spinning   (scan_stop)
                └────────────────> scanning   (the shaft still turning after a faults_clear)
 starting, idle, spinning, scanning ─> fault ─> idle   (faults_clear)
 every state but stopping ─> stopping   (shutdown; the end)
```
A speed of 0 leaves `spinning` as it is: the aperture ramps down under the law.
`status.state` carries the value (the strings are a contract: `tvsctl status --json`, the CAN
status frame). A transition not in TRANSITIONS is a bug in the daemon: `StateMachine.go` refuses
it with IllegalTransition naming both states, rather than drift into a state no code expects.
"""

from __future__ import annotations

import enum
from collections.abc import Callable

from tvsd.errors import EXIT_INTERNAL, TvsdError


class DaemonState(enum.StrEnum):
    STARTING = "starting"  # the socket answers; the devices are coming up
    IDLE = "idle"  # no speed requested
    SPINNING = "spinning"  # the aperture has a speed reference
    SCANNING = "scanning"  # ... and the laser is on, points are published
    FAULT = "fault"  # the drive holds its safe state (PWM 0) until faults_clear
    STOPPING = "stopping"  # shutdown: ramp down, devices off


S = DaemonState
TRANSITIONS: dict[DaemonState, frozenset[DaemonState]] = {
    S.STARTING: frozenset({S.IDLE, S.FAULT, S.STOPPING}),
    S.IDLE: frozenset({S.SPINNING, S.SCANNING, S.FAULT, S.STOPPING}),
    S.SPINNING: frozenset({S.SCANNING, S.FAULT, S.STOPPING}),
    S.SCANNING: frozenset({S.SPINNING, S.FAULT, S.STOPPING}),
    S.FAULT: frozenset({S.IDLE, S.STOPPING}),
    S.STOPPING: frozenset(),
}


class IllegalTransition(TvsdError, RuntimeError):
    """A transition the table does not allow: a bug in the daemon, not a user's mistake."""

    exit_status = EXIT_INTERNAL


class StateMachine:
    """The current state; `go` takes a transition of the table and tells `on_change`."""

    def __init__(self, on_change: Callable[[DaemonState, DaemonState], None] | None = None) -> None:
        self.state = S.STARTING
        self.on_change = on_change

    def go(self, new: DaemonState) -> None:
        """Move to `new` (staying put is always allowed and says nothing)."""
        old = self.state
        if new == old:
            return
        if new not in TRANSITIONS[old]:
            allowed = ", ".join(sorted(TRANSITIONS[old])) or "none"
            raise IllegalTransition(f"daemon state {old} cannot go to {new} (from {old}: {allowed})")
        self.state = new
        if self.on_change is not None:
            self.on_change(old, new)

    def can(self, new: DaemonState) -> bool:
        """Whether `go(new)` would be taken (check before acting on the devices)."""
        return new == self.state or new in TRANSITIONS[self.state]
