"""CAN frame layout of the robot bridge: pure encode/decode functions (no bus, no I/O).

Classic CAN, 8-byte payloads, 11-bit ids at fixed offsets from a configurable base id (default
0x580). Multi-byte fields are little-endian (Intel order, what DBC files and ``struct '<'`` use);
the point frames are bit-packed into one little-endian 64-bit word (bit 0 = LSB of byte 0). The
full table with examples is ``tvsd/hw/can/CAN.md``; the code here is the reference.

    id        dir          frame    payload (8 bytes)
    base+0    robot→tvsd   COMMAND  code u8 | cmd_id u8 | args (SPEED: rps×100 u16; AIM: φ, γ ×100 ° i16)
    base+1    tvsd→robot   ACK      code u8 | cmd_id u8 | result u8 (0 accepted, 1 refused) | reason u8 | 0
    base+2    tvsd→robot   STATUS   state u8 | rps×100 u16 | faults u8 | missed u16 | dropped u8 | seq u8
    base+3    tvsd→robot   POINT    two frames per point, told apart by the part bit (below)

Lower ids win arbitration, so the order is deliberate: a robot's STOP beats everything, acks beat
the periodic status, and the bulk point stream yields to all of them.

POINT word: bits 0 part (0/1) | 1–3 seq (point counter mod 8, same in both parts) | then
    part 0: x, y, z as i20 in 0.1 mm (bits 4–23, 24–43, 44–63)
    part 1: σx, σy, σz as u16 in 0.01 mm (bits 4–19, 20–35, 36–51) | flags u12 (bits 52–63)
Why i20 and not i24: x, y, z as i24 plus σ as u16 is 15 bytes, which leaves one byte of the two
frames for the part/seq header of *both* frames and the flags — it does not fit. i20 at 0.1 mm is
±52.4 m, far beyond where a triangulation scanner with a 0.5 m baseline measures usefully (σ grows
with the square of the range), and frees the bits for a 4-bit header per frame and 12 flag bits.
A value outside a field's range saturates (±inf to the limit; NaN coordinates → 0, NaN σ → max)
and sets FLAG_SATURATED, so the robot can tell.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from tvsd.errors import ProtocolError

FRAME_LEN = 8  # classic CAN: every frame of this protocol carries exactly 8 bytes

OFF_COMMAND, OFF_ACK, OFF_STATUS, OFF_POINT = range(4)

XYZ_LSB_M = 1e-4  # 0.1 mm
SIGMA_LSB_M = 1e-5  # 0.01 mm
_XYZ_BITS, _SIGMA_BITS, _FLAG_BITS = 20, 16, 12
XYZ_MIN, XYZ_MAX = -(1 << (_XYZ_BITS - 1)), (1 << (_XYZ_BITS - 1)) - 1  # in LSB
SIGMA_MAX = (1 << _SIGMA_BITS) - 1
FLAG_SATURATED = 1 << (_FLAG_BITS - 1)  # 0x800: a field did not fit (wire-only flag)
FLAGS_CARRIED = FLAG_SATURATED - 1  # scan flags bits 0..10 pass through (tvsd.scan.points.FLAG_*)

# Command ranges checked on the wire; the daemon checks its own limits on top (then REFUSED).
MAX_RPS = 50.0
PHI_RANGE_DEG = (-180.0, 180.0)
GAMMA_RANGE_DEG = (-90.0, 90.0)

_STATUS = struct.Struct("<BHBHBB")
_COMMAND_HEAD = struct.Struct("<BB")
_SPEED = struct.Struct("<BBH4x")
_AIM = struct.Struct("<BBhh2x")
_ACK = struct.Struct("<BBBB4x")

Payload = bytes | bytearray  # can.Message.data is a bytearray


class State(enum.IntEnum):
    """STATUS byte 0: the daemon's state (names as in the daemon's status `state`)."""

    UNKNOWN = 0
    IDLE = 1
    SPINNING = 2
    SCANNING = 3
    STOPPING = 4
    FAULT = 5


class CommandCode(enum.IntEnum):
    START = 0x01  # start scanning (args ignored)
    STOP = 0x02  # stop scanning (args ignored)
    SPEED = 0x03  # set the SA speed: bytes 2–3 rps×100 u16, 0.00..MAX_RPS
    AIM = 0x04  # aim the PL: bytes 2–3 φ×100 ° i16, bytes 4–5 γ×100 ° i16


class Reason(enum.IntEnum):
    """ACK byte 3. 1–3: the frame itself was bad (counted as bad frames); 4–7: the daemon said no."""

    OK = 0
    BAD_LENGTH = 1
    UNKNOWN_COMMAND = 2
    OUT_OF_RANGE = 3
    REFUSED = 4  # the daemon refused (e.g. wrong state for this command)
    BUSY = 5
    TIMEOUT = 6  # the daemon did not answer in time
    INTERNAL = 7  # the daemon's handler failed (a bug; logged)


@dataclass(frozen=True)
class Command:
    code: CommandCode
    cmd_id: int  # the robot's tag, 0..255, echoed in the ack
    rps: float | None = None  # SPEED
    phi_deg: float | None = None  # AIM
    gamma_deg: float | None = None


@dataclass(frozen=True)
class Ack:
    """What the command handler answers; the bridge puts it on the wire with the command's id."""

    accepted: bool
    reason: Reason = Reason.OK

    @classmethod
    def ok(cls) -> Ack:
        return cls(True, Reason.OK)

    @classmethod
    def refused(cls, reason: Reason = Reason.REFUSED) -> Ack:
        return cls(False, reason)


