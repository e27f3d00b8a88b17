"""Configuration: YAML files in config/ → validated, frozen objects.

Three files ship in config/ (each documented key by key there):
- ``tvsd.yaml``  the scanner: the physically consistent default plant, drive, control, geometry,
  and a pointer to its SIL profile;
- ``sil.yaml``   the simulated plant's environment: vibration, measurement, effects, seed;
- ``paper.yaml`` the paper's parameter set (Table 3 Exp1) and the tables tvsd reproduces.
The numbers and where each comes from are in the files; the decisions are in MODEL-NOTES.md.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path

from tvsd.errors import ConfigError, UsageError
from tvsd.hw.can.settings import CanSettings
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mpu6050 import ImuSettings
from tvsd.scan.settings import ScanSettings
from tvsd.schema import FieldError, Where, build, check, load_yaml, option


@dataclass(frozen=True, kw_only=True)
class PlantParams:
    """The scanning-aperture drive, paper eqs. (9)–(11) and (15)–(16) in SI units."""

    name: str = option(doc="name of the parameter set")
    J: float = option(doc="inertia of motor + aperture", unit="kg·m²", gt=0, le=10)
    kv: float = option(doc="viscous friction", unit="N·m·s/rad", ge=0, le=100)
    kM: float = option(doc="torque constant", unit="N·m/A", gt=0, le=100)
    kb: float = option(doc="back-EMF constant", unit="V·s/rad", gt=0, le=100)
    R: float = option(doc="armature resistance", unit="Ω", gt=0, le=1e4)
    L: float = option(doc="armature inductance", unit="H", gt=0, le=100)
    ku: float = option(doc="drive voltage gain", unit="V/V", gt=0, le=1e4)
    tau_c: float = option(doc="Coulomb friction torque", unit="N·m", ge=0, le=1e4)
    tau_s: float = option(doc="stiction torque", unit="N·m", ge=0, le=1e4)
    sigma0: float = option(doc="LuGre bristle stiffness", unit="N·m/rad", gt=0, le=1e9)
    sigma1: float = option(doc="LuGre bristle damping", unit="N·m·s/rad", ge=0, le=1e6)
    sigma2: float = option(0.0, doc="LuGre viscous term", unit="N·m·s/rad", ge=0, le=1e3)
    v0: float = option(doc="Stribeck velocity", unit="rad/s", gt=0, le=1e3)
    source: str = option("", doc="where the numbers come from")

    def __post_init__(self) -> None:
        if self.tau_c + self.tau_s <= 0:
            raise UsageError(f"plant {self.name}: tau_c and tau_s are both 0; LuGre needs g(ω) > 0")


@dataclass(frozen=True, kw_only=True)
class DriveConfig:
    u_max_v: float = option(12.0, doc="drive voltage limit ±U", unit="V", gt=0, le=400)


@dataclass(frozen=True, kw_only=True)
class Gains:
    """Gains of the robust law u = Gp·tanh(ε) + Gd·tanh(ε̇) + Gr·tanh(G0·ε) (paper eq. 18)."""

    Gp: float = option(doc="proportional gain", unit="V", ge=0, le=1e4)
    Gd: float = option(doc="derivative gain", unit="V", ge=0, le=1e4)
    Gr: float = option(doc="robust gain", unit="V", ge=0, le=1e4)
    G0: float = option(doc="sharpness factor", unit="1/rad", gt=0, le=1e6)

    def __post_init__(self) -> None:
        check(self)  # the one rule for gains from YAML, the API and the command line

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.Gp, self.Gd, self.Gr, self.G0)


@dataclass(frozen=True, kw_only=True)
class ControlConfig:
    rate_hz: float = option(10000.0, doc="control loop rate", unit="Hz", ge=100, le=100000)
    gains: Gains = option(doc="robust law gains")
    disturbance_bound_rad_s2: float = option(
        1.65, doc="Δv_max for condition (23), paper's largest measured value", unit="rad/s²", ge=0, le=1e6
    )
    scan_accel_rps2: float = option(
        10.0, doc="speed-reference ramp in scanning mode", unit="rev/s²", gt=0, le=1e4
    )
    overrun_streak_ms: float = option(
        100.0,
        doc="late ticks in a row for this long put the drive in its safe state (a shared machine stalls "
        "for ms at times; the MCU's watchdog cuts at 200 ms)",
        unit="ms",
        gt=0,
        le=1000,
    )
    scan_feedforward: bool = option(
        True, doc="scanning mode adds the model's steady voltage to the law's output (README)"
    )
    max_lag_rad: float = option(
        math.pi,
        doc="scanning mode: the reference slips beyond this lag (anti-windup)",
        unit="rad",
        gt=0,
        le=1e3,
    )

    @property
    def overrun_streak_ticks(self) -> int:
        """The overrun latch in ticks: this many late ticks in a row put the drive in its safe state."""
        return max(1, round(self.overrun_streak_ms * 1e-3 * self.rate_hz))


@dataclass(frozen=True, kw_only=True)
class GeometryConfig:
    baseline_m: float = option(
        0.5, doc="baseline a between PL and SA (MODEL-NOTES §6)", unit="m", gt=0, le=100
    )


@dataclass(frozen=True, kw_only=True)
class VibrationConfig:
    model: str = option("ou", doc="Δv model (MODEL-NOTES §4)", choices=("off", "sde", "ou"))
    sigma_v: float = option(
        0.3381, doc="σv: std (ou, rad/s²) or SDE intensity (sde, rad/s^1.5)", ge=0, le=1e4
    )
    tau_n_s: float = option(0.005, doc="OU correlation time", unit="s", gt=0, le=100)


@dataclass(frozen=True, kw_only=True)
class MeasurementConfig:
    sample_rate_hz: float = option(1000.0, doc="recording rate", unit="Hz", gt=0, le=100000)
    encoder_counts_per_rev: int = option(8192, doc="encoder counts per revolution (×4)", ge=4, le=1 << 24)
    speed_noise_rad_s: float = option(0.02, doc="speed measurement noise std", unit="rad/s", ge=0, le=1e3)


@dataclass(frozen=True, kw_only=True)
class SilConfig:
    vibration: VibrationConfig = option(VibrationConfig())
    measurement: MeasurementConfig = option(MeasurementConfig())
    effects: tuple[str, ...] = option([], doc='effects on, as "name:key=value,..." (tvsctl sim --help)')
    seed: int = option(1, doc="random seed of the simulated plant", ge=0, le=2**32 - 1)


@dataclass(frozen=True, kw_only=True)
class Reproduction:
    """Figures of the paper that `tvsctl sim` reproduces (paper.yaml only)."""

    table6_refs_deg: tuple[float, ...] = option([], doc="Table 6 reference positions", unit="deg")
    table6_settling_s: tuple[float, ...] = option([], doc="Table 6 settling times", unit="s")
    table6_ku: float = option(10.0, doc="ku that reproduces Table 6 (MODEL-NOTES §3)", gt=0)
    open_loop_ku: float = option(166.0, doc="ku of the open-loop runs (MODEL-NOTES §3)", gt=0)


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
    # The API's bounds (tvsd/daemon/rpc.py Limits; README "Daemon API limits"): no client may
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
    enabled; on loopback by default, or on a Unix socket for a reverse proxy (README "Live view")."""

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


