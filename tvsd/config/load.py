"""Loading a config: the file (or a named parameter set) → `Config`, every section built and checked
with file:line errors (`tvsd.schema`), then the rules across sections and files: one baseline for
the scanner, the SIL profile file, the effects' syntax, the excitation's room in the drive and the
daemon's speed bound."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

from tvsd.config.daemon import DaemonSettings, DevicesConfig, WebSettings
from tvsd.config.identify import IdentifySettings
from tvsd.config.scanner import (
    ControlConfig,
    DriveConfig,
    GeometryConfig,
    PlantParams,
    Reproduction,
    SilConfig,
)
from tvsd.errors import ConfigError, UsageError
from tvsd.hw.can.settings import CanSettings
from tvsd.hw.imu_settings import ImuSettings
from tvsd.hw.mcu.settings import McuSettings
from tvsd.scan.settings import ScanSettings
from tvsd.schema import Where, build, load_yaml, option


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


CHECKOUT_DIR = Path(__file__).resolve().parents[2] / "config"  # tvsd/config/load.py → the checkout
ETC_DIR = Path("/etc/tvsd")
# config/*.yaml as an installed wheel carries them (setup.py copies them there)
SHIPPED_DIR = Path(__file__).resolve().parent / "shipped"


def config_dir() -> Path:
    """Where the config files are: $TVSD_CONFIG_DIR, the source tree, /etc/tvsd, or (an installed
    wheel with no /etc/tvsd/tvsd.yaml) the copies shipped in the package — so `tvsctl sim … --params
    paper` and `tvsd --sil` work from a plain `pip install` (it said "/etc/tvsd/tvsd.yaml: no such
    config file; … see config/" where there is no config/)."""
    env = os.environ.get("TVSD_CONFIG_DIR")
    if env:
        return Path(env)
    if CHECKOUT_DIR.is_dir():
        return CHECKOUT_DIR
    if (ETC_DIR / "tvsd.yaml").is_file() or not (SHIPPED_DIR / "tvsd.yaml").is_file():
        return ETC_DIR
    return SHIPPED_DIR


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
            what = "not a regular file:" if profile.exists() else "no such file"
            raise ConfigError(
                f"{path}:{line}: sil_profile: {what} {_short(str(profile))}; "  # quoted: one line
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
