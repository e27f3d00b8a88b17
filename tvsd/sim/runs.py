"""Offline simulation runs on the drive model: step responses, spin-ups, open-loop inputs.

A `Setup` gathers the packed arrays the kernel reads from a Config; each run returns a `Trace`
(columns of tvsd.model.plant's output, as named arrays). `tvsctl sim`, the benchmarks, the SIL
recordings and the model doctor all go through here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from tvsd.causes import Effect, parse_effects
from tvsd.config import Config, Gains, VibrationConfig
from tvsd.model import effects as E
from tvsd.model import params as P
from tvsd.model import plant as K


@dataclass(frozen=True)
class Trace:
    """A simulated run, decimated: one entry per output row (SI units)."""

    t: np.ndarray
    u: np.ndarray  # command at the row instant, V
    u_mean: np.ndarray  # mean command over the row's interval, V
    u_applied: np.ndarray  # voltage the drive applied (after effects), V
    phi: np.ndarray
    omega: np.ndarray
    omega_mean: np.ndarray  # mean speed over the row's interval
    current: np.ndarray
    disturbance: np.ndarray  # mean disturbance acceleration about the SA axis, rad/s²
    phi_ref: np.ndarray
    slips: int = 0

    @property
    def sample_rate_hz(self) -> float:
        return float(1.0 / (self.t[1] - self.t[0])) if len(self.t) > 1 else math.nan


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

    def controller(self, mode: int, ref: float) -> np.ndarray:
        ctrl = np.zeros(K.N_CTRL)
        ctrl[K.C_MODE] = mode
        ctrl[K.C_GP], ctrl[K.C_GD], ctrl[K.C_GR], ctrl[K.C_G0] = self.gains.as_tuple()
        ctrl[K.C_UMAX] = self.u_max
        ctrl[K.C_REF] = ref
        ctrl[K.C_ACCEL] = self.scan_accel_rps2
        ctrl[K.C_MAXLAG] = self.max_lag_rad
        ctrl[K.C_FF] = 1.0 if self.scan_feedforward else 0.0
        ctrl[K.C_DIV] = self.substeps
        return ctrl


def _run(
    setup: Setup,
    mode: int,
    ref: float,
    n_periods: int,
    decim: int,
    u_in: np.ndarray | None = None,
    state: np.ndarray | None = None,
) -> Trace:
    """Run n_periods controller periods; one output row every `decim` periods."""
    out = np.zeros((n_periods // decim, K.N_OUT))
    st = np.zeros(K.N_STATE) if state is None else state
    u = np.zeros(1) if u_in is None else np.ascontiguousarray(u_in, dtype=np.float64)
    sub = setup.substeps
    slips = K.run(
        st,
        setup.plant,
        setup.effects,
        setup.vibration,
        setup.controller(mode, ref),
        setup.dt / sub,
        n_periods * sub,
        u,
        decim * sub,
        setup.seed,
        out,
    )
    return Trace(
        t=out[:, K.O_T],
        u=out[:, K.O_U],
        u_mean=out[:, K.O_U_MEAN],
        u_applied=out[:, K.O_UAPP],
        phi=out[:, K.O_PHI],
        omega=out[:, K.O_OMEGA],
        omega_mean=out[:, K.O_OMEGA_MEAN],
        current=out[:, K.O_I],
        disturbance=out[:, K.O_DIST_MEAN],
        phi_ref=out[:, K.O_PHI_REF],
        slips=int(slips),
    )


def step_response(setup: Setup, ref_rad: float, seconds: float) -> Trace:
    """Position mode from rest at φ = 0 to φr (paper Table 6, Figs. 14–16); full-rate output."""
    return _run(setup, K.MODE_POSITION, ref_rad, round(seconds / setup.dt), 1)


def spin(setup: Setup, rps: float, seconds: float, decim: int = 1) -> Trace:
    """Scanning mode from rest: the speed reference ramps to `rps` and the law tracks it."""
    return _run(setup, K.MODE_SCAN, rps, round(seconds / setup.dt), decim)


def open_loop(
    setup: Setup, u_per_period: np.ndarray, decim: int = 1, state: np.ndarray | None = None
) -> Trace:
    """Apply a given voltage command, one value per controller period (setup.dt)."""
    return _run(setup, K.MODE_OPEN, 0.0, len(u_per_period), decim, u_per_period, state)
