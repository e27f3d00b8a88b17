"""The drive set-up of one control session: the packed arrays the kernels read, built from a Config.

The control thread (tvsd.control.runner) and the offline simulation (tvsd.sim) both start from a
`Setup`: plant parameters, effects and vibration of the simulated plant, gains and limits of the
law, the loop period.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from tvsd.causes import Effect, parse_effects
from tvsd.config import Config, Gains, VibrationConfig
from tvsd.model import effects as E
from tvsd.model import params as P


@dataclass
class Setup:
    """Packed arrays for one simulation, built from a Config and optional overrides."""

    plant: np.ndarray
    effects: np.ndarray
    vibration: np.ndarray
    gains: Gains
    u_max: float
    dt: float
    scan_accel_rps2: float
    max_lag_rad: float
    seed: int
    substeps: int = 1  # plant steps per controller period (finer integration, same loop)
    scan_feedforward: bool = True
    effect_list: tuple[Effect, ...] = field(default_factory=tuple)
    vibration_model: str = "ou"

    @classmethod
    def from_config(
        cls,
        cfg: Config,
        *,
        effects: Iterable[Effect] | None = None,
        gains: Gains | None = None,
        ku: float | None = None,
        vibration: VibrationConfig | None = None,
        seed: int | None = None,
        substeps: int = 1,
    ) -> Setup:
        sil = cfg.sil_or_default
        effect_list = tuple(effects) if effects is not None else parse_effects(sil.effects)
        vib = vibration if vibration is not None else sil.vibration
        return cls(
            plant=P.pack_plant(cfg.plant, ku=ku),
            effects=E.pack(effect_list),
            vibration=P.pack_vibration(vib),
            gains=gains if gains is not None else cfg.control.gains,
            u_max=cfg.drive.u_max_v,
            dt=1.0 / cfg.control.rate_hz,
            scan_accel_rps2=cfg.control.scan_accel_rps2,
            max_lag_rad=cfg.control.max_lag_rad,
            seed=sil.seed if seed is None else seed,
            scan_feedforward=cfg.control.scan_feedforward,
            substeps=substeps,
            effect_list=effect_list,
            vibration_model=vib.model,
        )
