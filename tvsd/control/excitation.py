"""The excitation `tvsctl identify` plays on top of scanning: a table the control thread reads.

Three kinds (config `identify:`), summed:
- `steps`: the speed reference steps between −step_rps, 0 and +step_rps in a random order (no level
  twice in a row, so every hold is a step), each held step_hold_s. Through the scanning ramp the
  steps become bounded-acceleration moves: the law and the drive see both directions of change.
- `multisine`: lines from multisine_min_hz to multisine_max_hz on the speed reference, harmonics of
  the lowest, at most MAX_LINES of them log-spaced, with Schroeder phases (a low crest factor), scaled
  to a peak of multisine_rps and faded in and out over a period of the lowest line.
- `prbs`: a maximal-length pseudo-random binary sequence, ±prbs_v added to the drive voltage after
  the law, one bit per prbs_clock_s. In closed loop the law answers it; what the doctor needs is
  that the applied voltage carries power the disturbance does not (the recording keeps that voltage).
- `reversal` (asked for; not in the default kinds): once, in the middle of the run, the speed
  reference goes through zero to reversal_rps the other way, holds reversal_hold_s, and comes
  back, through the scanning ramp (control.scan_accel_rps2). It gives what one direction of
  rotation cannot: friction in both directions (friction asymmetry) and the command passing
  through zero, against the motion while the ramp brakes (a dead zone, which otherwise is an
  offset that Coulomb friction absorbs). Its table rows need the setpoint and the ramp rate.
The speed excitation stays within ±max_delta_rps (checked when the config is loaded), the reversal
within reversal_rps the other way; a row is 1/table_rate_hz long and the 10 kHz loop holds it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tvsd.config import IdentifySettings
from tvsd.errors import UsageError

MAX_LINES = 24
PRBS_BITS = 15  # x^15 + x^14 + 1: a period of 32767 bits (131 s at 4 ms)


@dataclass(frozen=True)
class Excitation:
    """One excitation: rows of a speed-reference offset (rev/s) and a voltage offset (V)."""

    period_s: float
    d_rps: np.ndarray
    d_volts: np.ndarray
    kinds: tuple[str, ...]
    seed: int
    lines_hz: tuple[float, ...] = ()  # the multisine's frequencies: recorded, so the doctor skips them


    @property
    def seconds(self) -> float:
        return len(self.d_rps) * self.period_s

    def times(self) -> np.ndarray:
        """Each row's start, s after the excitation starts."""
        return np.arange(len(self.d_rps)) * self.period_s

    def describe(self) -> dict[str, object]:
        return {
            "kinds": list(self.kinds),
            "seconds": self.seconds,
            "rows": len(self.d_rps),
            "period_s": self.period_s,
            "seed": self.seed,
            "peak_rps": float(np.max(np.abs(self.d_rps))) if len(self.d_rps) else 0.0,
            "peak_volts": float(np.max(np.abs(self.d_volts))) if len(self.d_volts) else 0.0,
            "lines_hz": list(self.lines_hz),
        }


def build(s: IdentifySettings, setpoint_rps: float = 0.0, accel_rps2: float = 0.0) -> Excitation:
    """The table of `s` (its kinds, duration, amplitudes, seed); a reversal needs the speed
    setpoint (its magnitude: the daemon signs the table) and the scanning ramp's rate."""
    n = round(s.seconds * s.table_rate_hz)
    t = np.arange(n) / s.table_rate_hz
    rng = np.random.default_rng(s.seed)
    d_rps = np.zeros(n)
    d_volts = np.zeros(n)
    lines: tuple[float, ...] = ()
    if "steps" in s.kinds and s.step_rps > 0:
        d_rps += steps(n, round(s.step_hold_s * s.table_rate_hz), s.step_rps, rng)
    if "multisine" in s.kinds and s.multisine_rps > 0:
        d_rps += multisine(t, s.multisine_min_hz, s.multisine_max_hz, s.multisine_rps)
        lines = tuple(float(f) for f in multisine_lines(s.multisine_min_hz, s.multisine_max_hz))
    if "prbs" in s.kinds and s.prbs_v > 0:
        d_volts += s.prbs_v * prbs(n, max(1, round(s.prbs_clock_s * s.table_rate_hz)), rng)
    if "reversal" in s.kinds:
        d_rps += reversal(t, s, abs(setpoint_rps), accel_rps2)
    return Excitation(1.0 / s.table_rate_hz, d_rps, d_volts, tuple(s.kinds), s.seed, lines)