EXCITATION_KINDS = ("steps", "multisine", "prbs")


@dataclass(frozen=True, kw_only=True)
class IdentifySettings:
    """The `identify:` section: the bounded excitation `tvsctl identify` adds while the aperture
    spins (tvsd/control/excitation.py builds it, the control thread plays it). Steps and the
    multisine move the speed reference (through the scanning ramp, so the acceleration stays
    within control.scan_accel_rps2); the PRBS is added to the drive voltage after the law, then
    clipped at ±drive.u_max_v."""

    kinds: tuple[str, ...] = option(
        list(EXCITATION_KINDS),
        doc="excitations to add, any of steps, multisine, prbs",
        choices=EXCITATION_KINDS,
    )
    seconds: float = option(20.0, doc="how long the excitation runs", unit="s", ge=1)
    max_seconds: float = option(
        120.0, doc="longest excitation: the control thread preallocates its table", unit="s", ge=1, le=600
    )
    table_rate_hz: float = option(
        1000.0, doc="rows per second of the excitation table (the 10 kHz loop holds each)", unit="Hz",
        ge=10, le=10000,
    )  # fmt: skip
    step_rps: float = option(0.5, doc="speed-reference step size", unit="rev/s", ge=0, le=5)
    step_hold_s: float = option(1.0, doc="each step is held this long", unit="s", ge=0.05, le=30)
    multisine_rps: float = option(0.2, doc="peak of the speed-reference multisine", unit="rev/s", ge=0, le=5)
    multisine_min_hz: float = option(0.2, doc="lowest multisine line", unit="Hz", gt=0, le=100)
    multisine_max_hz: float = option(8.0, doc="highest multisine line", unit="Hz", gt=0, le=100)
    prbs_v: float = option(0.5, doc="PRBS amplitude added to the drive voltage", unit="V", ge=0, le=6)
    prbs_clock_s: float = option(
        0.004, doc="PRBS bit time (≥ the MCU's PWM frame period)", unit="s", ge=0.0004, le=1
    )
    max_delta_rps: float = option(
        1.5, doc="bound on the speed-reference excitation (steps + multisine peak)", unit="rev/s", gt=0, le=10
    )
    abort_error_rps: float = option(
        3.0, doc="abort when the measured speed strays this far from the speed reference", unit="rev/s",
        gt=0, le=20,
    )  # fmt: skip
    min_rps: float = option(
        5.0, doc="the aperture spins at least this fast (after the excitation) during identify", unit="rev/s",
        gt=0,
    )  # fmt: skip
    seed: int = option(1, doc="random seed of the step order, multisine phases and PRBS", ge=0)

    def __post_init__(self) -> None:
        check(self)
        for kind in self.kinds:
            if kind not in EXCITATION_KINDS:
                raise FieldError(
                    "kinds", f"unknown excitation {kind!r}: use any of {', '.join(EXCITATION_KINDS)}"
                )
        if not self.kinds:
            raise FieldError("kinds", f"give at least one of {', '.join(EXCITATION_KINDS)}")
        if self.seconds > self.max_seconds:
            raise FieldError(
                "seconds", f"must be at most max_seconds ({self.max_seconds:g} s), got {self.seconds:g}"
            )
        if self.multisine_min_hz >= self.multisine_max_hz:
            raise FieldError(
                "multisine_min_hz",
                f"must be below multisine_max_hz ({self.multisine_max_hz:g} Hz), "
                f"got {self.multisine_min_hz:g}",
            )
        if self.multisine_max_hz > self.table_rate_hz / 10:
            raise FieldError(
                "multisine_max_hz",
                f"must be at most table_rate_hz / 10 ({self.table_rate_hz / 10:g} Hz), got "
                f"{self.multisine_max_hz:g}: ten rows per period keep the sine a sine",
            )
        if self.prbs_clock_s * self.table_rate_hz < 1 - 1e-9:
            raise FieldError(
                "prbs_clock_s",
                f"must be at least one table row (1/table_rate_hz = {1 / self.table_rate_hz:g} s), "
                f"got {self.prbs_clock_s:g}",
            )
        speed = self.speed_excitation_rps
        if speed > self.max_delta_rps:
            key = "step_rps" if "steps" in self.kinds else "multisine_rps"
            raise FieldError(
                key,
                f"the speed excitation (step_rps + multisine_rps of the kinds on) reaches {speed:g} "
                f"rev/s, beyond max_delta_rps ({self.max_delta_rps:g}): lower them or raise that bound",
            )

    @property
    def speed_excitation_rps(self) -> float:
        """The largest excursion of the speed reference the kinds on can make."""
        return (self.step_rps if "steps" in self.kinds else 0.0) + (
            self.multisine_rps if "multisine" in self.kinds else 0.0
        )


