"""The daemon's sections: `devices:` (which backend stands behind each device), `daemon:` (tvsd's
own periods, bounds and API limits) and `web:` (the live view)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from tvsd.schema import FieldError, check, option


@dataclass(frozen=True, kw_only=True)
class DevicesConfig:
    """The `devices:` section: which backend stands behind each device interface. `sil` puts the
    simulated device behind the same interface at its boundary (a pty for the MCU, a register map
    behind the smbus2 calls for the IMUs); `tvsd --sil` makes every device `sil`."""

    mcu: str = option(
        "hardware", doc="the MCU (motor PWM, encoder, pulses, steppers)", choices=("hardware", "sil")
    )
    imu: str = option(
        "hardware", doc="the two MPU6050s (`off`: no IMU, points marked)", choices=("hardware", "sil", "off")
    )


@dataclass(frozen=True, kw_only=True)
class DaemonSettings:
    """The `daemon:` section: tvsd's own periods, bounds and limits (tvsd/daemon/app.py)."""

    status_period_s: float = option(
        1.0, doc="status published, faults checked, systemd watchdog fed this often", unit="s", gt=0, le=10
    )
    drain_period_s: float = option(
        0.02, doc="the control thread's ticks move into the recording this often", unit="s", gt=0, le=1
    )
    fault_window_s: float = option(
        2.0,
        doc="full-rate control ticks recorded before each fault (the thread keeps 6.5 s)",
        unit="s",
        ge=0,
        le=6,
    )
    fault_log_size: int = option(200, doc="faults listed (older ones are only counted)", ge=1, le=100000)
    status_faults: int = option(
        10, doc="the newest faults carried in status (faults_list gives all fault_log_size)", ge=0, le=1000
    )
    home_timeout_s: float = option(
        30.0, doc="the stepper axes home within this after start", unit="s", gt=0, le=3600
    )
    max_rps: float = option(60.0, doc="speed requests beyond ±this are refused", unit="rev/s", gt=0, le=200)
    stop_margin_s: float = option(
        1.0, doc="at stop, the ramp down may take this much longer than the ramp says", unit="s", ge=0, le=600
    )
    stopped_rps: float = option(
        0.5, doc="at stop, the aperture counts as stopped below this", unit="rev/s", gt=0, le=10
    )
    # The API's bounds (tvsd/daemon/rpc/limits.py Limits; README "Daemon API limits"): no client may
    # stall the event loop or grow a reply without end.
    rpc_max_batch: int = option(50, doc="requests in one batch line", ge=1, le=1000)
    rpc_max_reply_bytes: int = option(1 << 20, doc="one reply line", unit="bytes", ge=4096, le=1 << 28)
    rpc_rate_per_s: float = option(
        50.0, doc="requests per second per connection (faster clients are slowed)", gt=0, le=1e6
    )
    rpc_burst: int = option(
        50, doc="requests at once before the rate applies (≥ rpc_max_batch)", ge=1, le=100000
    )
    rpc_max_concurrent: int = option(8, doc="a batch's requests in flight at once", ge=1, le=1000)
    rpc_max_clients: int = option(64, doc="connections at once", ge=1, le=10000)
    rpc_rate_total_per_s: float = option(
        400.0, doc="requests per second from all connections together (faster: each is slowed)", gt=0, le=1e6
    )
    stale_after_ms: float = option(
        100.0,
        doc="status marks rps and the loop's measurement stale when the newest measurement is older",
        unit="ms",
        gt=0,
        le=10000,
    )

    def __post_init__(self) -> None:
        if self.rpc_burst < self.rpc_max_batch:
            raise FieldError(
                "rpc_burst", f"must be at least rpc_max_batch ({self.rpc_max_batch}), got {self.rpc_burst}"
            )


SOCKET_PATH_MAX = 107  # sun_path is 108 bytes on Linux, NUL included


@dataclass(frozen=True, kw_only=True)
class WebSettings:
    """The `web:` section: the daemon's live, read-only web page (tvsd/daemon/web). Off unless
    enabled; on loopback by default, or on a Unix socket for a reverse proxy (docs/measurements/web-view.md,
    "Live view")."""

    enabled: bool = option(False, doc="serve the live view")
    host: str = option("127.0.0.1", doc="address to bind (loopback: this machine only)")
    port: int = option(8080, doc="TCP port (0: any free port, named in the daemon's log)", ge=0, le=65535)
    socket: Path | None = option(None, doc="a Unix socket for a reverse proxy instead of host/port")
    push_hz: float = option(5.0, doc="frames pushed to a browser at most this often", unit="Hz", gt=0, le=5)
    history_s: float = option(60.0, doc="speed and lateness shown over the last", unit="s", ge=10, le=600)
    cloud_points: int = option(5000, doc="newest points shown in the 3D view", ge=100, le=100000)
    spectrum_s: float = option(4.0, doc="IMU samples per Welch spectrum", unit="s", ge=1, le=30)
    max_clients: int = option(8, doc="browsers served at once (more get HTTP 503)", ge=1, le=64)
    stall_s: float = option(
        5.0, doc="a browser that has not taken a frame for this long is dropped", unit="s", gt=0, le=60
    )
    send_buffer_kib: int = option(
        64, doc="kernel send buffer per browser: bounds what a non-reading client holds", unit="KiB", ge=4
    )
    floor_s: float = option(
        1.0,
        doc="the machine's floor (a bare sleep loop at the control rate) is measured this long",
        unit="s",
        gt=0,
        le=10,
    )
    floor_every_s: float = option(60.0, doc="... this often (0: once at start)", unit="s", ge=0)

    def __post_init__(self) -> None:
        check(self)
        if self.socket is not None:
            if not self.socket.is_absolute():
                raise FieldError("socket", f"{self.socket} is relative: give an absolute path")
            if len(os.fsencode(self.socket)) > SOCKET_PATH_MAX:
                raise FieldError("socket", f"{self.socket} is longer than {SOCKET_PATH_MAX} bytes")
        if 0 < self.floor_every_s < 10 * self.floor_s:
            raise FieldError(
                "floor_every_s",
                f"{self.floor_every_s:g} s would measure the floor more than a tenth of the time "
                f"(floor_s {self.floor_s:g} s): use 0 or ≥ {10 * self.floor_s:g}",
            )