@dataclass(frozen=True)
class AckFrame:
    code: int
    cmd_id: int
    accepted: bool
    reason: Reason


@dataclass(frozen=True)
class Status:
    state: State
    rps: float
    faults: int
    missed_ticks: int  # mod 2**16: the robot takes differences
    dropped: int  # points the bridge dropped, mod 2**8
    seq: int  # mod 2**8


@dataclass(frozen=True)
class Point:
    seq: int
    x: float  # m
    y: float
    z: float
    sigma_x: float  # m
    sigma_y: float
    sigma_z: float
    flags: int


class BadFrame(ProtocolError):
    """A frame from the robot broke the protocol; `reason` goes into the refused ack."""

    def __init__(self, reason: Reason, message: str, code: int = 0, cmd_id: int = 0) -> None:
        super().__init__(message)
        self.reason, self.code, self.cmd_id = reason, code, cmd_id


def _quantize(value: float, lsb: float, lo: int, hi: int, nan: int) -> tuple[int, bool]:
    """Round to the nearest LSB and clamp; the bool says the value did not fit."""
    if math.isnan(value):
        return nan, True
    if math.isinf(value):
        return (hi if value > 0 else lo), True
    n = round(value / lsb)
    if n < lo or n > hi:
        return min(max(n, lo), hi), True
    return n, False


# --- status ----------------------------------------------------------------------------------------


def state_of(value: Any) -> State:
    """A daemon state name ('idle', 'scanning', ...) or number → State; anything else UNKNOWN."""
    if isinstance(value, str):
        return State.__members__.get(value.upper(), State.UNKNOWN)
    try:
        return State(int(value))
    except (TypeError, ValueError):
        return State.UNKNOWN


def encode_status(state: State, rps: float, faults: int, missed_ticks: int, dropped: int, seq: int) -> bytes:
    # Levels saturate (rps, faults); counters wrap, so the robot's differences stay right.
    rps_n, _ = _quantize(max(rps, 0.0), 0.01, 0, 0xFFFF, 0)
    return _STATUS.pack(
        int(state), rps_n, min(max(faults, 0), 0xFF), missed_ticks & 0xFFFF, dropped & 0xFF, seq & 0xFF
    )


def decode_status(data: Payload) -> Status:
    if len(data) != FRAME_LEN:
        raise BadFrame(Reason.BAD_LENGTH, f"status frame has {len(data)} bytes, expected 8")
    state, rps, faults, missed, dropped, seq = _STATUS.unpack(bytes(data))
    return Status(state_of(state), rps / 100, faults, missed, dropped, seq)


# --- points ----------------------------------------------------------------------------------------


def encode_point(record: Mapping[str, Any], seq: int) -> tuple[bytes, bytes]:
    """A point record (tvsd.scan.points FIELDS, SI units) → its two POINT frames (part 0, part 1)."""
    head = (seq & 0x7) << 1
    saturated = False
    xyz = []
    for key in ("x", "y", "z"):
        n, sat = _quantize(float(record[key]), XYZ_LSB_M, XYZ_MIN, XYZ_MAX, 0)
        xyz.append(n & ((1 << _XYZ_BITS) - 1))  # two's complement in 20 bits
        saturated |= sat
    sig = []
    for key in ("sigma_x", "sigma_y", "sigma_z"):
        n, sat = _quantize(float(record[key]), SIGMA_LSB_M, 0, SIGMA_MAX, SIGMA_MAX)
        sig.append(n)
        saturated |= sat
    flags = int(record.get("flags", 0))
    if flags < 0 or flags & ~FLAGS_CARRIED:
        saturated = True  # flag bits the wire cannot carry
    flags = (flags & FLAGS_CARRIED) | (FLAG_SATURATED if saturated else 0)
    w0 = head | xyz[0] << 4 | xyz[1] << 24 | xyz[2] << 44
    w1 = head | 1 | sig[0] << 4 | sig[1] << 20 | sig[2] << 36 | flags << 52
    return w0.to_bytes(8, "little"), w1.to_bytes(8, "little")


