"""Packing of configuration objects into the float64 arrays the numba kernels read."""

from __future__ import annotations

import numpy as np

from tvsd.config import PlantParams, VibrationConfig

# Plant array layout.
P_J, P_KV, P_KM, P_KB, P_R, P_L, P_KU, P_TC, P_TS, P_S0, P_S1, P_S2, P_V0 = range(13)
N_PLANT = 13

# Vibration array layout; V_MODE: 0 off, 1 literal SDE (eq. 12), 2 Ornstein–Uhlenbeck.
V_MODE, V_SIGMA, V_TAU = range(3)
N_VIB = 3
VIB_MODES = {"off": 0, "sde": 1, "ou": 2}


def pack_plant(p: PlantParams, *, ku: float | None = None) -> np.ndarray:
    """Plant parameters in kernel order; `ku` overrides the drive gain (paper runs, MODEL-NOTES §3)."""
    return np.array(
        [
            p.J,
            p.kv,
            p.kM,
            p.kb,
            p.R,
            p.L,
            p.ku if ku is None else ku,
            p.tau_c,
            p.tau_s,
            p.sigma0,
            p.sigma1,
            p.sigma2,
            p.v0,
        ],
        dtype=np.float64,
    )


def pack_vibration(v: VibrationConfig) -> np.ndarray:
    return np.array([VIB_MODES[v.model], v.sigma_v, v.tau_n_s], dtype=np.float64)
