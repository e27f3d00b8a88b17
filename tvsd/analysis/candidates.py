"""Candidate extensions of the paper's model, one per cause of DESIGN.md's vocabulary.

Each `fit_<cause>` fits the extended inverse model and returns a Candidate with the cause's
parameters under the DESIGN.md names. Scanned parameters (a threshold, a delay, an order, a
frequency) count as parameters in the BIC. `colored_noise` is a property of the noise, tested on
the residual in tvsd.analysis.noise.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from tvsd.analysis.baseline import speed_error
from tvsd.analysis.inverse import Builder, Columns, Fit, Signals, scan
from tvsd.causes import CATALOGUE, Effect
from tvsd.model import effects as E

MAX_COGGING_ORDER = 24
MAX_DELAY_S = 0.05


@dataclass(frozen=True)
class Candidate:
    cause: str
    effect: dict[str, float | str]
    fit: Fit
    delta_bic: float  # in-sample BIC of the baseline minus this model's: > 0 favours the extension
    builders: Mapping[str, Builder]  # the columns of the extended model
    y_of: Callable[[Columns], np.ndarray]  # the effort rows it explains, for any recording
    input_transform: Callable[[np.ndarray], np.ndarray] | None = None

    def effect_array(self) -> np.ndarray:
        """The effects-library array for simulating this extension."""
        keys = {p.name for p in CATALOGUE[self.cause].params} if self.cause in CATALOGUE else set()
        params = {k: v for k, v in self.effect.items() if k in keys}
        if self.cause == "friction_asymmetry":
            return E.neutral()  # simulated through the direction-split friction instead
        return E.pack([Effect(self.cause, params)])


def _plain(cols: Columns) -> np.ndarray:
    return cols.y


def _cand(
    cause: str,
    effect: dict[str, float | str],
    fit: Fit,
    base: Fit,
    builders: Mapping[str, Builder],
    y_of: Callable[[Columns], np.ndarray] = _plain,
    transform: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Candidate:
    return Candidate(cause, effect, fit, base.bic - fit.bic, builders, y_of, transform)


def _harmonic(order: int) -> tuple[Builder, Builder]:
    return (lambda s: s.band(np.sin(order * s.phi)), lambda s: s.band(np.cos(order * s.phi)))


def fit_imbalance(cols: Columns, base: Fit) -> Candidate:
    sin1, cos1 = _harmonic(1)
    builders = cols.with_base({"s1": sin1, "c1": cos1})
    fit = cols.fit(cols.y, builders)
    cs, cc = fit.value("s1"), fit.value("c1")
    # −A·sin(φ+ψ) = cs·sin φ + cc·cos φ on the effort side
    effect: dict[str, float | str] = {
        "order": 1,
        "amplitude": math.hypot(cs, cc),
        "phase": math.atan2(-cc, -cs),
    }
    return _cand("imbalance", effect, fit, base, builders)


def fit_cogging(cols: Columns, base: Fit) -> Candidate:
    best: tuple[int, Fit, dict[str, Builder]] | None = None
    for order in range(2, MAX_COGGING_ORDER + 1):
        sin_n, cos_n = _harmonic(order)
        builders = cols.with_base({"sN": sin_n, "cN": cos_n})
        fit = cols.fit(cols.y, builders, scanned=1)
        if best is None or fit.rss < best[1].rss:
            best = (order, fit, builders)
    assert best is not None
    order, fit, builders = best
    amplitude = math.hypot(fit.value("sN"), fit.value("cN"))
    return _cand("cogging", {"order": order, "amplitude": amplitude}, fit, base, builders)


def fit_resonance(cols: Columns, base: Fit) -> Candidate:
    """A line fixed in Hz: start at the residual's strongest spectral peak, refine f by scanning."""
    from scipy.signal import welch

    t_rows = cols.prep.t_rows
    fs_rows = 1.0 / float(np.median(np.diff(t_rows)))
    f, pxx = welch(base.residual, fs=fs_rows, nperseg=min(len(base.residual), int(8 * fs_rows)))
    # The strongest line relative to its neighbourhood: the residual's background is not flat.
    from scipy.ndimage import median_filter

    prominence = pxx / np.maximum(median_filter(pxx, size=41, mode="nearest"), 1e-300)
    valid = (f > 1.0) & (f < 0.8 * fs_rows / 2)
    f0 = float(f[valid][np.argmax(prominence[valid])])
    df = float(f[1] - f[0])

    def builders(freq: float) -> dict[str, Builder]:
        return cols.with_base(
            {
                "sR": lambda s: s.band(np.sin(2 * math.pi * freq * s.t)),
                "cR": lambda s: s.band(np.cos(2 * math.pi * freq * s.t)),
            }
        )

    freq, _ = scan(lambda fr: cols.fit(cols.y, builders(fr)).rss, np.linspace(f0 - df, f0 + df, 9))
    chosen = builders(freq)
    fit = cols.fit(cols.y, chosen, scanned=1)
    amplitude = math.hypot(fit.value("sR"), fit.value("cR"))
    return _cand("resonance", {"frequency_hz": freq, "amplitude": amplitude}, fit, base, chosen)