def point_part(data: Payload) -> tuple[int, int]:
    """(part, seq) of a POINT frame, to pair the two frames of a point."""
    return data[0] & 1, (data[0] >> 1) & 0x7


def decode_point(part0: Payload, part1: Payload) -> Point:
    if len(part0) != FRAME_LEN or len(part1) != FRAME_LEN:
        raise BadFrame(Reason.BAD_LENGTH, "point frames carry 8 bytes each")
    (p0, s0), (p1, s1) = point_part(part0), point_part(part1)
    if (p0, p1) != (0, 1) or s0 != s1:
        raise BadFrame(Reason.OUT_OF_RANGE, f"not the two parts of one point: parts {p0},{p1} seq {s0},{s1}")
    w0, w1 = int.from_bytes(part0, "little"), int.from_bytes(part1, "little")

    def signed(shift: int) -> float:
        n = (w0 >> shift) & ((1 << _XYZ_BITS) - 1)
        return (n - (1 << _XYZ_BITS) if n >> (_XYZ_BITS - 1) else n) * XYZ_LSB_M

    def sigma(shift: int) -> float:
        return ((w1 >> shift) & SIGMA_MAX) * SIGMA_LSB_M

    return Point(s0, signed(4), signed(24), signed(44), sigma(4), sigma(20), sigma(36), w1 >> 52)


# --- commands and acks -----------------------------------------------------------------------------


def encode_command(cmd: Command) -> bytes:
    """The robot's side (and the tests'): a Command → its COMMAND frame."""
    if cmd.code is CommandCode.SPEED:
        return _SPEED.pack(cmd.code, cmd.cmd_id, round((cmd.rps or 0.0) * 100))
    if cmd.code is CommandCode.AIM:
        return _AIM.pack(
            cmd.code, cmd.cmd_id, round((cmd.phi_deg or 0.0) * 100), round((cmd.gamma_deg or 0.0) * 100)
        )
    return _COMMAND_HEAD.pack(cmd.code, cmd.cmd_id) + bytes(6)


def decode_command(data: Payload) -> Command:
    """A COMMAND frame → Command; BadFrame (with the reason for the refused ack) if it is not one."""
    code, cmd_id = (data[0], data[1]) if len(data) >= 2 else (data[0] if data else 0, 0)
    if len(data) != FRAME_LEN:
        raise BadFrame(Reason.BAD_LENGTH, f"command frame has {len(data)} bytes, expected 8", code, cmd_id)
    if code not in CommandCode._value2member_map_:
        raise BadFrame(Reason.UNKNOWN_COMMAND, f"unknown command code 0x{code:02x}", code, cmd_id)
    kind = CommandCode(code)
    if kind is CommandCode.SPEED:
        rps = _SPEED.unpack(bytes(data))[2] / 100
        if rps > MAX_RPS:
            raise BadFrame(Reason.OUT_OF_RANGE, f"speed {rps} rev/s above {MAX_RPS}", code, cmd_id)
        return Command(kind, cmd_id, rps=rps)
    if kind is CommandCode.AIM:
        _, _, phi_n, gamma_n = _AIM.unpack(bytes(data))
        phi, gamma = phi_n / 100, gamma_n / 100
        if not (
            PHI_RANGE_DEG[0] <= phi <= PHI_RANGE_DEG[1] and GAMMA_RANGE_DEG[0] <= gamma <= GAMMA_RANGE_DEG[1]
        ):
            raise BadFrame(Reason.OUT_OF_RANGE, f"aim φ {phi}°, γ {gamma}° out of range", code, cmd_id)
        return Command(kind, cmd_id, phi_deg=phi, gamma_deg=gamma)
    return Command(kind, cmd_id)


def encode_ack(code: int, cmd_id: int, ack: Ack) -> bytes:
    return _ACK.pack(code & 0xFF, cmd_id & 0xFF, 0 if ack.accepted else 1, int(ack.reason))


def decode_ack(data: Payload) -> AckFrame:
    if len(data) != FRAME_LEN:
        raise BadFrame(Reason.BAD_LENGTH, f"ack frame has {len(data)} bytes, expected 8")
    code, cmd_id, result, reason = _ACK.unpack(bytes(data))
    return AckFrame(
        code, cmd_id, result == 0, Reason(reason) if reason in Reason._value2member_map_ else Reason.INTERNAL
    )
