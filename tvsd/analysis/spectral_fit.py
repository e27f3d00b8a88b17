"""The residual the spectral tests see, refitted where the doctor's fit leaves a shape that is no
vibration (docs/measurements/colour14.md).

The doctor's coefficients come from GLS whitened by an AR(6) fitted to its own residual. Two
ways that residual's low end is then not the vibration's, both seen on outsider nulls named
`colored_noise`:

- **A coarse encoder's count difference** (256 counts at 2 kHz: a count step of 49 rad/s, the
  slow levels below one count per sample). Its quantisation is 10³–10⁴× the vibration at the
  band's top, and the columns built from the same speed (ω, sgn ω, the Stribeck and absorber
  shapes) carry that error too, so the fit trades coefficients against it (errors in the
  variables): o14033's Stribeck and absorber coefficients came out 10–100× the fine encoder's,
  and their low-frequency part, a few ×10 % of the flat level below 5 Hz, was named a τ 48 ms
  colour. An AR(6) cannot whiten a spectrum that rises 40 dB over the band, so the fit still
  weighs the floor's band. Weighted by the known spectrum instead — the flat level plus the
  quantisation floor (tvsd.analysis.quantisation) — the floor's band has no say: o14033's colour
  p 3.6e-5 → 0.5, as with the fine encoder's coefficients on the same rows (0.53).
- **The drive's fast response** to a command with fast edges: a PRBS at 500 Hz, ω the encoder's
  backward difference (half a sample late). The baseline has the command at two taps (u, u one
  sample ahead); a response between or beyond them leaves a misfit ∝ f⁴·|U(f)|² that rises into
  the band's top (o14073: 1.3–2× the flat level at 20–40 Hz with a fine encoder too), where the
  colour test's band meets the floor. In open loop the command does not depend on the
  vibration, so what a short FIR of the command explains is the drive's and not the vibration's
  colour (the argument of tvsd.analysis.command_levels for a static per-level error): the
  residual loses FIR_TAPS more taps of the command, FIR_TAPS degrees of freedom of thousands of
  rows. In closed loop the command answers the noise and nothing is added.

Both in open loop only (a recorded reference: as before): in closed loop the command answers the
noise, and the closed-loop colour rule's residual was measured on the doctor's own fit
(docs/measurements/closedcolour2.md). Without a floor only the command's taps are added.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_toeplitz
from scipy.signal import welch

from tvsd.analysis import quantisation
from tvsd.analysis.design import _shift
from tvsd.analysis.gls import clear_memory, gls
from tvsd.analysis.noise import BAND_LOW_HZ, band_top
from tvsd.analysis.prep import Prepared
from tvsd.analysis.quantisation import Floor

# the command delayed by these samples (− : advanced) beside the baseline's u(t) and u(t+1): a
# 5-tap FIR over t − 2 … t + 2 (a held command acts a sample late, tvsd.analysis.verdict's
# `sampling_convention`; the outsider's backward-difference ω is half a sample late)
FIR_TAPS = (1, 2, -2)
# flat + an f⁴ floor rising 10⁶ to the rows' Nyquist is whitened to 0.9–1.1 by AR(48) (AR(24): 0.27–1.7)
FLOOR_AR_ORDER = 48
SEGMENT_S = 4.0  # the spectral tests' Welch segment (tvsd.analysis.noise)


def command_taps(prep: Prepared) -> np.ndarray:
    """The command at FIR_TAPS more shifts, as rows (the baseline's band filter and decimation)."""
    u = np.asarray(prep.data.u, dtype=float)
    return np.column_stack([prep.band_rows(_shift(u, k)) for k in FIR_TAPS])


def flat_level(resid: np.ndarray, rate: float, floor: Floor | None, band_hz: float) -> float:
    """The residual's flat level as the colour test reads it: the lowest tenth of its band, the
    floor taken off (tvsd.analysis.noise._whole_band)."""
    nper = min(len(resid), int(SEGMENT_S * rate))
    f, p = welch(resid - resid.mean(), fs=rate, nperseg=nper)
    m = (f >= BAND_LOW_HZ) & (f <= band_top(f, band_hz))
    fm, pm = f[m], p[m]
    if len(fm) < 3:
        return 0.0
    known = np.zeros_like(fm) if floor is None else np.asarray(floor(fm), dtype=float)
    k = max(3, len(pm) // 10)
    return max(float(np.median((pm - known)[:k])), 1e-3 * float(np.median(pm[:k])), 1e-300)


def floor_whitening(level: float, floor: Floor, rate: float, order: int = FLOOR_AR_ORDER) -> np.ndarray:
    """The AR whitening filter of the spectrum level + floor(f) on the rows (Yule–Walker on the
    spectrum's own autocovariance), [1, −φ₁, …]."""
    n = 4096
    f = np.linspace(0.0, rate / 2, n + 1)
    s = level + np.asarray(floor(f), dtype=float)
    acf = np.fft.irfft(s)[: order + 1]
    if not (acf[0] > 0 and np.all(np.isfinite(acf))):
        return np.array([1.0])
    phi = solve_toeplitz(acf[:order], acf[1 : order + 1])
    return np.concatenate([[1.0], -phi])


def refit(
    prep: Prepared,
    keep: np.ndarray,
    residual: np.ndarray,
    rate: float,
    model: tuple[np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, Floor | None]:
    """The residual rows the spectral tests see and the quantisation floor in them: as
    `quantisation.gated` (the held levels taken out, the gaps ramped), in open loop with the fit
    redone on the model's columns and the command's FIR_TAPS, whitened, with a floor, by the flat
    level plus the floor (else the doctor's AR)."""
    first, floor = quantisation.gated(prep, keep, residual, rate, model)
    if model is None or prep.data.closed_loop:  # closed loop: the command answers the noise
        return first, floor
    X, ar = model
    if floor is not None:
        ar = floor_whitening(flat_level(first, rate, floor, prep.band.cutoff_hz), floor, rate)
    Xe = np.column_stack([X, command_taps(prep)])
    # `keep` was cleared for the doctor's AR; the floor's is longer, and its memory must not reach
    # the rows left out (the shaft stuck, where the model does not hold) nor the record's start.
    # The spectral tests then see those rows only: a row fitted on none of its own is extrapolated
    # (the commands' and levels' filtered edges at a run's start are collinear elsewhere: o14036's
    # first 48 rows at 1.3× the residual's rms, colour p 1.0 → 3e-4; colourgain.md)
    k = clear_memory(keep, len(ar) - 1) if floor is not None else keep > 0
    if not np.any(k) or not np.all(np.isfinite(Xe[k])):
        return first, floor
    # y − X·θ refitted: the residual's own GLS fit on the extended columns is the change (linear)
    delta = gls(residual, Xe, ar, k).theta
    if not np.all(np.isfinite(delta)):
        return first, floor
    return quantisation.gated(prep, k, residual - Xe @ delta, rate, (Xe, ar))