@dataclass(frozen=True, kw_only=True)
class Config:
    plant: PlantParams = option(doc="drive parameters")
    drive: DriveConfig = option(DriveConfig())
    control: ControlConfig = option(doc="control loop")
    geometry: GeometryConfig = option(GeometryConfig())
    sil_profile: str | None = option(None, doc="SIL profile file, relative to this file")
    sil: SilConfig | None = option(None, doc="SIL profile inline (instead of sil_profile)")
    reproduction: Reproduction | None = option(None, doc="paper figures to reproduce")
    scan: ScanSettings = option(ScanSettings(), doc="scan pipeline (baseline from geometry)")
    imu: ImuSettings = option(ImuSettings(), doc="the two MPU6050s")
    can: CanSettings = option(CanSettings(), doc="CAN bridge to a robot (off by default)")
    devices: DevicesConfig = option(DevicesConfig(), doc="hardware or SIL backend per device")
    mcu: McuSettings = option(McuSettings(), doc="the MCU: serial link, rates, fail-safe times")
    daemon: DaemonSettings = option(DaemonSettings(), doc="tvsd's own periods and limits")
    web: WebSettings = option(WebSettings(), doc="the live web view (off by default)")
    identify: IdentifySettings = option(IdentifySettings(), doc="tvsctl identify's excitation and limits")

    @property
    def sil_or_default(self) -> SilConfig:
        return self.sil if self.sil is not None else SilConfig()


