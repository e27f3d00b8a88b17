"""Motion that the simulated MPU6050s feel: the link between the SIL plant and the IMU twin.

A MotionSource gives, at sensor sample times, the angular rate (rad/s) and specific force (m/s^2,
what an accelerometer reads: gravity up plus linear acceleration) in the sensor's frame. Calls come
with increasing times (the twin asks for each new FIFO sample once), so sources may keep state.

Three sources: SyntheticMotion (the effects as parameters, usable now), ArrayMotion (built from
the SIL plant's time series t, alpha_sa, omega_shaft, gamma) and PlantMotion (read live from a
running SIL plant's history ring, tvsd.sim.mcu_plant.McuPlant: the daemon's SIL IMUs).

Modelling choices (see MODEL-NOTES.md §4):
- the vibration is an angular acceleration about the SA axis (sensor X): the paper's Δv;
- its random part is Ornstein–Uhlenbeck (std σ, correlation time τ, exact discretization, so the
  result does not depend on the step);
- the housing sits on compliant mounts, so the angular rate is the integral of α with a slow leak
  (τ_leak = 1 s): the rate stays bounded, and dω/dt = α above ~0.2 Hz;
- the accelerometer sees gravity tilted by γ about X, plus α·r along Y and Z (lever arm r);
- the PL sensor feels the same disturbance, attenuated by the frame (coupling 0.3, an assumption).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Protocol

import numpy as np
from scipy.signal import lfilter

from tvsd.errors import UsageError
from tvsd.sim.twin_kernels import leaky_rate

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from tvsd.sim.mcu_plant import PlantHistory

GRAVITY = 9.80665


@dataclass(frozen=True)
class MotionSample:
    gyro: np.ndarray  # (n, 3) rad/s, sensor frame
    accel: np.ndarray  # (n, 3) m/s^2 specific force, sensor frame


class MotionSource(Protocol):
    def sample(self, t: np.ndarray) -> MotionSample:
        """Motion at times `t` (s, increasing, and after the times of any earlier call)."""
        ...


def _specific_force(alpha: np.ndarray, gamma: float, lever_m: float) -> np.ndarray:
    """Gravity tilted by γ about X (sensor Z up at γ = 0), plus tangential α·r on Y and Z."""
    out = np.empty((alpha.size, 3))
    out[:, 0] = 0.0
    out[:, 1] = GRAVITY * np.sin(gamma) + lever_m * alpha
    out[:, 2] = GRAVITY * np.cos(gamma) + lever_m * alpha
    return out


def _axis_vector(values: np.ndarray, axis: int) -> np.ndarray:
    out = np.zeros((values.size, 3))
    out[:, axis] = values
    return out


@dataclass(frozen=True)
class SyntheticParams:
    rps: float = 25.0  # shaft rotation rate, rev/s
    imbalance_rad_s2: float = 2.0  # once-per-revolution line amplitude (0 = effect off)
    imbalance_phase: float = 0.0
    vibration_std_rad_s2: float = 0.3  # OU random vibration, std
    vibration_tau_s: float = 0.005  # OU correlation time
    resonance_hz: float = 0.0  # structural mode (0 = off)
    resonance_rad_s2: float = 0.0
    gamma_rad: float = 0.0  # rod tilt: the gravity direction
    lever_m: float = 0.01
    axis: int = 0  # the SA axis in the sensor frame
    leak_tau_s: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.rps < 0 or self.vibration_std_rad_s2 < 0 or self.imbalance_rad_s2 < 0:
            raise UsageError("motion: rps, imbalance and vibration std must be >= 0")
        if self.vibration_tau_s <= 0 or self.leak_tau_s <= 0:
            raise UsageError("motion: vibration_tau_s and leak_tau_s must be > 0")
        if self.resonance_hz < 0 or self.axis not in (0, 1, 2):
            raise UsageError("motion: resonance_hz must be >= 0 and axis 0, 1 or 2")


class SyntheticMotion:
    """Imbalance line + OU vibration + optional resonance line, as a stateful stream."""

    def __init__(self, params: SyntheticParams) -> None:
        self.params = params
        self._rng = np.random.default_rng(params.seed)
        self._t_last: float | None = None
        self._alpha_ou = 0.0
        self._omega_ou = 0.0

    @property
    def rotation_hz(self) -> float:
        return self.params.rps

    def _lines(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sine lines in α and their zero-mean integrals in ω (exact)."""
        p = self.params
        alpha = np.zeros_like(t)
        omega = np.zeros_like(t)
        for f, amp, phase in (
            (p.rps, p.imbalance_rad_s2, p.imbalance_phase),
            (p.resonance_hz, p.resonance_rad_s2, 0.0),
        ):
            if f > 0 and amp > 0:
                arg = 2 * np.pi * f * t + phase
                alpha += amp * np.sin(arg)
                omega -= amp / (2 * np.pi * f) * np.cos(arg)
        return alpha, omega

    def _ou(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        if p.vibration_std_rad_s2 == 0:
            return np.zeros_like(t), np.zeros_like(t)
        t_prev = t[0] if self._t_last is None else self._t_last
        dt = np.diff(np.concatenate([[t_prev], t]))
        a = np.exp(-dt / p.vibration_tau_s)
        noise = self._rng.standard_normal(t.size) * p.vibration_std_rad_s2 * np.sqrt(1 - a * a)
        c = np.exp(-dt / p.leak_tau_s)
        if np.ptp(dt) < 1e-12:  # uniform step: vectorized recursions
            alpha = lfilter([1.0], [1.0, -a[0]], noise, zi=[a[0] * self._alpha_ou])[0]
            prev = np.concatenate([[self._alpha_ou], alpha[:-1]])
            u = p.leak_tau_s * (1 - c[0]) * 0.5 * (prev + alpha)
            omega = lfilter([1.0], [1.0, -c[0]], u, zi=[c[0] * self._omega_ou])[0]
        else:
            alpha, omega = np.empty_like(t), np.empty_like(t)
            al, om = self._alpha_ou, self._omega_ou
            for i in range(t.size):
                new = a[i] * al + noise[i]
                om = c[i] * om + p.leak_tau_s * (1 - c[i]) * 0.5 * (al + new)
                al = new
                alpha[i], omega[i] = al, om
        self._alpha_ou, self._omega_ou = float(alpha[-1]), float(omega[-1])
        return alpha, omega

    def sample(self, t: np.ndarray) -> MotionSample:
        t = np.asarray(t, dtype=np.float64)
        if t.size == 0:
            return MotionSample(np.zeros((0, 3)), np.zeros((0, 3)))
        if self._t_last is not None and t[0] < self._t_last:
            raise ValueError(f"motion sampled backwards in time ({t[0]} < {self._t_last})")
        alpha_l, omega_l = self._lines(t)
        alpha_n, omega_n = self._ou(t)
        self._t_last = float(t[-1])
        alpha = alpha_l + alpha_n
        p = self.params
        return MotionSample(
            _axis_vector(omega_l + omega_n, p.axis), _specific_force(alpha, p.gamma_rad, p.lever_m)
        )


def synthetic_pair(params: SyntheticParams, pl_coupling: float = 0.3) -> dict[str, SyntheticMotion]:
    """Sources for both sensors: SA as given, PL with the disturbance scaled by `pl_coupling`."""
    pl = replace(
        params,
        imbalance_rad_s2=params.imbalance_rad_s2 * pl_coupling,
        vibration_std_rad_s2=params.vibration_std_rad_s2 * pl_coupling,
        resonance_rad_s2=params.resonance_rad_s2 * pl_coupling,
        seed=params.seed + 1,
    )
    return {"pl": SyntheticMotion(pl), "sa": SyntheticMotion(params)}


class ArrayMotion:
    """A MotionSource from the SIL plant's series: α about the SA axis at times t_s.

    `omega_shaft` (rad/s) is kept to report the rotation rate; the plant's α already holds its
    effect on the housing. Times outside the series are an error, not an extrapolation.
    """

    def __init__(
        self,
        t_s: np.ndarray,
        alpha_sa: np.ndarray,
        gamma_rad: float = 0.0,
        omega_shaft: np.ndarray | None = None,
        axis: int = 0,
        lever_m: float = 0.01,
        leak_tau_s: float = 1.0,
    ) -> None:
        t_s = np.asarray(t_s, dtype=np.float64)
        alpha_sa = np.asarray(alpha_sa, dtype=np.float64)
        if t_s.ndim != 1 or t_s.shape != alpha_sa.shape or t_s.size < 2:
            raise ValueError("ArrayMotion: t and alpha_sa must be 1-D, same length, >= 2 points")
        dt = np.diff(t_s)
        if np.any(dt <= 0):
            raise ValueError("ArrayMotion: t must be strictly increasing")
        omega = np.empty_like(alpha_sa)  # leaky trapezoid integration, as SyntheticMotion
        omega[0] = 0.0
        c = np.exp(-dt / leak_tau_s)
        incr = leak_tau_s * (1 - c) * 0.5 * (alpha_sa[1:] + alpha_sa[:-1])
        for i in range(dt.size):
            omega[i + 1] = c[i] * omega[i] + incr[i]
        self.t_s, self.alpha_sa, self.omega = t_s, alpha_sa, omega
        self.gamma_rad, self.axis, self.lever_m = gamma_rad, axis, lever_m
        self.omega_shaft = None if omega_shaft is None else np.asarray(omega_shaft, dtype=float)

    @property
    def rotation_hz(self) -> float:
        if self.omega_shaft is None:
            return 0.0
        return float(np.mean(self.omega_shaft) / (2 * np.pi))

    def sample(self, t: np.ndarray) -> MotionSample:
        t = np.asarray(t, dtype=np.float64)
        if t.size and (t[0] < self.t_s[0] or t[-1] > self.t_s[-1]):
            raise ValueError(
                f"ArrayMotion covers {self.t_s[0]:g}..{self.t_s[-1]:g} s, asked {t[0]:g}..{t[-1]:g} s"
            )
        alpha = np.interp(t, self.t_s, self.alpha_sa)
        omega = np.interp(t, self.t_s, self.omega)
        return MotionSample(
            _axis_vector(omega, self.axis), _specific_force(alpha, self.gamma_rad, self.lever_m)
        )


class LivePlant(Protocol):
    """What PlantMotion reads: tvsd.sim.mcu_plant.McuPlant offers it."""

    def history(self, since_sim: float = -math.inf) -> PlantHistory: ...

    def host_to_sim(self, t_host: ArrayLike) -> np.ndarray: ...

    def covered_host(self) -> float: ...


class PlantMotion:
    """A MotionSource read live from a running SIL plant (McuPlant's history ring).

    Sample times are host times (time.monotonic, through PlantClock), mapped to the plant's sim
    time on its pacing line (McuPlant.host_to_sim). The angular acceleration about the SA axis is
    the plant's disturbance (mean over each 1 ms chunk, piecewise constant), times `scale` (the PL
    sensor: the frame's coupling, as synthetic_pair). The rate is its leaky integral (τ_leak, as
    the other sources), integrated exactly over each constant piece in sim time, so the gyro
    reads the plant's own rate whatever the pacing speed (at speed s the sensor's samples are
    s/rate apart in sim time).

    The plant steps its 1 ms chunks up to a chunk and a wake-up behind its pacing line, and a
    twin takes each sample as soon as its clock says it is due: give the twins PlantClock, which
    holds their time back to what the plant has stepped. (On the plain real-time clock about half
    the samples would hold the previous chunk's value: measured coherence with the plant 0.93
    instead of 0.998 over 5–50 Hz.) Times before the ring hold its oldest chunk; times past the
    plant's newest chunk (a plant not paced, or stalled) hold it for up to `hold_s`, then the
    acceleration is 0: a stopped plant shakes nothing.
    """

    def __init__(
        self,
        plant: LivePlant,
        scale: float = 1.0,
        gamma_rad: float = 0.0,
        axis: int = 0,
        lever_m: float = 0.01,
        leak_tau_s: float = 1.0,
        hold_s: float = 0.1,
        still_below_rad_s: float = 0.0,
    ) -> None:
        if axis not in (0, 1, 2) or leak_tau_s <= 0 or hold_s < 0 or still_below_rad_s < 0:
            raise UsageError(
                "PlantMotion: axis 0, 1 or 2, leak_tau_s > 0, hold_s >= 0, still_below_rad_s >= 0"
            )
        # The vibration comes from the turning aperture: with the shaft slower than this the frame
        # feels none of the plant's disturbance (0: always, as a bench of the disturbance alone).
        # The plant's Δv runs at rest too; passed on, it moved the PL twin by ~4°/s at 0 rev/s and
        # the calibration's motion check refused every SIL calibration.
        self.still_below_rad_s = still_below_rad_s
        self.plant, self.scale = plant, scale
        self.gamma_rad, self.axis, self.lever_m = gamma_rad, axis, lever_m
        self.leak_tau_s, self.hold_s = leak_tau_s, hold_s
        self._s_last: float | None = None  # sim time of the last sample
        self._omega = 0.0  # the leaky rate there (the mounts at rest before the first sample)
        self._shaft = 0.0  # the plant's shaft rate at the last sample, rad/s

    @property
    def rotation_hz(self) -> float:
        return self._shaft / (2 * np.pi)

    def sample(self, t: np.ndarray) -> MotionSample:
        t = np.asarray(t, dtype=np.float64)
        if t.size == 0:
            return MotionSample(np.zeros((0, 3)), np.zeros((0, 3)))
        s = np.asarray(self.plant.host_to_sim(t), dtype=np.float64)
        if self._s_last is None:
            self._s_last = float(s[0])
        if s[0] < self._s_last - 1e-12:
            raise ValueError(f"motion sampled backwards in time ({s[0]} < {self._s_last})")
        h = self.plant.history(self._s_last)
        ends, accel = h.t, h.disturbance * self.scale * (np.abs(h.omega) >= self.still_below_rad_s)
        stop = float(ends[-1] + self.hold_s)  # past it the plant is not running: no acceleration
        rate, pos, omega = leaky_rate(  # exact over each constant piece: ω̇ = a − ω/τ
            s, np.ascontiguousarray(ends, np.float64), np.ascontiguousarray(accel, np.float64),
            stop, self.leak_tau_s, self._omega, self._s_last,
        )  # fmt: skip
        now = h.at(s)
        turning = np.abs(now.omega) >= self.still_below_rad_s
        # The leak (τ_leak = 1 s) only keeps an integrated random acceleration bounded; it is not
        # how the frame settles: on its mounts it comes to rest within their ring-down (tens of
        # ms). Left to the leak, the rate held when the shaft stopped decayed over seconds and
        # calibrate-imu refused "pl IMU is moving" (spread 0.89, then 0.35 deg/s). At rest the
        # mounts hold no rate, as before the first sample.
        rate = np.where(turning, rate, 0.0)
        self._s_last, self._omega = pos, omega if turning[-1] else 0.0
        alpha = np.where((s <= stop) & turning, now.disturbance * self.scale, 0.0)
        self._shaft = float(now.omega[-1])
        return MotionSample(
            _axis_vector(rate, self.axis), _specific_force(alpha, self.gamma_rad, self.lever_m)
        )


class PlantClock:
    """The twins' clock when they follow a live plant: real time (time.monotonic), held back to
    the host time the plant has stepped to (LivePlant.covered_host), by at most `max_lag_s`.

    So a twin takes a sample only once the plant has computed that instant: its samples enter
    the FIFO up to ~1 ms late (the chunk and the pacing thread's wake-up), as if the sensor had
    that much more pipeline, and the reader's clock fit (a lower envelope over many reads) still
    times them to within the shortest of those lags. A stalled or stopped plant does not stop
    the sensors: past `max_lag_s` the clock runs on (PlantMotion holds, then goes still).
    Non-decreasing once the plant is paced (before that it is real time: start the plant first).
    """

    def __init__(self, plant: LivePlant, max_lag_s: float = 0.01) -> None:
        self.plant, self.max_lag_s = plant, max_lag_s

    def now(self) -> float:
        real = time.monotonic()
        covered = self.plant.covered_host()
        if math.isnan(covered):
            return real
        return max(min(real, covered), real - self.max_lag_s)

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


def plant_pair(
    plant: LivePlant,
    gamma_rad: float = 0.0,
    axis: int = 0,
    pl_coupling: float = 0.3,
    lever_m: float = 0.01,
    still_below_rps: float = 0.0,
) -> dict[str, PlantMotion]:
    """Sources for both sensors from one running plant: SA as the plant's disturbance, PL the
    same scaled by `pl_coupling` (the frame's attenuation, as synthetic_pair); both at rest while
    the shaft turns slower than `still_below_rps` (PlantMotion.still_below_rad_s)."""
    still = 2 * math.pi * still_below_rps
    return {
        "pl": PlantMotion(plant, pl_coupling, gamma_rad, axis, lever_m, still_below_rad_s=still),
        "sa": PlantMotion(plant, 1.0, gamma_rad, axis, lever_m, still_below_rad_s=still),
    }