def _input_scan(
    cols: Columns,
    base: Fit,
    cause: str,
    key: str,
    transform: Callable[[float], Callable[[np.ndarray], np.ndarray]],
    grid: np.ndarray,
) -> Candidate:
    u = cols.prep.data.u
    cmd = cols.command_transform or (lambda v: v)

    def score(v: float) -> float:
        applied = transform(v)(u)
        return speed_error(cols, cols.fit(cols.effort(applied), cols.base), cmd(applied))

    x, _ = scan(score, grid)
    chosen = transform(x)
    fit = cols.fit(cols.effort(chosen(u)), cols.base, scanned=1)
    return _cand(cause, {key: x}, fit, base, cols.base, lambda c: c.effort(chosen(c.prep.data.u)), chosen)


def _clip(x: float) -> Callable[[np.ndarray], np.ndarray]:
    return lambda u: np.clip(u, -x, x)


def _dead(x: float) -> Callable[[np.ndarray], np.ndarray]:
    return lambda u: np.where(np.abs(u) <= x, 0.0, u - np.sign(u) * x)


def fit_saturation(cols: Columns, base: Fit) -> Candidate:
    top = float(np.max(np.abs(cols.prep.data.u)))
    return _input_scan(cols, base, "saturation", "u_max", _clip, np.linspace(0.2 * top, top, 41))


def fit_deadzone(cols: Columns, base: Fit) -> Candidate:
    top = float(np.max(np.abs(cols.prep.data.u)))
    return _input_scan(cols, base, "deadzone", "u0", _dead, np.linspace(0.0, 0.5 * top, 41))


def fit_delay(cols: Columns, base: Fit) -> Candidate:
    d = cols.prep.data
    dt = 1.0 / d.sample_rate_hz

    def shifted(x: float) -> Callable[[np.ndarray], np.ndarray]:
        return lambda u: np.interp(d.t - x, d.t, u, left=0.0)

    return _input_scan(cols, base, "delay", "delay_s", shifted, np.arange(0.0, MAX_DELAY_S + dt / 2, dt))


