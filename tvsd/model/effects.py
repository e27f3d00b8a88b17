"""The effects library: one entry per cause of DESIGN.md's vocabulary.

The SIL plant switches them on; the model doctor fits them as candidate extensions. Each effect has
the parameter names of the DESIGN.md table. On the command line and in sil.yaml an effect is written
``name:key=value,key=value`` (e.g. ``imbalance:amplitude=6e-5,phase=0.5``).

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

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from tvsd.errors import UsageError

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

# Parameters a drift can move; the index is what the kernel switches on.
DRIFT_PARAMETERS = ("kv", "J", "R", "kM", "friction")


@dataclass(frozen=True)
class Param:
    name: str
    unit: str
    lo: float
    hi: float
    default: float | None = None  # None: required
    integer: bool = False


@dataclass(frozen=True)
class EffectSpec:
    name: str
    meaning: str
    params: tuple[Param, ...]


CATALOGUE: dict[str, EffectSpec] = {
    spec.name: spec
    for spec in (
        EffectSpec(
            "imbalance",
            "torque A·sin(φ+ψ), once per revolution",
            (
                Param("order", "", 1, 1, 1, integer=True),
                Param("amplitude", "N·m", 0, 1.0),
                Param("phase", "rad", -2 * math.pi, 2 * math.pi, 0.0),
            ),
        ),
        EffectSpec(
            "cogging",
            "torque A·sin(N·φ), N ≥ 2 times per revolution",
            (
                Param("order", "", 2, 64, integer=True),
                Param("amplitude", "N·m", 0, 1.0),
                Param("phase", "rad", -2 * math.pi, 2 * math.pi, 0.0),
            ),
        ),
        EffectSpec(
            "resonance",
            "a structural mode: torque line at a fixed frequency",
            (
                Param("frequency_hz", "Hz", 0.1, 2000.0),
                Param("amplitude", "N·m", 0, 1.0),
                Param("phase", "rad", -2 * math.pi, 2 * math.pi, 0.0),
            ),
        ),
        EffectSpec("saturation", "drive clips the voltage at ±u_max", (Param("u_max", "V", 0.01, 400.0),)),
        EffectSpec("deadzone", "drive outputs nothing for |u| < u0", (Param("u0", "V", 0.0, 50.0),)),
        EffectSpec("delay", "transport delay command → applied voltage", (Param("delay_s", "s", 0.0, 0.1),)),
        EffectSpec(
            "friction_asymmetry",
            "friction level differs by direction",
            (Param("ratio", "", 0.05, 20.0),),
        ),
        EffectSpec(
            "colored_noise",
            "vibration disturbance low-pass correlated (OU)",
            (Param("tau_s", "s", 1e-5, 10.0),),
        ),
        EffectSpec(
            "drift",
            "a parameter changes steadily during the run",
            (Param("parameter", "", 0, len(DRIFT_PARAMETERS) - 1), Param("relative_change", "", -0.9, 10.0)),
        ),
    )
}


@dataclass(frozen=True)
class Effect:
    """One effect switched on, with its parameters (names as in DESIGN.md)."""

    name: str
    params: Mapping[str, float | str]

    def __str__(self) -> str:
        body = ",".join(f"{k}={v}" for k, v in self.params.items())
        return f"{self.name}:{body}" if body else self.name


def parse_effect(text: str) -> Effect:
    """Parse ``name:key=value,...``; errors say what was seen and how to write it."""
    name, _, body = text.strip().partition(":")
    name = name.strip()
    if name not in CATALOGUE:
        raise UsageError(f"unknown effect '{name}' in '{text}'; known effects: {', '.join(CATALOGUE)}")
    spec = CATALOGUE[name]
    given: dict[str, str] = {}
    for item in filter(None, (s.strip() for s in body.split(","))):
        key, eq, value = item.partition("=")
        if not eq:
            raise UsageError(f"effect '{text}': '{item}' is not key=value; write e.g. {_example(spec)}")
        given[key.strip()] = value.strip()
    known = {p.name: p for p in spec.params}
    for key in given:
        if key not in known:
            raise UsageError(f"effect {name}: unknown parameter '{key}'; it takes {', '.join(known)}")
    params: dict[str, float | str] = {}
    for p in spec.params:
        if p.name not in given:
            if p.default is None:
                raise UsageError(
                    f"effect {name}: missing '{p.name}' ({p.unit or 'no unit'}); e.g. {_example(spec)}"
                )
            params[p.name] = p.default
            continue
        params[p.name] = _value(name, p, given[p.name])
    return Effect(name, params)


def _value(effect: str, p: Param, raw: str) -> float | str:
    if effect == "drift" and p.name == "parameter":
        if raw not in DRIFT_PARAMETERS:
            raise UsageError(
                f"effect drift: parameter '{raw}' cannot drift; choose {', '.join(DRIFT_PARAMETERS)}"
            )
        return raw
    try:
        value = float(raw)
    except ValueError:
        raise UsageError(f"effect {effect}: {p.name}={raw!r} is not a number") from None
    if not math.isfinite(value) or not p.lo <= value <= p.hi:
        raise UsageError(f"effect {effect}: {p.name}={raw} is outside [{p.lo:g}, {p.hi:g}] {p.unit}".rstrip())
    if p.integer:
        if not value.is_integer():
            raise UsageError(f"effect {effect}: {p.name}={raw} must be a whole number")
        return float(int(value))
    return value


def _example(spec: EffectSpec) -> str:
    body = ",".join(f"{p.name}={p.default if p.default is not None else '…'}" for p in spec.params)
    return f"{spec.name}:{body}"


def parse_effects(texts: Iterable[str]) -> tuple[Effect, ...]:
    effects = tuple(parse_effect(t) for t in texts)
    names = [e.name for e in effects]
    for name in set(names):
        if names.count(name) > 1:
            raise UsageError(f"effect {name} given twice; give each effect once")
    return effects


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


def catalogue_help() -> str:
    lines = []
    for spec in CATALOGUE.values():
        lines.append(f"  {_example(spec):48s} {spec.meaning}")
    return "\n".join(lines)
