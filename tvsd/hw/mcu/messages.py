"""Typed MCU -> host messages, held to protocol.yaml's field lists when the link starts.

The payload layouts come from the spec; the classes here give them types for the rest of tvsd.
``check_against(spec)`` refuses a spec whose fields no longer match these classes, so a protocol
change the host code has not followed fails at start-up with the message's name, not later with
a garbled value.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from tvsd.errors import ProtocolError
from tvsd.hw.mcu.spec import ProtocolSpec, load_spec


@dataclass(frozen=True, slots=True)
class Identify:
    proto_version: int
    clock_hz: int
    table_hash: int
    board: int


@dataclass(frozen=True, slots=True)
class HeartbeatAck:
    host_us: int
    mcu_ticks: int


@dataclass(frozen=True, slots=True)
class State:
    ticks: int  # the MCU's 32-bit tick count when the sample was taken
    encoder16: int


@dataclass(frozen=True, slots=True)
class Pulse:
    channel: int
    event_seq: int
    mcu_ticks: int


@dataclass(frozen=True, slots=True)
class Fault:
    code: int
    detail: int


@dataclass(frozen=True, slots=True)
class StepperState:
    axis: int
    position: int
    flags: int

    MOVING = 1
    HOMED = 2
    AT_LIMIT = 4

    @property
    def moving(self) -> bool:
        return bool(self.flags & self.MOVING)

    @property
    def homed(self) -> bool:
        return bool(self.flags & self.HOMED)

    @property
    def at_limit(self) -> bool:
        return bool(self.flags & self.AT_LIMIT)


@dataclass(frozen=True, slots=True)
class Ack:
    seq: int
    status: int


@dataclass(frozen=True, slots=True)
class McuStats:
    rx_frames: int
    crc_errors: int
    resyncs: int
    tx_dropped: int
    duplicates: int  # repeated host frames the MCU dropped unexecuted
    rx_overflows: int  # received bytes the board's RX ring had no room for (a host burst)
    ticks_dropped: int  # control ticks the board's tick queue had no room for (a late main loop)
    watchdog_expiries: int  # heartbeat watchdog cuts since boot (each also a fault frame, which can be lost)


def ack_meaning(status: int, spec: ProtocolSpec | None = None) -> str:
    """What an ack status means, from protocol.yaml's ack_status (the firmware's ACK_* come from
    the same table)."""
    return (spec or load_spec()).ack_meaning(status)


Message = Identify | HeartbeatAck | State | Pulse | Fault | StepperState | Ack | McuStats

# spec name -> class
M2H_CLASSES: dict[str, type] = {
    "identify": Identify,
    "heartbeat_ack": HeartbeatAck,
    "state": State,
    "pulse": Pulse,
    "fault": Fault,
    "stepper_state": StepperState,
    "ack": Ack,
    "stats": McuStats,
}

# host -> MCU messages the link sends, with the field order it passes
H2M_FIELDS: dict[str, tuple[str, ...]] = {
    "identify_req": (),
    "heartbeat": ("host_us",),
    "pwm_set": ("duty",),
    "stepper_move": ("axis", "steps", "rate_sps", "accel_sps2"),
    "stepper_home": ("axis",),
    "laser_set": ("on",),
    "config_set": ("watchdog_ms", "state_div", "max_on_ms"),
    "stats_req": (),
}


def check_against(spec: ProtocolSpec) -> dict[int, type]:
    """id -> class for every m2h message; ProtocolError naming the first mismatch."""
    out: dict[int, type] = {}
    for name, cls in M2H_CLASSES.items():
        m = spec.by_name(name)
        mine = tuple(f.name for f in fields(cls))
        if m.dir != "m2h" or m.field_names != mine:
            raise ProtocolError(
                f"{spec.path}: message {name} is {m.dir} {list(m.field_names)}, but this tvsd "
                f"reads it as m2h {list(mine)}: update tvsd/hw/mcu/messages.py with the protocol"
            )
        out[m.id] = cls
    for name, names in H2M_FIELDS.items():
        m = spec.by_name(name)
        if m.dir != "h2m" or m.field_names != names:
            raise ProtocolError(
                f"{spec.path}: message {name} is {m.dir} {list(m.field_names)}, but this tvsd "
                f"sends h2m {list(names)}: update tvsd/hw/mcu/messages.py with the protocol"
            )
    return out
