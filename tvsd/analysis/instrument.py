"""The reference as instrument: closed-loop recordings analysed by instrumental variables.

In closed loop the command answers the noise: the law reacts within a few ms to every speed
disturbance, and the rows are zero-phase filtered, so the command columns of the regression
(tvsd.analysis.design) are correlated with its error. Least squares on them is biased, and the
bootstrap of tvsd.analysis.calibrate, which conditions on the regressors, is then not the null
distribution either: a command map (dead zone, delay, drift of R) picks up the law's answer to
the noise.

The instruments follow IDIM-IV's idea (Janot et al.): regressors built from noise-free signals.
Here the noise-free command and speed are their first-stage predictions from the reference alone
(two-stage least squares): û and ω̂ are the recorded ω_ref through the loop's own linear
response, estimated over the file after the spin-up (a static gain, then a Wiener filter where
the reference is coherent with the signal; û clipped to the recorded command's range, as the law
saturates on a step). The baseline's command and speed columns, and every candidate block that
is a function of the command or the speed (dead zone, saturation, delay, drift, friction by
direction), are then built from û and ω̂; blocks of the angle and of time (imbalance, cogging, a
line) are their own instruments (the angle tracks the reference to within the lag). The
acceleration stays measured; the rows are those after the spin-up. Each regressor is then a
function of the reference, which the noise does not move, so conditioning on the regressors
(what the bootstrap does) is legitimate again, with no change to calibrate.py.

With identify's PRBS recorded (`u_exc`, exogenous: drawn before the run, added after the law)
the first stage predicts from it too, and the second stage's left side is cleaned of
(X − X̂)·θ_IV (`instrumented(measured=...)`), so the bootstrap sees the structural residual.

Status: two uses. As a confirmation, by default: in closed loop by least squares a command-side
cause (dead zone, clip, delay, drift, friction asymmetry) must also pass the gate on the
instrumented design (tvsd.analysis.closed_checks.instrumented_check; docs/measurements/doctor-false-alarms.md,
"Closed-loop false alarms"); the clip on its own design (tvsd.analysis.rules' identified_for,
expected_for: docs/measurements/closedsat.md).
As the whole analysis, opt-in (`diagnose(..., iv=True)`; `python -m tvsd.analysis.matrix_closed
--variants ls,iv`), not the default, because it did not measure better. On 104 cases of the
closed-loop family (docs/measurements/closed-loop-ls-iv.w*.jsonl, the same files through both): 3
false alarms in 10 nulls for both, 52 of 94 effect cases named against least squares' 49 — better on
delay and dead zone at 3×, no better elsewhere, and ≈ 30 % slower. With the reversal segment it did
worse than least squares (6 of 12 nulls alarmed; docs/measurements/doctor-closed.md, "Closed loop"). The PRBS
lifts the first
stage's share of the command's band-limited variance (0.87 → 0.96 on a 30 s case); what is left —
the law's answer to the noise — is low-pass and, through the scanned nonlinear blocks of û, still
fits. A file without a moving reference or a u_exc column instruments nothing: then the command-side
causes are not testable (doctor.py drops them)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from scipy.signal import csd, welch

from tvsd.analysis import design as D
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.instrument_maps import expected_maps
from tvsd.analysis.prep import Prepared
from tvsd.analysis.rules import DEFAULT, Rules

SPUN_SHARE = 0.8
MIN_COHERENCE = 0.2
CATCH_UP = 5.0
SETTLE_S = 0.5
WIENER_S = 4.0  # Welch segment: 0.25 Hz resolution of the loop's response to the reference
MOVING_SHARE = 0.005  # the reference must vary by this share of its level (steady scanning: ~0)
EXCITATION = "u_exc"  # the recording's column of the voltage identify added after the law


def reference_moves(data: Dataset) -> bool:
    """Whether the file holds a closed-loop reference that varies (steps, multisine) after the
    first fifth (a spin-up alone does not identify the drive's command map)."""
    ref = data.speed_reference
    if ref is None or len(ref) < 10:
        return False
    steady = ref[len(ref) // 5 :]
    level = float(np.mean(np.abs(steady)))
    return level > 0 and float(np.std(steady)) > MOVING_SHARE * level


def excited(data: Dataset) -> bool:
    """Whether the file carries an exogenous excitation to instrument with: a moving reference, or
    identify's voltage excitation (u_exc) that is not all zero."""
    exc = data.refs.get(EXCITATION)
    moving_exc = exc is not None and data.closed_loop and float(np.std(exc)) > 0
    return reference_moves(data) or moving_exc


def bank(data: Dataset) -> np.ndarray:
    """The instrument signal: ω_ref, a position loop's dφ_ref/dt (Dataset.speed_reference; its
    slips, where it is the derivative of a slipping φ_ref, clipped to its range)."""
    w_ref = data.speed_reference
    if w_ref is None:
        raise ValueError(f"{data.name}: open loop, no reference to instrument with")
    return np.clip(w_ref, *np.quantile(w_ref, [0.001, 0.999]))


@dataclasses.dataclass(frozen=True)
class FirstStage:
    u_hat: np.ndarray  # full rate, as the command column (not low-passed)
    speed_hat: np.ndarray  # full rate, low-passed like prep.speed
    r2_u: float  # share of the command's band-limited variance the reference explains
    r2_speed: float
    u_lin: np.ndarray | None = None  # the linear prediction before the clip to the recorded range
    spread: float = 0.0  # std of u − u_lin after the spin-up: what the reference leaves of u
    bounds: tuple[float, float] = (0.0, 0.0)  # the recorded command's range (the law's rails)


def steady_start(data: Dataset, spin_only: bool = False) -> int:
    """The first sample after the spin-up: |ω_ref| has reached SPUN_SHARE of its level, and the
    tracking error (mean |ω_ref − ω| over SETTLE_S) is back under CATCH_UP × its median and stays
    there up to the middle of the file. Before it the drive may sit at its limit while the shaft
    catches up: nothing a linear response to the reference describes.

    `spin_only`: the first time the error is back under that bar after the spin-up, whatever
    follows. A drive held at its rail on the identify steps makes a large error on every step,
    which moved the start to the middle of the file (a clip near the rail: 15.4 s of 30) and
    left half the clipped samples out of the clip's confirmation; its design models the rail
    (E[f(u)] of u clipped to the recorded range), so it need not leave the steps out."""
    ref = bank(data)
    level = float(np.median(np.abs(ref[len(ref) // 5 :])))
    spun = np.flatnonzero(np.abs(ref) >= SPUN_SHARE * level)
    first = int(spun[0]) if len(spun) else 0
    win = max(1, round(SETTLE_S * data.sample_rate_hz))
    speed = data.speed if data.speed is not None else np.gradient(data.position, data.t)
    err = np.convolve(np.abs(ref - speed), np.ones(win) / win, mode="same")
    bar = CATCH_UP * float(np.median(err))
    if spin_only:
        caught = np.flatnonzero(err[first:] <= bar)
        return min(len(ref) - 1, first + win + (int(caught[0]) if len(caught) else 0))
    late = np.flatnonzero(err[: len(err) // 2] > bar)
    after = int(late[-1]) + win if len(late) else 0
    return min(len(ref) - 1, max(first + win, after))


def first_stage(prep: Prepared, use_exc: bool = True, spin_only: bool = False) -> FirstStage:
    """û and ω̂: the reference through the closed loop's own linear response, estimated over the
    file (Wiener filter H = S_rv / S_rr, Welch-averaged; any function of the reference, past or
    future, is a valid instrument). Constant lags would leave part of the loop's response to the
    reference in u − û, and a scanned block of û (a delay) would then fit that, not the noise.

    With the identify run's voltage excitation recorded (`u_exc`, the PRBS added after the law)
    and `use_exc`, what the reference leaves is then predicted from it the same way: the PRBS is
    independent of the noise (drawn before the run), and it carries the command's broadband part
    that the reference, a few Hz wide, cannot."""
    data = prep.data
    ref = bank(data)
    u_f = prep.lowpass(data.u)
    rate = data.sample_rate_hz
    s0 = steady_start(data, spin_only)
    edge = slice(max(prep.trim, s0), len(u_f) - prep.trim)
    u_lin = _wiener(ref, data.u, rate, s0)
    w_lin = _wiener(ref, prep.speed, rate, s0)
    exc = data.refs.get(EXCITATION) if use_exc else None
    if exc is not None and float(np.std(exc[s0:])) > 0:
        u_lin = u_lin + _wiener(exc, data.u - u_lin, rate, s0)
        w_lin = w_lin + _wiener(exc, prep.speed - w_lin, rate, s0)
    # The law saturates at the drive's limits on a reference step: the prediction does too.
    lo, hi = float(np.min(data.u)), float(np.max(data.u))
    u_hat = np.clip(u_lin, lo, hi)
    w_hat = prep.lowpass(w_lin)
    r2_u = _r2(u_f[edge], prep.lowpass(u_hat)[edge])
    spread = float(np.std((data.u - u_lin)[s0:])) if s0 < len(u_lin) else 0.0
    return FirstStage(u_hat, w_hat, r2_u, _r2(prep.speed[edge], w_hat[edge]), u_lin, spread, (lo, hi))


def _wiener(x: np.ndarray, y: np.ndarray, fs: float, start: int = 0) -> np.ndarray:
    """y's best linear prediction from x (any lags), fitted from `start` on (Welch segments of
    WIENER_S), applied to all of x."""
    n = len(x)
    nper = min(n - start, max(64, round(WIENER_S * fs)))
    # The static part first (Welch's segments lose the mean: the steady-state map would be lost).
    xs, ys = x[start:], y[start:]
    A = np.column_stack([np.ones_like(xs), xs])
    c, *_ = np.linalg.lstsq(A, ys, rcond=None)
    static = c[0] + c[1] * x
    xm = float(np.mean(xs))
    y = y - static
    ym = 0.0
    f, Sxy = csd(xs - xm, y[start:], fs, nperseg=nper)
    _, Sxx = welch(xs - xm, fs, nperseg=nper)
    _, Syy = welch(y[start:], fs, nperseg=nper)
    # Only where the reference explains y (coherence): elsewhere the ratio is noise over a
    # reference with no power, which the spin-up (where there is power) would amplify.
    coherence = np.abs(Sxy) ** 2 / np.maximum(Sxx * Syy, 1e-300)
    H = np.where(coherence > MIN_COHERENCE, Sxy / np.maximum(Sxx, 1e-300), 0.0)
    # Applied to x mirrored (x, then x reversed): periodic without a jump where the FFT wraps (a
    # spin-up ends far from where it starts, and the loop's response holds a derivative).
    ext = np.concatenate([x - xm, (x - xm)[::-1]])
    grid = np.fft.rfftfreq(2 * n, 1.0 / fs)
    Hn = np.interp(grid, f, H.real) + 1j * np.interp(grid, f, H.imag)
    return static + ym + np.fft.irfft(np.fft.rfft(ext) * Hn, 2 * n)[:n]


def _r2(x: np.ndarray, fit: np.ndarray) -> float:
    v = float(np.var(x))
    return 1.0 - float(np.var(x - fit)) / v if v > 0 else 0.0


def instrumented(
    prep: Prepared,
    offset: bool,
    rotary: bool,
    use_exc: bool = True,
    measured: D.Design | None = None,
    expected: bool = False,
    spin_only: bool = False,
    identified_only: bool = False,
    rules: Rules = DEFAULT,
) -> tuple[D.Design, FirstStage]:
    """The design with every command and speed regressor built from the reference's prediction
    (the acceleration, the angle and time as measured).

    With the `measured` design (same rows), the left side becomes y − (X − X̂)·θ_IV: the
    regression on X̂ then has the 2SLS coefficients and, as its residual, the structural one
    y − X·θ_IV — the equation's own error, which the instruments do not move. Without it the
    second stage's residual also holds (X − X̂)·θ, the law's answer to the noise (a low-pass,
    correlated with the noise), which the bootstrap's i.i.d. whitened errors do not describe and
    the scanned command blocks (built from û) fit. `expected`: the maps' blocks as
    E[f(u) | instruments] (expected_maps); `spin_only`: rows from the spin-up's end
    (steady_start); `identified_only`: θ_IV along identified directions (structural_left_side);
    `rules`: the design's (tvsd.analysis.rules)."""
    fs = first_stage(prep, use_exc, spin_only)
    data = dataclasses.replace(prep.data, u=fs.u_hat)
    prep_iv = dataclasses.replace(prep, data=data, speed=fs.speed_hat)
    t0 = float(prep.data.t[steady_start(prep.data, spin_only)])
    design = D.build(prep_iv, offset, rotary, fit_mask=prep.t_rows >= t0, rules=rules)
    if expected:
        expected_maps(design, prep, fs)
    if measured is not None:
        design.y = structural_left_side(design, measured, identified_only)
    return design, fs


WEAK_F = 10.0  # a direction of the instrumented columns is identified from this first-stage F on
# Which cause's confirmation uses which of these designs: tvsd.analysis.rules (identified_for,
# expected_for, spin_only_for; identified_only and expected_maps for every cause, branch cldz).


def structural_left_side(iv: D.Design, measured: D.Design, identified_only: bool = False) -> np.ndarray:
    """y − (X − X̂)·θ_IV: the left side whose regression on X̂ leaves the structural residual
    y − X·θ_IV (unchanged y where the two designs' columns differ). θ_IV by least squares on X̂
    (main's rule) unless `identified_only`, which does the following.

    θ_IV is fitted only along the directions of X̂ the instruments identify: a column that is
    ~0 on the rows (a Stribeck term at the scanning speed, e^−(ω/ωs)² ≈ 1e−50) or a
    combination of the speed shapes that ω̂ holds constant has no instrumented variation, and
    least squares on X̂ gave it a coefficient of 1e5–1e7 (X̂'s condition number 1e16), which
    multiplied the measured-minus-predicted speed into the left side: its residual was 5× the
    least-squares one on a closed-loop clip (matrix seed 71, case 710138) and every block's z ≈ 0.
    Per right singular vector v of X̂ (columns scaled to unit norm), the first-stage strength is
    μ² = ‖X̂v‖² / (‖(X − X̂)v‖²/n), the concentration parameter of that combination; with one
    instrument it is the first-stage F, and F < 10 is a weak instrument (Staiger & Stock 1997;
    more instruments only lower F = μ²/q, so μ² < WEAK_F is weak for any q). The weak directions
    keep their least-squares coefficients on the measured columns (what the instruments cannot
    say, the fit must still remove); the identified ones get the 2SLS coefficients."""
    if measured.X.shape != iv.X.shape:
        return iv.y
    return iv.y - (measured.X - iv.X) @ iv_theta(iv, measured, identified_only)


def iv_theta(iv: D.Design, measured: D.Design, identified_only: bool = False) -> np.ndarray:
    """θ_IV of structural_left_side (the designs' columns must match): least squares on X̂ on
    the instrumented rows, or along the identified directions only (`identified_only`)."""
    m = iv.rows_mask
    if not identified_only:  # main's rule: lstsq on X̂
        theta, *_ = np.linalg.lstsq(iv.X[m], iv.y[m], rcond=None)
        return np.asarray(theta)
    A, B, y = iv.X[m], measured.X[m], iv.y[m]
    scale = np.linalg.norm(A, axis=0)
    scale[~(scale > 0)] = 1.0
    As, Bs = A / scale, B / scale
    U, S, Vt = np.linalg.svd(As, full_matrices=False)
    gap = np.mean(((Bs - As) @ Vt.T) ** 2, axis=0)
    strong = WEAK_F * np.maximum(gap, 1e-300) <= S**2
    c = Vt[strong].T @ ((U[:, strong].T @ y) / S[strong])
    if not np.all(strong):
        V2 = Vt[~strong].T
        c2, *_ = np.linalg.lstsq(Bs @ V2, y - Bs @ c, rcond=None)
        c = c + V2 @ c2
    return np.asarray(c / scale)


def structural_residual(iv: D.Design, measured: D.Design, identified_only: bool = False) -> np.ndarray | None:
    """y − X·θ_IV on the measured design's rows: θ_IV by the second stage (least squares on
    the instrumented columns X̂, on the rows after the spin-up), the residual on the measured
    columns — the equation's own error, in which a mode of the plant stays and the law's answer
    to the noise, which least squares on the measured command leaves there (doctor.py's closed-
    loop peak), does not. None when the two designs' columns differ."""
    if measured.X.shape != iv.X.shape:
        return None
    return np.asarray(measured.y - measured.X @ iv_theta(iv, measured, identified_only))


def residual(measured: D.Design, used: D.Design, verdict: Any) -> np.ndarray:
    """The equation error for the noise's colour. Open loop: the verdict's residual. IV: the
    coefficients on the measured regressors (the IV residual y − Xθ); the second stage's own
    residual also holds the law's answer to the noise (u − û), a low-pass that is no vibration."""
    if used is measured:
        return np.asarray(verdict.residual)
    k = measured.X.shape[1]
    if used.X.shape[1] != k or verdict.X.shape[1] != k:  # an extension named: its own residual
        return np.asarray(verdict.residual)
    return measured.y - measured.X @ np.asarray(verdict.theta)[:k]