def reversal(t: np.ndarray, s: IdentifySettings, setpoint_rps: float, accel_rps2: float) -> np.ndarray:
    """The offset that takes the reference from `setpoint_rps` to −reversal_rps for the ramp down
    and reversal_hold_s, centred in the run (the ramp back follows)."""
    if setpoint_rps <= 0 or accel_rps2 <= 0:
        raise UsageError("identify: a reversal needs the speed setpoint and control.scan_accel_rps2")
    swing = setpoint_rps + s.reversal_rps
    ramp = swing / accel_rps2
    span = 2 * ramp + s.reversal_hold_s
    seconds = len(t) / s.table_rate_hz
    if span > seconds:
        raise UsageError(
            f"identify: the reversal ({swing:g} rev/s at {accel_rps2:g} rev/s² both ways, held "
            f"{s.reversal_hold_s:g} s) takes {span:.3g} s; the run is {seconds:g} s: give --seconds "
            f"{math.ceil(span + 1)} or more"
        )
    start = 0.5 * (seconds - span)
    return np.where((t >= start) & (t < start + ramp + s.reversal_hold_s), -swing, 0.0)


def steps(n: int, hold: int, size: float, rng: np.random.Generator) -> np.ndarray:
    """Levels −size, 0, +size in a random order, never the same twice in a row, `hold` rows each;
    it starts away from 0 (the first hold is a step)."""
    levels = np.array([-size, 0.0, size])
    out = np.empty(n)
    current = 1  # index of 0
    for start in range(0, n, hold):
        current = int(rng.choice([k for k in range(3) if k != current]))
        out[start : start + hold] = levels[current]
    return out


def multisine(t: np.ndarray, f_min: float, f_max: float, peak: float) -> np.ndarray:
    """Harmonics of f_min up to f_max (at most MAX_LINES, log-spaced), Schroeder phases, scaled to
    `peak` and faded in/out with a raised cosine over 1/f_min."""
    ks = _harmonics(f_min, f_max)
    phases = -math.pi * ks * (ks - 1) / len(ks)
    x = np.sum(np.cos(2 * math.pi * f_min * ks[:, None] * t[None, :] + phases[:, None]), axis=0)
    x *= peak / max(float(np.max(np.abs(x))), 1e-12)
    fade = min(1.0 / f_min, 0.5 * float(t[-1] if len(t) else 0.0))
    if fade > 0:
        w = np.ones_like(t)
        head, tail = t < fade, t > t[-1] - fade
        w[head] = 0.5 - 0.5 * np.cos(math.pi * t[head] / fade)
        w[tail] = 0.5 - 0.5 * np.cos(math.pi * (t[-1] - t[tail]) / fade)
        x *= w
    return x


def _harmonics(f_min: float, f_max: float) -> np.ndarray:
    k_max = math.floor(f_max / f_min + 1e-9)
    return np.unique(np.round(np.geomspace(1, k_max, min(MAX_LINES, k_max))).astype(int))


def multisine_lines(f_min: float, f_max: float) -> np.ndarray:
    """The multisine's frequencies, Hz: what a recording declares as `# excitation_hz:`."""
    return f_min * _harmonics(f_min, f_max)


def prbs(n: int, hold: int, rng: np.random.Generator) -> np.ndarray:
    """±1, a maximal-length 15-bit LFSR sequence from a random nonzero state, `hold` rows a bit."""
    state = int(rng.integers(1, 1 << PRBS_BITS))
    bits = np.empty(-(-n // hold))
    for i in range(len(bits)):
        new = ((state >> 14) ^ (state >> 13)) & 1
        state = ((state << 1) | new) & ((1 << PRBS_BITS) - 1)
        bits[i] = 1.0 if new else -1.0
    return np.repeat(bits, hold)[:n]
