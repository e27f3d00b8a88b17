"""What is known of the shaft's acceleration between pulses: the IMU and the drive model.

The SA speed is not uniform over a revolution: the vibration (paper eq. 12's Δv, and the
imbalance) and the speed loop's own reaction push it around. Both are measured or known:
- the SA IMU measures the disturbance acceleration about the shaft axis (1 kHz FIFO);
- the daemon knows the voltage it commanded, and the drive model turns it into torque:
  J·ω̇ ∋ kM·i with i ≈ (ku·u − kb·ω)/R (the electrical time constant L/R = 0.1 ms is below one IMU
  sample), and the viscous terms damp every speed change at λ = (kv + σ2)/J + kM·kb/(R·J).
The angle these accelerations cause, Φ_K(t) — the known acceleration through ω̇ = a − λ·ω, twice
integrated — is subtracted before fitting the zero pulses and added back at the optical pulse
(tvsd.scan.beta). Coulomb/Stribeck friction is flat at scanning speed and, like every constant,
is left to the fit; so are the means, which are removed. λ matters for the paper's parameter set
(kv/J = 385 1/s); for the default plant it is 0.4 1/s, nothing over a revolution.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import lfilter

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class DriveModel:
    """The drive as the compensation sees it: J·ω̇ = kM·i − (kv·ω …), L·i̇ = ku·u − kb·ω − R·i."""

    accel_per_volt: float  # kM·ku/(R·J), rad/s² per V at steady current
    damping: float = 0.0  # λ = kv/J + kM·kb/(R·J), 1/s
    tau_e: float = 0.0  # L/R, s: the current's lag behind the voltage

    @classmethod
    def from_plant(
        cls, kM: float, ku: float, R: float, J: float, kv: float = 0.0, kb: float = 0.0, L: float = 0.0
    ) -> DriveModel:
        return cls(kM * ku / (R * J), kv / J + kM * kb / (R * J), L / R)

    def accel(self, u: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        """Mean acceleration over each control period of a command held over it (current lag L/R).

        Run at the control rate (the daemon's loop has every command): a stiff position loop (the
        paper set's rings at ~440 Hz) would otherwise be seen through 1 ms means only.
        """
        if self.tau_e <= 0.0:
            return self.accel_per_volt * u
        decay = np.exp(-dt / self.tau_e)
        # First-order lag, exact for a command held over each period (starting from 0 current).
        end = lfilter([1.0 - decay], [1.0, -decay], u)
        start = np.concatenate([[0.0], end[:-1]])
        mean = u + (start - u) * (self.tau_e / dt) * (1.0 - decay)
        return self.accel_per_volt * mean


@dataclass(frozen=True)
class KnownAccel:
    """Piecewise-constant known acceleration on a uniform grid, in MCU time.

    Sample k holds over [t0 + k·dt, t0 + (k+1)·dt). `imu` and `drive` are kept apart because their
    error budgets differ (gyro scale tolerance vs drive-model tolerance).
    """

    t0: float
    dt: float
    imu: F64  # rad/s², mean disturbance over each sample, as measured
    drive: F64  # rad/s², model acceleration of the commanded voltage
    damping: float = 0.0  # λ (1/s) of ω̇ = a − λ·ω

    @classmethod
    def build(
        cls, t0: float, dt: float, imu: ArrayLike, drive: ArrayLike | None = None, damping: float = 0.0
    ) -> KnownAccel:
        imu_ = np.asarray(imu, dtype=np.float64)
        drv = np.zeros_like(imu_) if drive is None else np.asarray(drive, dtype=np.float64)
        if drv.shape != imu_.shape:
            raise ValueError("imu and drive samples must be on the same grid")
        return cls(t0, dt, imu_ - imu_.mean(), drv - drv.mean(), damping)

    def _gains(self, s: F64 | float) -> tuple[F64, F64, F64]:
        """Over a time s from a grid point: speed decay e, ∫e (g) and ∫∫ of the forcing (h)."""
        lam, s_ = self.damping, np.asarray(s, dtype=np.float64)
        x = lam * s_
        if lam == 0.0:
            return np.ones_like(s_), s_, 0.5 * s_ * s_
        e = np.exp(-x)
        g = -np.expm1(-x) / lam
        # h = (s − g)/λ loses every digit for λ·s → 0; its series is exact to 1e-16 below 1e-3.
        small = x < 1e-3
        h = np.where(small, s_ * s_ * (0.5 - x / 6.0 + x * x / 24.0), (s_ - g) / np.where(small, 1.0, lam))
        return e, g, h

    @cached_property
    def total(self) -> F64:
        return self.imu + self.drive

    @property
    def t_end(self) -> float:
        return self.t0 + len(self.imu) * self.dt

    def covers(self, t: ArrayLike) -> NDArray[np.bool_]:
        t_ = np.asarray(t, dtype=np.float64)
        return (t_ >= self.t0) & (t_ < self.t_end)

    def _grid(self, a: F64) -> tuple[F64, F64]:
        """Speed and angle at the grid points from t0 (at rest), exact for piecewise-constant a.

        Kept for each series it was asked for (by identity: `total`, `imu`, `drive`): one point's
        β and σ ask for the same grids up to six times (the point stream computes them on the
        event loop)."""
        memo: dict[int, tuple[F64, F64, F64]] = self.__dict__.setdefault("_grids", {})
        hit = memo.get(id(a))
        if hit is not None and hit[0] is a:
            return hit[1], hit[2]
        w, p = self._grid_of(a)
        if a is self.imu or a is self.drive or a is self.__dict__.get("total"):
            memo[id(a)] = (a, w, p)
        return w, p

    def _grid_of(self, a: F64) -> tuple[F64, F64]:
        e, g, h = (float(v) for v in self._gains(self.dt))
        if self.damping == 0.0:
            w = np.concatenate([[0.0], np.cumsum(a) * g])
        else:
            w = np.concatenate([[0.0], lfilter([g], [1.0, -e], a)])
        p = np.concatenate([[0.0], np.cumsum(w[:-1] * g + a * h)])
        return w, p

    def integrals(self, t: ArrayLike, accel: F64 | None = None) -> tuple[F64, F64]:
        """ω_K(t) and Φ_K(t) from t0: the acceleration through ω̇ = a − λ·ω, exactly."""
        if accel is None and isinstance(t, np.ndarray) and t.size <= 64:
            # A point's β and its σ ask for the same few times twice: kept by value.
            memo: dict[tuple[object, ...], tuple[F64, F64]] = self.__dict__.setdefault("_integral_memo", {})
            key = (t.shape, t.dtype.str, t.tobytes())
            hit = memo.get(key)
            if hit is None:
                if len(memo) >= 8:
                    memo.clear()
                hit = memo[key] = self._integrals(t, self.total)
                for arr in hit:
                    arr.flags.writeable = False  # shared by the callers that ask again
            return hit
        return self._integrals(t, self.total if accel is None else accel)

    def _integrals(self, t: ArrayLike, a: F64) -> tuple[F64, F64]:
        w, p = self._grid(a)
        t_ = np.asarray(t, dtype=np.float64) - self.t0
        i = np.clip((t_ / self.dt).astype(np.int64), 0, len(a) - 1)
        e, g, h = self._gains(t_ - i * self.dt)
        return w[i] * e + a[i] * g, p[i] + w[i] * g + a[i] * h

    def effective(self, accel: F64) -> F64:
        """What the shaft's speed actually integrates: a − λ·ω_K (cell means), = a without damping."""
        if self.damping == 0.0:
            return accel
        w, _p = self._grid(accel)
        return np.diff(w) / self.dt  # the cell's speed change over its length

    def intensity(self, t: ArrayLike, window_s: float, accel: F64 | None = None) -> F64:
        """Vibration intensity q (rad²/s³) in a window ending at each t: E[a²]·dt.

        For white acceleration (paper eq. 12) this is σv², whatever the sample rate: it is the
        paper's σv squared, measured, and what the vibration threshold is compared with.
        """
        a = self.total if accel is None else accel
        cum = np.concatenate([[0.0], np.cumsum(a * a)])
        end, start = self._window(t, window_s)
        return (cum[end] - cum[start]) / np.maximum(end - start, 1) * self.dt

    def _window(self, t: ArrayLike, window_s: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        # One point's σ asks for the same windows four times (the same `t` array): kept by identity.
        key = (id(t), window_s)
        memo: dict[tuple[int, float], tuple[object, NDArray[np.int64], NDArray[np.int64]]]
        memo = self.__dict__.setdefault("_windows", {})
        hit = memo.get(key)
        if hit is not None and hit[0] is t:
            return hit[1], hit[2]
        end, start = self._window_of(t, window_s)
        if isinstance(t, np.ndarray):
            memo.clear()  # only the newest: a stream's known acceleration lives for one computation
            memo[key] = (t, end, start)
        return end, start

    def _window_of(self, t: ArrayLike, window_s: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        n = max(round(window_s / self.dt), 2)
        end = np.clip(
            ((np.asarray(t, dtype=np.float64) - self.t0) / self.dt).astype(np.int64), 1, len(self.imu)
        )
        return end, np.maximum(end - n, 0)

    def autocovariance(self, t: ArrayLike, window_s: float, lags: int, accel: F64 | None = None) -> F64:
        """(n, lags) autocovariance of the samples over the window ending at each t (biased estimate).

        The biased estimate (divided by the window length at every lag) keeps the implied spectrum
        non-negative, so a quadratic form with it is a variance.
        """
        a = self.total if accel is None else accel
        end, start = self._window(t, window_s)
        width = int(np.max(end - start)) if len(end) else 1
        idx = start[:, None] + np.arange(width)[None, :]
        valid = idx < end[:, None]
        seg = np.where(valid, a[np.minimum(idx, len(a) - 1)], 0.0)
        seg = seg - np.where(
            valid, seg.sum(axis=1, keepdims=True) / np.maximum(valid.sum(1, keepdims=True), 1), 0.0
        )
        if lags <= 4:  # a few lags (the σ model's 2): direct sums, cheaper than two FFTs
            r = np.stack([np.sum(seg[:, : width - k] * seg[:, k:], axis=1) for k in range(lags)], axis=1)
        else:
            nfft = 1 << int(np.ceil(np.log2(width + lags)))
            spec = np.fft.rfft(seg, nfft, axis=1)
            r = np.fft.irfft(spec * np.conj(spec), nfft, axis=1)[:, :lags]
        return r / np.maximum(valid.sum(axis=1, keepdims=True), 1)
