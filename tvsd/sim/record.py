"""SIL recordings in the recording-CSV contract, with a realistic measurement.

Profiles:
- ``steps``: open-loop voltage staircase, levels of both signs between 5 % and 100 % of the drive
  limit, held 1.5–4 s (the default plant's mechanical time constant is 2.4 s), so the recording
  holds a mix of speeds and directions, near-zero levels and full-scale ones;
- ``spin``: the scanning mode from rest to `rps` (closed loop, the robust law).
Measurement: the encoder angle quantised to its counts, the speed as the mean over each sample
period plus Gaussian noise (a tachometer / encoder-period estimate), the command as the mean
voltage over the period. The effects switched on are not written to the file: tests hide them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvsd.causes import Effect
from tvsd.config import Config, MeasurementConfig
from tvsd.control.setup import Setup
from tvsd.errors import UsageError
from tvsd.recording.csvfile import write
from tvsd.sim import runs

PROFILES = ("steps", "spin")


def staircase(rng: np.random.Generator, seconds: float, u_max: float, dt: float) -> np.ndarray:
    """Open-loop voltage staircase, one value per simulation step."""
    n = round(seconds / dt)
    u = np.empty(n)
    k = 0
    sign = 1.0
    while k < n:
        hold = round(rng.uniform(1.5, 4.0) / dt)
        level = u_max * rng.uniform(0.05, 1.0)
        if rng.random() < 0.6:  # change direction often: friction and dead zone show at reversals
            sign = -sign
        u[k : k + hold] = sign * level
        k += hold
    u[: round(0.2 / dt)] = 0.0  # start at rest, as a recording would
    return u


@dataclass(frozen=True)
class RecordResult:
    path: Path
    profile: str
    seconds: float
    rows: int
    sample_rate_hz: float


def measure(trace: runs.Trace, m: MeasurementConfig, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """What the scanner's sensors would have reported for a decimated trace."""
    count = 2 * math.pi / m.encoder_counts_per_rev
    return {
        "t": trace.t - trace.t[0],
        "u": trace.u_mean,
        "omega": trace.omega_mean + rng.normal(0.0, m.speed_noise_rad_s, len(trace.t)),
        "phi": np.floor(trace.phi / count) * count,
    }


def record(
    cfg: Config,
    out: Path,
    profile: str,
    seconds: float,
    effects: tuple[Effect, ...],
    seed: int,
    rps: float = 20.0,
    params_name: str = "default",
) -> RecordResult:
    if profile not in PROFILES:
        raise UsageError(f"unknown profile '{profile}'; choose {' or '.join(PROFILES)}")
    m = cfg.sil_or_default.measurement
    setup = Setup.from_config(cfg, effects=effects, seed=seed)
    decim = round(1.0 / (setup.dt * m.sample_rate_hz))
    if decim < 1 or abs(decim * setup.dt * m.sample_rate_hz - 1.0) > 1e-9:
        raise UsageError(
            f"sample_rate_hz {m.sample_rate_hz:g} must divide the loop rate "
            f"{1 / setup.dt:g} Hz; choose e.g. 1000"
        )
    rng = np.random.default_rng(seed)
    if profile == "steps":
        trace = runs.open_loop(setup, staircase(rng, seconds, setup.u_max, setup.dt), decim)
        meta: dict[str, object] = {"profile": "steps"}
    else:
        trace = runs.spin(setup, rps, seconds, decim)
        meta = {"profile": "spin", "rps_setpoint": rps}
    cols = measure(trace, m, rng)
    meta.update(
        {
            "source": "tvsctl sim record",
            "params": params_name,
            "seed": seed,
            "vibration_model": setup.vibration_model,
            "encoder_counts_per_rev": m.encoder_counts_per_rev,
        }
    )
    write(out, cols["t"], cols["u"], cols["omega"], cols["phi"], m.sample_rate_hz, meta)
    return RecordResult(out, profile, seconds, len(trace.t), m.sample_rate_hz)
