"""The effects library: one entry per cause of docs/architecture.md's vocabulary.

The SIL plant switches them on; the model doctor fits them as candidate extensions. Their names,
parameters and syntax are the vocabulary in tvsd.causes.

For the numba kernels the active effects are packed into one float64 array (`pack`), indexed by the
E_* constants; an effect that is off holds its neutral value (amplitude 0, ratio 1, u_max inf).

What each effect does to the plant (paper eqs. 9–11):
- imbalance   torque A·sin(φ+ψ) added to the shaft (once per revolution);
- cogging     torque A·sin(N·φ + ψ) added to the shaft (N ≥ 2 per revolution; ψ optional, 0);
- resonance   torque A·sin(2π·f·t + ψ) added to the shaft: a line fixed in Hz, not locked to φ;
- saturation  applied voltage clipped to ±u_max;
- deadzone    applied voltage u − u0·sgn(u) for |u| > u0, else 0 (the standard continuous dead zone);
- delay       applied voltage = command delayed by delay_s (linear interpolation between steps);
- friction_asymmetry  every friction term (kv·ω and LuGre) multiplied by `ratio` when ω < 0;
- colored_noise       Δv becomes an Ornstein–Uhlenbeck acceleration with correlation time tau_s;
- drift       one parameter moves linearly from its value to value·(1 + relative_change) over the run.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from tvsd.causes import DRIFT_PARAMETERS, Effect

# Layout of the packed effects array.
E_IMB_AMP, E_IMB_PHASE = 0, 1
E_COG_ORDER, E_COG_AMP = 2, 3
E_RES_FREQ, E_RES_AMP = 4, 5
E_SAT_UMAX = 6
E_DZ_U0 = 7
E_DELAY = 8
E_FRIC_RATIO = 9
E_NOISE_TAU = 10
E_DRIFT_PARAM, E_DRIFT_REL = 11, 12
E_COG_PHASE, E_RES_PHASE = 13, 14
N_EFFECT_SLOTS = 15


def neutral() -> np.ndarray:
    eff = np.zeros(N_EFFECT_SLOTS)
    eff[E_SAT_UMAX] = np.inf
    eff[E_FRIC_RATIO] = 1.0
    eff[E_DRIFT_PARAM] = -1.0
    return eff


def pack(effects: Iterable[Effect]) -> np.ndarray:
    """The float64 array the kernels read (layout: the E_* constants)."""
    eff = neutral()
    for e in effects:
        p = e.params
        if e.name == "imbalance":
            eff[E_IMB_AMP], eff[E_IMB_PHASE] = float(p["amplitude"]), float(p["phase"])
        elif e.name == "cogging":
            eff[E_COG_ORDER], eff[E_COG_AMP] = float(p["order"]), float(p["amplitude"])
            eff[E_COG_PHASE] = float(p.get("phase", 0.0))
        elif e.name == "resonance":
            eff[E_RES_FREQ], eff[E_RES_AMP] = float(p["frequency_hz"]), float(p["amplitude"])
            eff[E_RES_PHASE] = float(p.get("phase", 0.0))
        elif e.name == "saturation":
            eff[E_SAT_UMAX] = float(p["u_max"])
        elif e.name == "deadzone":
            eff[E_DZ_U0] = float(p["u0"])
        elif e.name == "delay":
            eff[E_DELAY] = float(p["delay_s"])
        elif e.name == "friction_asymmetry":
            eff[E_FRIC_RATIO] = float(p["ratio"])
        elif e.name == "colored_noise":
            eff[E_NOISE_TAU] = float(p["tau_s"])
        elif e.name == "drift":
            eff[E_DRIFT_PARAM] = float(DRIFT_PARAMETERS.index(str(p["parameter"])))
            eff[E_DRIFT_REL] = float(p["relative_change"])
    return eff
