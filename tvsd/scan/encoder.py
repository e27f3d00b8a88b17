"""β from the motor encoder, where there is one: the shaft angle read at both pulses.

The MCU samples the quadrature count every control period (10 kHz) on the same timer as the
pulses. The angle at a pulse comes from the samples within ±`half_window_s`, read at the
pulse (see `EncoderLog.angle` for how the count quantisation is bounded). Over ±0.5 ms the speed
changes too little to bend the line (the literal SDE at σv = 0.8069 moves the angle off a line by
~1e-6 rad there, ~1e-3 count).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tvsd.scan.pulses import CleanPulses

F64 = NDArray[np.float64]
_WIDE = 5  # the speed's window, in read windows: ±2.5 ms, where the SDE moves the speed < 0.1 %
_CHUNK = 4096  # rows per pass: bounds the (rows, samples) work arrays


@dataclass(frozen=True)
class EncoderLog:
    t: F64  # s, MCU time of each sample, uniform
    counts: NDArray[np.int64]  # cumulative quadrature count
    counts_per_rev: int

    def angle(self, t: F64, half_window_s: float) -> tuple[F64, F64, F64]:
        parts = [self._angle(t[i : i + _CHUNK], half_window_s) for i in range(0, max(len(t), 1), _CHUNK)]
        return tuple(np.concatenate([p[k] for p in parts]) for k in range(3))  # type: ignore[return-value]

    def _angle(self, t: F64, half_window_s: float) -> tuple[F64, F64, F64]:
        """Angle (rad) at each t, the variance of its quantisation error, and the speed (rad/s).

        The speed s comes from a least-squares line over a window `_WIDE` times longer (where
        quantisation hardly matters: < 0.02 count at the read window's ends). With s known, the
        counts c_i at τ_i (time from t) bound the count at t to the band
        [max(c_i − s·τ_i), min(c_i − s·τ_i) + 1) (floor quantisation): its middle is the estimate,
        and the true count is uniform in it (variance w²/12). The band is ~1/N wide when the
        samples' sub-count phases spread, and a whole count when the shaft advances a whole number
        of counts per sample and every sample sees the same phase — where a dither model, 1/(12·N),
        would be optimistic by √N.
        """
        dt = float(self.t[1] - self.t[0])
        half = max(round(half_window_s / dt), 1)
        wide = _WIDE * half
        centre = np.clip(np.searchsorted(self.t, t), wide, len(self.t) - wide - 1)
        idx_w = centre[:, None] + np.arange(-wide, wide + 1)[None, :]
        tau_w = self.t[idx_w] - t[:, None]
        c_w = self.counts[idx_w].astype(np.float64)
        tm, cm = tau_w.mean(axis=1), c_w.mean(axis=1)
        sxx = np.sum((tau_w - tm[:, None]) ** 2, axis=1)
        slope = np.sum((tau_w - tm[:, None]) * (c_w - cm[:, None]), axis=1) / sxx
        inner = slice(wide - half, wide + half + 1)
        tau, cs = tau_w[:, inner], c_w[:, inner]
        resid = cs - slope[:, None] * tau
        rows = np.arange(len(t))
        i_lo, i_hi = resid.argmax(axis=1), resid.argmin(axis=1)
        lo, hi = resid[rows, i_lo], resid[rows, i_hi] + 1.0
        width = hi - lo
        # The slope's own error (dither model of the wide fit) tilts the band about t by δs·τ of
        # the two samples that bound it.
        tilt = (1.0 / 12.0) / sxx * 0.5 * (tau[rows, i_lo] ** 2 + tau[rows, i_hi] ** 2)
        # An empty band: the speed changed within the window more than a line allows; fall back
        # to the least-squares line with a whole count of uncertainty.
        empty = width <= 0.0
        mean = np.where(empty, cm - slope * tm + 0.5, 0.5 * (lo + hi))
        var = np.where(empty, 1.0 / 12.0, width * width / 12.0) + tilt
        scale = 2.0 * math.pi / self.counts_per_rev
        return mean * scale, var * scale * scale, slope * scale

    def covers(self, t: F64, half_window_s: float) -> NDArray[np.bool_]:
        reach = _WIDE * half_window_s
        return (t - reach > self.t[0]) & (t + reach < self.t[-1])


def estimate(
    pulses: CleanPulses, enc: EncoderLog, timer_resolution_s: float, half_window_s: float = 5e-4
) -> tuple[F64, F64, F64]:
    """(t, β, σβ) for every optical pulse the encoder log covers, with the zero pulse before it."""
    t_o = pulses.opt_t
    t_z = pulses.zero_t[pulses.opt_idx] if len(t_o) else np.zeros(0)
    ok = enc.covers(t_o, half_window_s) & enc.covers(t_z, half_window_s)
    t_o, t_z = t_o[ok], t_z[ok]
    a_o, v_o, omega = enc.angle(t_o, half_window_s)
    a_z, v_z, _ = enc.angle(t_z, half_window_s)
    beta = a_o - a_z
    # The pulse timestamps' own quantisation moves where the angle is read: ω·U(±res/2) each.
    var = v_o + v_z + 2.0 * omega * omega * timer_resolution_s**2 / 12.0
    return t_o, beta, np.sqrt(var)
