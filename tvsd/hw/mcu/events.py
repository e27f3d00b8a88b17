"""What the MCU link hands its users: typed events, its counters, the identity check, the port.

Shared by the link's parts (``link``: wiring, life cycle, reporting; ``sending``: typed frames;
``queries``: requests awaited; ``receiving``: frame handlers and the queue to the event loop;
``io_thread``: the port's thread), so none of them imports another for a type.
"""

from __future__ import annotations

import math
import os
import termios
from dataclasses import dataclass
from typing import Any

import serial

from tvsd.errors import DeviceError, ProtocolError, UsageError
from tvsd.hw.mcu.messages import Identify
from tvsd.hw.mcu.spec import ProtocolSpec

FLASH_HINT = (
    "flash the firmware image of this tvsd (make -C firmware, then avrdude: hil/README.md, section MCU)"
)


def check_identity(ident: Identify, spec: ProtocolSpec, port: str) -> None:
    """Refuse an MCU that speaks another protocol: one line, seen vs expected, and the fix."""
    if ident.proto_version != spec.version:
        raise ProtocolError(
            f"the MCU on {port} speaks protocol v{ident.proto_version}, this tvsd speaks "
            f"v{spec.version}: {FLASH_HINT}"
        )
    if ident.table_hash != spec.table_hash:
        raise ProtocolError(
            f"the MCU on {port} has command table 0x{ident.table_hash:08X} (protocol "
            f"v{ident.proto_version}), this tvsd expects 0x{spec.table_hash:08X}: the firmware "
            f"was built from another protocol.yaml; {FLASH_HINT}"
        )


@dataclass(frozen=True, slots=True)
class PulseEvent:
    channel: int
    channel_name: str
    event_seq: int
    mcu_ticks: int  # unwrapped to 64 bits
    host_time: float  # clock-sync mapped; NaN before the first heartbeat round trip


@dataclass(frozen=True, slots=True)
class FaultEvent:
    code: int
    name: str
    detail: int
    host_time: float


@dataclass(frozen=True, slots=True)
class Refusal:
    """The MCU refused a frame we sent (an ack with a non-zero status)."""

    name: str  # message name, e.g. "stepper_move"
    values: tuple[int, ...]  # its fields, as sent
    status: int
    reason: str
    host_time: float


@dataclass
class LinkStats:
    frames_rx: int = 0
    frames_tx: int = 0
    crc_errors: int = 0
    bad_headers: int = 0
    resyncs: int = 0
    bytes_dropped: int = 0
    lost_frames: int = 0  # MCU -> host frames missing by SEQ gaps
    duplicates: int = 0
    lost_events: int = 0  # pulse events missing by event_seq gaps
    tx_dropped: int = 0  # host -> MCU frames refused because the output buffer was full
    nacks: int = 0  # ack frames with a non-zero status
    faults: int = 0
    link_up: bool = False
    link_losses: int = 0
    last_loss_s: float = math.nan  # time.monotonic() when the I/O thread last called the link lost
    rtt_last_s: float = math.nan
    rtt_p50_s: float = math.nan
    rtt_max_s: float = math.nan
    rtt_samples: int = 0
    clock_drift_ppm: float = math.nan
    clock_residual_us: float = math.nan
    states_unanchored: int = 0  # state frames before the first heartbeat_ack that it could not place
    heartbeats: int = 0  # sent on the I/O thread's schedule (pings not counted)
    heartbeats_withheld: int = 0  # due but not sent: the liveness count had not moved (control dead)
    last_heartbeat_s: float = math.nan  # time.monotonic() of the last one sent on the schedule
    heartbeat_gap_max_s: float = 0.0  # longest time between two sent (the firmware cuts at watchdog_ms)
    heartbeat_late_max_s: float = 0.0  # the I/O thread's worst wake-up after a heartbeat's due time
    events_dropped: int = 0  # events for the event loop refused because its queue was full

    def as_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in self.__dict__.items()}


def open_serial(port: str, baud: int) -> serial.Serial:
    """Open the port non-blocking, or one clear DeviceError saying what to check."""
    try:
        return serial.Serial(port, baud, timeout=0, write_timeout=0, exclusive=True)
    except ValueError as exc:  # pyserial: a baud rate or setting it cannot apply
        raise UsageError(f"cannot open serial port {port} at {baud} baud: {exc}") from exc
    except (serial.SerialException, OSError) as exc:
        errno = getattr(exc, "errno", None)
        if errno:
            reason = os.strerror(errno)
        elif isinstance(exc.__context__, termios.error):  # opened, but termios refused it
            reason = f"not a serial port ({exc.__context__.args[-1]})"
        else:
            reason = str(exc)
        raise DeviceError(
            f"cannot open serial port {port}: {reason}; check the cable / the path / "
            "permissions (dialout group)"
        ) from exc
