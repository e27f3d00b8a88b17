"""The inverse model: drive effort = inertia·accel + friction − unknown torques, fitted by IDIM-IV.

    b_u·u − b_ω·ω = J·ω̇ + kv·ω + τc·sgn ω + (τs − τc)·exp(−(ω/v0)²)·sgn ω [+ offset] + e

is linear in its parameters (paper eqs. 10, 16 at steady bristle state). The vibration makes e
(= J·Δv) correlated with the measured acceleration, and in closed loop with the command too, so
plain least squares is biased (J low by 1 % on a 60 s staircase, by 25 % on a spin-up). As in
IDIM-IV (Janot, Gautier et al.), each column also has an instrument: the same column computed from
the model's noise-free simulation driven by the recorded command; θ = (ZᵀX)⁻¹Zᵀy, iterated.

A candidate extension either adds columns (imbalance, cogging, resonance, drift of kv/J/friction)
or transforms the input or the friction (saturation, dead zone, delay, asymmetry, drift of R/kM)
with one scanned parameter. Models are compared by BIC on the decimated rows, whose spacing is
about the inverse of the band kept, so they are close to independent.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from scipy.signal import filtfilt

from tvsd.analysis.prep import Prepared

# Below this many rows in the Stribeck region its term is not identifiable and is left out.
MIN_STRIBECK_ROWS = 50

# A column is a function of (speed, accel, φ) at full rate returning a full-rate array that is
# already in the band (speed and accel are low-passed; anything else goes through band()).
Builder = Callable[["Signals"], np.ndarray]


@dataclass(frozen=True)
class Signals:
    speed: np.ndarray
    accel: np.ndarray
    phi: np.ndarray
    band: Callable[[np.ndarray], np.ndarray]
    t: np.ndarray
    t_frac: np.ndarray  # time as a fraction of the record (drift)


@dataclass(frozen=True)
class Fit:
    names: tuple[str, ...]
    theta: np.ndarray
    cov: np.ndarray
    rss: float
    n: int
    k: int  # parameters, including scanned ones
    residual: np.ndarray
    proj: np.ndarray | None = None  # first stage: X̂ = Z·proj (IV fits only)

    @property
    def bic(self) -> float:
        return self.n * math.log(self.rss / self.n) + self.k * math.log(self.n)

    def value(self, name: str) -> float:
        return float(self.theta[self.names.index(name)]) if name in self.names else 0.0

    def stderr(self, name: str) -> float:
        if name not in self.names:
            return math.nan
        i = self.names.index(name)
        return float(math.sqrt(max(self.cov[i, i], 0.0)))

    def params(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.theta, strict=True)}


def solve(
    y: np.ndarray, X: np.ndarray, Z: np.ndarray | None, names: tuple[str, ...], scanned: int = 0
) -> Fit:
    """LS (Z None) or IV as two-stage least squares.

    With instruments, the columns are first projected on them (X̂) and y is regressed on X̂; the
    estimate is the IV one, and the second-stage RSS is what models are compared by. The plain IV
    residual y − X·θ is not fit for that: it holds X·(θ_LS − θ_IV), which any extra column
    correlated with the signal can absorb. `residual` is the structural y − X·θ, for diagnosis.
    """
    proj = None if Z is None else np.linalg.lstsq(Z, X, rcond=None)[0]
    Xh = X if proj is None else Z @ proj
    theta, *_ = np.linalg.lstsq(Xh, y, rcond=None)
    compare = y - Xh @ theta
    resid = y - X @ theta
    rss = float(compare @ compare)
    n, k = len(y), len(names)
    sigma2 = float(resid @ resid) / max(n - k, 1)
    try:
        cov = sigma2 * np.linalg.inv(Xh.T @ Xh)
    except np.linalg.LinAlgError:
        cov = np.full((k, k), np.nan)
    return Fit(names, theta, cov, rss, n, k + scanned, resid, proj)


class Columns:
    """Decimated regression rows (and instruments) of one prepared dataset."""

    def __init__(self, prep: Prepared, v0: float) -> None:
        self.prep = prep
        self.v0 = v0
        d = prep.data
        self.t_frac = (d.t - d.t[0]) / max(d.duration_s, 1e-9)
        self.measured = Signals(prep.speed, prep.accel, d.position, prep.lowpass, d.t, self.t_frac)
        self.simulated: Signals | None = None
        self.command_transform: Callable[[np.ndarray], np.ndarray] | None = None
        self.y = self.effort()
        self.base: dict[str, Builder] = {
            "J": lambda s: s.accel,
            "kv": lambda s: s.speed,
            "tau_c": lambda s: s.band(np.sign(s.speed)),
        }
        # The Stribeck velocity v0 is the rotary drive's (config, rad/s); a linear axis's reference
        # model (EMPS) has no Stribeck term.
        rotary = d.units.axis == "rotary"
        if rotary and np.count_nonzero(np.abs(prep.rows(prep.speed)) < 2 * v0) >= MIN_STRIBECK_ROWS:
            self.base["d_stribeck"] = lambda s: s.band(np.exp(-((s.speed / v0) ** 2)) * np.sign(s.speed))
        if d.offset_term:
            self.base["offset"] = lambda s: np.ones_like(s.speed)
        self._cache: dict[tuple[str, bool], np.ndarray] = {}
        self.fit_rows = np.ones(len(self.y), dtype=bool)

    def extended(
        self,
        y: np.ndarray,
        builders: Mapping[str, Builder],
        command_transform: Callable[[np.ndarray], np.ndarray] | None,
    ) -> Columns:
        """A copy whose baseline is an extended model: the next pass tests causes on top of it."""
        other = copy.copy(self)
        other.y = y
        other.base = dict(builders)
        other.command_transform = command_transform
        other._cache = {}
        return other

    def hold_out_after(self, fraction: float) -> None:
        """Fit on the first `fraction` of the record; the rest is held out."""
        t = self.prep.t_rows
        self.fit_rows = t < t[0] + fraction * (t[-1] - t[0])

    def use_instruments(self, sim_speed: np.ndarray | None) -> None:
        """Instruments from a simulated speed (None: plain least squares)."""
        if sim_speed is None or not np.all(np.isfinite(sim_speed)):
            self.simulated = None  # no usable simulation: least squares
        else:
            filtered = filtfilt(self.prep.b, self.prep.a, sim_speed)
            accel = np.gradient(filtered, 1.0 / self.prep.data.sample_rate_hz)
            speed = np.convolve(filtered, [0.25, 0.5, 0.25], mode="same")
            m = self.measured
            self.simulated = Signals(speed, accel, m.phi, m.band, m.t, m.t_frac)
        self._cache.clear()

    def effort(
        self,
        u: np.ndarray | None = None,
        b_scale: np.ndarray | float = 1.0,
        bw_scale: np.ndarray | float = 1.0,
    ) -> np.ndarray:
        """Rows of the drive effort b_u·u − b_ω·ω, for a transformed command or scaled gains."""
        d = self.prep.data
        u = d.u if u is None else u
        if self.command_transform is not None:  # an input effect already in the model
            u = self.command_transform(u)
        if d.lag_s > 0:  # the current lags the command by L/R (dataset.py)
            u = np.interp(d.t - d.lag_s, d.t, u)
        drive = self.prep.lowpass(d.b_u * b_scale * u) - d.b_omega * bw_scale * self.prep.speed
        return self.prep.rows(drive)

    def _rows(self, name: str, builder: Builder, simulated: bool) -> np.ndarray:
        sig = self.simulated if simulated and self.simulated is not None else self.measured
        if self.base.get(name) is not builder:
            return self.prep.rows(builder(sig))
        key = (name, simulated)  # baseline columns are reused by every candidate
        if key not in self._cache:
            self._cache[key] = self.prep.rows(builder(sig))
        return self._cache[key]

    def matrix(self, builders: Mapping[str, Builder], simulated: bool = False) -> np.ndarray:
        return np.column_stack([self._rows(n, builders[n], simulated) for n in builders])

    def fit(self, y: np.ndarray, builders: Mapping[str, Builder], scanned: int = 0) -> Fit:
        """Fit on the fitting rows (self.fit_rows) only; the held-out rows stay unseen."""
        names = tuple(builders)
        m = self.fit_rows
        X = self.matrix(builders)[m]
        Z = self.matrix(builders, True)[m] if self.simulated is not None else None
        return solve(y[m], X, Z, names, scanned)

    def heldout_residual(
        self, y: np.ndarray, builders: Mapping[str, Builder], fit: Fit, projected: bool = True
    ) -> np.ndarray:
        """Residual on the held-out rows with θ from the fitting rows.

        For an IV fit the prediction uses the instrument-projected columns Z·Π (Π from the
        fitting rows): functions of the command only, so an unmodelled torque or the vibration,
        which sit in the measured acceleration, cannot leak into the comparison of two models.
        """
        m = ~self.fit_rows
        if projected and fit.proj is not None and self.simulated is not None:
            return y[m] - self.matrix(builders, True)[m] @ fit.proj @ fit.theta
        return y[m] - self.matrix(builders)[m] @ fit.theta

    def with_base(self, extra: Mapping[str, Builder]) -> dict[str, Builder]:
        out = dict(self.base)
        out.update(extra)
        return out

    def baseline(self) -> Fit:
        return self.fit(self.y, self.base)


def scan(objective: Callable[[float], float], grid: np.ndarray, refine: bool = True) -> tuple[float, float]:
    """Minimise a 1-D objective: grid search, then golden-section between the best neighbours."""
    values = np.array([objective(float(x)) for x in grid])
    i = int(np.argmin(values))
    best_x, best_v = float(grid[i]), float(values[i])
    if not refine or len(grid) < 3:
        return best_x, best_v
    a, b = float(grid[max(i - 1, 0)]), float(grid[min(i + 1, len(grid) - 1)])
    g = (math.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = objective(c), objective(d)
    for _ in range(20):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = objective(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = objective(d)
    x, v = (c, fc) if fc < fd else (d, fd)
    return (x, v) if v < best_v else (best_x, best_v)
