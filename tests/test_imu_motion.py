"""The motion sources that drive the IMU twins: statistics and lines as parametrised."""

from __future__ import annotations

import numpy as np
import pytest

from tvsd.sim.imu_motion import GRAVITY, ArrayMotion, SyntheticMotion, SyntheticParams


def alpha_of(sample, params):
    """Recover α from the tangential term lever·α on the accelerometer's Y axis."""
    return (sample.accel[:, 1] - GRAVITY * np.sin(params.gamma_rad)) / params.lever_m


@pytest.mark.parametrize("dt", [1e-3, 2.5e-4])
def test_ou_vibration_has_its_std_whatever_the_step(dt):
    p = SyntheticParams(rps=0, imbalance_rad_s2=0, vibration_std_rad_s2=0.8, vibration_tau_s=0.005, seed=2)
    motion = SyntheticMotion(p)
    t = np.arange(0, 100.0, dt)
    alpha = np.concatenate([alpha_of(motion.sample(c), p) for c in np.array_split(t, 7)])
    # 100 s / (2 tau) = 1e4 independent stretches: std known to ~0.7 %; 3 % is > 4 sigma
    assert abs(alpha.std() / 0.8 - 1) < 0.03
    # correlation time: lag-tau autocorrelation of an OU process is 1/e
    lag = round(0.005 / dt)
    r = np.corrcoef(alpha[:-lag], alpha[lag:])[0, 1]
    assert abs(r - np.exp(-1)) < 0.03


def test_imbalance_line_and_gravity_direction():
    gamma = np.radians(20)
    p = SyntheticParams(rps=19.87, imbalance_rad_s2=1.5, vibration_std_rad_s2=0, gamma_rad=gamma)
    m = SyntheticMotion(p).sample(np.arange(0, 2.0, 1e-4))
    alpha = alpha_of(m, p)
    assert abs(alpha.max() - 1.5) < 1e-3 and abs(alpha.min() + 1.5) < 1e-3
    # the gyro about the SA axis is the line's exact integral: its derivative is α
    d = np.gradient(m.gyro[:, 0], 1e-4)
    assert np.max(np.abs(d - alpha)[10:-10]) < 1e-3 * 1.5  # central difference, 500 pts/period
    assert np.allclose(m.accel[:, 2] - p.lever_m * alpha, GRAVITY * np.cos(gamma))
    assert np.all(m.gyro[:, 1:] == 0)


def test_motion_refuses_to_go_back_in_time():
    motion = SyntheticMotion(SyntheticParams())
    motion.sample(np.array([1.0, 1.001]))
    with pytest.raises(ValueError, match="backwards"):
        motion.sample(np.array([0.5]))


def test_array_motion_integrates_alpha_and_stays_in_its_span():
    t = np.arange(0, 8.0, 1e-4)
    alpha = 2.0 * np.sin(2 * np.pi * 25 * t)
    motion = ArrayMotion(t, alpha)
    m = motion.sample(np.arange(6.0, 7.0, 1e-4))
    # leaky integral (tau 1 s) of a 25 Hz sine started at rest: amplitude A/(2 pi f), plus the
    # start's offset A/(2 pi f) decaying as exp(-t/1 s): it moves 0.16 % over 6..7 s
    amplitude = 2.0 / (2 * np.pi * 25)
    assert abs(np.ptp(m.gyro[:, 0]) / 2 / amplitude - 1) < 5e-3
    with pytest.raises(ValueError, match="covers"):
        motion.sample(np.array([7.5, 8.5]))
    with pytest.raises(ValueError, match="increasing"):
        ArrayMotion(np.array([0.0, 0.0, 1.0]), np.zeros(3))