def fit_friction_asymmetry(cols: Columns, base: Fit) -> Candidate:
    """Separate friction by direction (as EMPS' asymmetric reference); ratio at the typical speed."""
    builders = {k: v for k, v in cols.base.items() if k not in ("kv", "tau_c", "d_stribeck")}

    def part(sign: float, kind: str) -> Builder:
        def column(s: Signals) -> np.ndarray:
            side = s.speed < 0 if sign < 0 else s.speed >= 0
            return s.speed * side if kind == "kv" else s.band(sign * side)

        return column

    builders.update(
        {
            "kv_pos": part(1, "kv"),
            "kv_neg": part(-1, "kv"),
            "tau_c_pos": part(1, "tc"),
            "tau_c_neg": part(-1, "tc"),
        }
    )
    fit = cols.fit(cols.y, builders)
    w = cols.prep.speed
    moving = np.abs(w) > 0.1 * np.max(np.abs(w))
    speed = float(np.median(np.abs(w[moving]))) if np.any(moving) else 1.0
    level_pos = fit.value("kv_pos") * speed + fit.value("tau_c_pos")
    level_neg = fit.value("kv_neg") * speed + fit.value("tau_c_neg")
    ratio = level_neg / level_pos if level_pos > 0 else math.nan
    effect: dict[str, float | str] = {
        "ratio": ratio,
        "at_speed": speed,
        "kv_pos": fit.value("kv_pos"),
        "kv_neg": fit.value("kv_neg"),
        "tau_c_pos": fit.value("tau_c_pos"),
        "tau_c_neg": fit.value("tau_c_neg"),
    }
    return _cand("friction_asymmetry", effect, fit, base, builders)


def fit_drift(cols: Columns, base: Fit) -> list[Candidate]:
    """A parameter changing linearly over the record: one candidate per parameter that can drift
    (kv and R, say, look alike in steady running; the held-out simulation tells them apart)."""
    options: list[tuple[str, Fit, float, Mapping[str, Builder], Callable[[Columns], np.ndarray]]] = []
    # The column t/T·x with coefficient c makes the parameter p + c·t/T: relative to its value
    # at the start (the extended fit's p), not to the baseline's average.
    linear: dict[str, tuple[Builder, str]] = {
        "kv": (lambda s: s.band(s.t_frac * s.speed), "kv"),
        "J": (lambda s: s.band(s.t_frac * s.accel), "J"),
        "friction": (lambda s: s.band(s.t_frac * np.sign(s.speed)), "tau_c"),
    }
    for name, (column, param) in linear.items():
        builders = cols.with_base({"drift": column})
        fit = cols.fit(cols.y, builders, scanned=1)
        start = fit.value(param)
        rel = fit.value("drift") / start if start != 0 else math.nan
        options.append((name, fit, rel, builders, _plain))
    grid = np.linspace(-0.8, 2.0, 57)
    # R drifts: the drive's effort scales by 1/(1 + c·t/T); kM drifts: kM and kb both scale.
    scaled: dict[str, Callable[[Columns, float], np.ndarray]] = {
        "R": lambda k, c: k.effort(b_scale=1 / (1 + c * k.t_frac), bw_scale=1 / (1 + c * k.t_frac)),
        "kM": lambda k, c: k.effort(b_scale=1 + c * k.t_frac, bw_scale=(1 + c * k.t_frac) ** 2),
    }
    for name, effort in scaled.items():
        c, _ = scan(lambda x, e=effort: cols.fit(e(cols, x), cols.base).rss, grid)  # type: ignore[misc]
        options.append(
            (name, cols.fit(effort(cols, c), cols.base, scanned=1), c, cols.base, _scaled(effort, c))
        )
    return [
        _cand("drift", {"parameter": name, "relative_change": rel}, fit, base, builders, y_of)
        for name, fit, rel, builders, y_of in options
    ]


def _scaled(effort: Callable[[Columns, float], np.ndarray], c: float) -> Callable[[Columns], np.ndarray]:
    return lambda k: effort(k, c)


DETERMINISTIC: dict[str, Callable[[Columns, Fit], Candidate | list[Candidate]]] = {
    "imbalance": fit_imbalance,
    "cogging": fit_cogging,
    "resonance": fit_resonance,
    "saturation": fit_saturation,
    "deadzone": fit_deadzone,
    "delay": fit_delay,
    "friction_asymmetry": fit_friction_asymmetry,
    "drift": fit_drift,
}
