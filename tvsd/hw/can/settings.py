"""The `can:` config section, apart from the bridge so loading a config never imports python-can."""

from __future__ import annotations

from dataclasses import dataclass

from tvsd.schema import option

MAX_BASE_ID = 0x7FF - 3  # four consecutive 11-bit ids


@dataclass(frozen=True, kw_only=True)
class CanSettings:
    """Config section `can`."""

    enabled: bool = option(False, doc="run the CAN bridge to a robot")
    interface: str = option("socketcan", doc="python-can interface (socketcan, pcan, virtual, ...)")
    channel: str = option("can0", doc="python-can channel of the interface")
    bitrate: int = option(
        500000,
        doc="bus bit rate (ignored by socketcan: set it with `ip link`)",
        unit="bit/s",
        ge=10000,
        le=1000000,
    )
    base_id: int = option(
        0x580, doc="first of the four 11-bit ids (command, ack, status, point)", ge=0, le=MAX_BASE_ID
    )
    status_hz: float = option(10.0, doc="status frame rate", unit="Hz", gt=0, le=100)
    handler_timeout_s: float = option(
        2.0, doc="a robot's command unanswered this long gets a TIMEOUT ack, not silence", unit="s", gt=0
    )
    point_queue: int = option(
        256, doc="points waiting for the bus before the oldest is dropped", ge=1, le=65536
    )
