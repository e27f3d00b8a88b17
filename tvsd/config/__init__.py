"""Configuration: YAML files in config/ → validated, frozen objects.

Three files ship in config/ (each documented key by key there):
- ``tvsd.yaml``  the scanner: the physically consistent default plant, drive, control, geometry,
  and a pointer to its SIL profile;
- ``sil.yaml``   the simulated plant's environment: vibration, measurement, effects, seed;
- ``paper.yaml`` the paper's parameter set (Table 3 Exp1) and the tables tvsd reproduces.
The numbers and where each comes from are in the files; the decisions are in MODEL-NOTES.md.

One owner a module: `scanner` (plant, drive, control, geometry, SIL environment, reproduction),
`daemon` (devices, daemon, web), `identify` (the excitation), `load` (the composition `Config`,
the files, the rules across sections). The devices' own sections live beside their drivers
(`tvsd.hw`, `tvsd.scan`). Import the names from here.
"""

from tvsd.config.daemon import SOCKET_PATH_MAX, DaemonSettings, DevicesConfig, WebSettings
from tvsd.config.identify import EXCITATION_KINDS, IdentifySettings
from tvsd.config.load import PARAM_SETS, Config, config_dir, load_config, load_sil_profile
from tvsd.config.scanner import (
    ControlConfig,
    DriveConfig,
    Gains,
    GeometryConfig,
    MeasurementConfig,
    PlantParams,
    Reproduction,
    SilConfig,
    VibrationConfig,
)

__all__ = [
    "EXCITATION_KINDS",
    "PARAM_SETS",
    "SOCKET_PATH_MAX",
    "Config",
    "ControlConfig",
    "DaemonSettings",
    "DevicesConfig",
    "DriveConfig",
    "Gains",
    "GeometryConfig",
    "IdentifySettings",
    "MeasurementConfig",
    "PlantParams",
    "Reproduction",
    "SilConfig",
    "VibrationConfig",
    "WebSettings",
    "config_dir",
    "load_config",
    "load_sil_profile",
]
