"""DESIGN.md's cause vocabulary: each effect's name, meaning and parameters (units, ranges).

The SIL plant switches these effects on and the model doctor fits them as candidate extensions;
both, and the config loader, read the names and the ``name:key=value,key=value`` syntax from here
(e.g. ``imbalance:amplitude=6e-5,phase=0.5``). What each effect does to the plant, and how the
kernels receive it, is tvsd.model.effects.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from tvsd.errors import UsageError

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


def catalogue_help() -> str:
    lines = []
    for spec in CATALOGUE.values():
        lines.append(f"  {_example(spec):48s} {spec.meaning}")
    return "\n".join(lines)