def config_dir() -> Path:
    """Where the shipped config files are: $TVSD_CONFIG_DIR, the source tree, or /etc/tvsd."""
    env = os.environ.get("TVSD_CONFIG_DIR")
    if env:
        return Path(env)
    in_tree = Path(__file__).resolve().parent.parent / "config"
    return in_tree if in_tree.is_dir() else Path("/etc/tvsd")


PARAM_SETS = {"default": "tvsd.yaml", "paper": "paper.yaml"}


def load_config(path: str | Path | None = None, *, params: str | None = None) -> Config:
    """Load a scanner config: an explicit file, or a named parameter set (default / paper)."""
    if path is None:
        name = params or "default"
        if name not in PARAM_SETS:
            raise UsageError(f"unknown parameter set '{name}'; choose one of {', '.join(PARAM_SETS)}")
        path = config_dir() / PARAM_SETS[name]
    path = Path(path)
    data = load_yaml(path)
    cfg: Config = build(Config, data, Where(path, data.line, ""))
    if cfg.sil is not None and cfg.sil_profile is not None:
        line = data.key_lines.get("sil", data.line)
        raise ConfigError(f"{path}:{line}: sil: give either 'sil' or 'sil_profile', not both")
    scan_keys = getattr(data.get("scan"), "key_lines", {})
    if "baseline_m" in scan_keys:
        raise ConfigError(
            f"{path}:{scan_keys['baseline_m']}: scan.baseline_m: set geometry.baseline_m instead "
            "(one baseline for the whole scanner)"
        )
    cfg = dataclasses.replace(cfg, scan=dataclasses.replace(cfg.scan, baseline_m=cfg.geometry.baseline_m))
    if cfg.sil_profile is not None:
        profile = path.parent / cfg.sil_profile
        line = data.key_lines.get("sil_profile", data.line)
        try:
            found = profile.is_file()
        except (OSError, ValueError) as exc:  # a name too long, a NUL byte
            why = exc.strerror if isinstance(exc, OSError) else str(exc)
            raise ConfigError(
                f"{path}:{line}: sil_profile: cannot use {_short(cfg.sil_profile)} ({why}); "
                f"give a file path relative to {path.name}"
            ) from None
        if not found:
            raise ConfigError(
                f"{path}:{line}: sil_profile: no such file {profile}; "
                f"give a file path relative to {path.name}"
            )
        cfg = dataclasses.replace(cfg, sil=load_sil_profile(profile))
    _check_effects(cfg.sil_or_default, path, data)
    _check_identify(cfg, path, data)
    return cfg


def _short(text: str) -> str:
    return repr(text) if len(text) <= 60 else repr(text[:57]) + f"... ({len(text)} characters)"


def _check_identify(cfg: Config, path: Path, data: dict[str, object]) -> None:
    """The excitation's bounds against the drive's and the daemon's (rules across sections)."""
    ident = cfg.identify
    lines = getattr(data.get("identify"), "key_lines", {})
    top = getattr(data, "key_lines", {}).get("identify", 1)
    if ident.prbs_v > 0.5 * cfg.drive.u_max_v and "prbs" in ident.kinds:
        raise ConfigError(
            f"{path}:{lines.get('prbs_v', top)}: identify.prbs_v: {ident.prbs_v:g} V is more than half of "
            f"drive.u_max_v ({cfg.drive.u_max_v:g} V): the law would have no room left; lower it"
        )
    if ident.min_rps + ident.speed_excitation_rps > cfg.daemon.max_rps:
        raise ConfigError(
            f"{path}:{lines.get('min_rps', top)}: identify.min_rps: {ident.min_rps:g} rev/s plus the "
            f"excitation ({ident.speed_excitation_rps:g}) exceeds daemon.max_rps ({cfg.daemon.max_rps:g})"
        )


def load_sil_profile(path: Path) -> SilConfig:
    data = load_yaml(path)
    sil: SilConfig = build(SilConfig, data, Where(path, data.line, ""))
    _check_effects(sil, path, data)
    return sil


def _check_effects(sil: SilConfig, path: Path, data: dict[str, object]) -> None:
    from tvsd.causes import parse_effects  # the vocabulary owns the syntax

    try:
        parse_effects(sil.effects)
    except UsageError as exc:
        lines = getattr(data, "key_lines", {})
        line = lines.get("effects", lines.get("sil", 1))
        raise ConfigError(f"{path}:{line}: effects: {exc}") from None
