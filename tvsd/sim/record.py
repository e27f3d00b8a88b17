"""SIL recordings in the recording-CSV contract, with a realistic measurement.

Profiles:
- ``steps``: open-loop voltage staircase, levels of both signs between 5 % and 100 % of the drive
  limit, held 1.5–4 s (the default plant's mechanical time constant is 2.4 s), so the recording
  holds a mix of speeds and directions, near-zero levels and full-scale ones;
- ``multisine``: open-loop, a PRBS (random-sign levels held 20–300 ms) on a multisine, both
  within the drive limit: broadband excitation, many reversals;
- ``spin``: the scanning mode from rest to `rps` (closed loop, the robust law); the controller's
  reference goes into the file as ``omega_ref``, ``phi_ref`` (as the daemon's export does);
- ``identify``: ``spin``, then from 1 s after the ramp `tvsctl identify`'s excitation (config
  ``identify:``, its seed the record's: speed-reference steps and multisine, PRBS on the voltage)
  until the end, as the daemon plays it (tvsd.control.excitation); the column ``u_exc`` holds the
  voltage it added after the law (the PRBS), as the daemon's export does.
What ``u`` is follows ``u_unit`` (DESIGN.md): ``V`` the drive voltage; ``A`` the motor current
(as a current-controlled drive reports it); ``N*m`` the torque kM·i; ``duty`` the voltage over the
drive limit, with ``u_scale`` = that limit.
Measurement: the encoder angle quantised to its counts, the speed as the mean over each sample
period plus Gaussian noise (a tachometer / encoder-period estimate), the command as the mean
voltage over the period. The effects switched on are not written to the file: tests hide them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvsd.causes import Effect
from tvsd.config import Config, MeasurementConfig
from tvsd.control import excitation
from tvsd.control.setup import Setup
from tvsd.errors import UsageError
from tvsd.recording.csvfile import format_lines, write
from tvsd.sim import runs

PROFILES = ("steps", "multisine", "spin", "identify")
U_UNITS = ("V", "A", "N*m", "duty")
MULTISINE_HZ = tuple(float(f) for f in np.geomspace(0.2, 20.0, 8))  # the open-loop multisine's lines


def multisine(rng: np.random.Generator, seconds: float, u_max: float, dt: float) -> np.ndarray:
    """PRBS on a multisine (0.2–20 Hz, random phases), scaled into ±u_max."""
    n = round(seconds / dt)
    t = np.arange(n) * dt
    u = np.zeros(n)
    for f in MULTISINE_HZ:
        u += np.sin(2 * math.pi * f * t + rng.uniform(0, 2 * math.pi))
    u *= 0.35 * u_max / max(float(np.max(np.abs(u))), 1e-12)
    k = 0
    while k < n:
        hold = round(rng.uniform(0.02, 0.3) / dt)
        u[k : k + hold] += 0.6 * u_max * (1.0 if rng.random() < 0.5 else -1.0) * rng.uniform(0.3, 1.0)
        k += hold
    u = np.clip(u, -u_max, u_max)
    u[: round(0.2 / dt)] = 0.0
    return u


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


def identify_table(
    cfg: Config, setup: Setup, rps: float, seconds: float, seed: int, lines_hz: list[float] | None = None
) -> tuple[np.ndarray, float]:
    """`tvsctl identify`'s excitation as the closed-loop kernel's table (one row per controller
    period), starting 1 s after the ramp to `rps`; and that start, s. `lines_hz` (when given)
    receives the multisine's frequencies, which the recording declares."""
    lines_hz = [] if lines_hz is None else lines_hz
    start = abs(rps) / cfg.control.scan_accel_rps2 + 1.0
    length = seconds - start
    if length < 1.0:
        raise UsageError(
            f"--seconds {seconds:g}: the identify profile needs {start + 1:.3g} s or more "
            f"(ramp to {rps:g} rev/s, then at least 1 s of excitation)"
        )
    ident = dataclasses.replace(cfg.identify, seconds=length, max_seconds=max(length, 1.0), seed=seed)
    ex = excitation.build(ident, rps, cfg.control.scan_accel_rps2)
    lines_hz[:] = ex.lines_hz
    n = round(seconds / setup.dt)
    k0 = round(start / setup.dt)
    table = np.zeros((n, 2))
    rows = np.minimum(((np.arange(n - k0) * setup.dt) / ex.period_s).astype(np.int64), len(ex.d_rps) - 1)
    table[k0:, 0] = ex.d_rps[rows]
    table[k0:, 1] = ex.d_volts[rows]
    return table, start


RK4_LIMIT = 1.5  # h·R/L kept below this: RK4's stability limit on the real axis is 2.79
MAX_SUBSTEPS = 1000  # plant steps per control tick: 0.1 µs at 10 kHz


def substeps_for(cfg: Config, effects: tuple[Effect, ...]) -> int:
    """Plant steps per controller period so that the electrical pole −R/L stays inside RK4's
    stability region all run long (a drifting R included): at 10 kHz the paper's motor has
    h·R/L = 0.85, so a winding with 3× its R and the same L (or such an R drifting up) would
    integrate to 1e15 rad/s."""
    r = cfg.plant.R
    for e in effects:
        if e.name == "drift" and e.params.get("parameter") == "R":
            r *= max(1.0, 1.0 + float(e.params.get("relative_change", 0.0)))
    n = max(1, math.ceil(r / cfg.plant.L / cfg.control.rate_hz / RK4_LIMIT))
    if n > MAX_SUBSTEPS:  # a run would take hours (L = 1e-12 H: 7.6e8 plant steps per tick)
        tau = cfg.plant.L / r
        shortest = RK4_LIMIT / (MAX_SUBSTEPS * cfg.control.rate_hz)
        raise UsageError(
            f"plant.L / plant.R = {tau:.3g} s, an electrical time constant below the {shortest:.3g} s "
            f"the simulator resolves; check plant.L ({cfg.plant.L:g} H: henries, not mH) and plant.R"
        )
    return n


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
    u_unit: str = "V",
) -> RecordResult:
    if profile not in PROFILES:
        raise UsageError(f"unknown profile '{profile}'; choose {', '.join(PROFILES)}")
    if u_unit not in U_UNITS:
        raise UsageError(f"unknown u_unit '{u_unit}'; choose {', '.join(U_UNITS)}")
    m = cfg.sil_or_default.measurement
    setup = Setup.from_config(cfg, effects=effects, seed=seed, substeps=substeps_for(cfg, effects))
    decim = round(1.0 / (setup.dt * m.sample_rate_hz))
    if decim < 1 or abs(decim * setup.dt * m.sample_rate_hz - 1.0) > 1e-9:
        raise UsageError(
            f"sample_rate_hz {m.sample_rate_hz:g} must divide the loop rate "
            f"{1 / setup.dt:g} Hz; choose e.g. 1000"
        )
    rng = np.random.default_rng(seed)
    extra: dict[str, np.ndarray] = {}
    if profile in ("steps", "multisine"):
        shape = staircase if profile == "steps" else multisine
        trace = runs.open_loop(setup, shape(rng, seconds, setup.u_max, setup.dt), decim)
        meta: dict[str, object] = {"profile": profile}
        if profile == "multisine":
            meta["excitation_hz"] = format_lines(MULTISINE_HZ)
    elif profile == "spin":
        trace = runs.spin(setup, rps, seconds, decim)
        meta = {"profile": "spin", "rps_setpoint": rps}
        extra = {"omega_ref": np.gradient(trace.phi_ref, trace.t), "phi_ref": trace.phi_ref}
    else:
        lines: list[float] = []
        exc, start = identify_table(cfg, setup, rps, seconds, seed, lines)
        trace = runs.spin_excited(setup, rps, seconds, exc, decim)
        meta = {"profile": "identify", "rps_setpoint": rps, "excitation_start_s": start}
        if lines:  # the multisine's lines: the doctor leaves them out of its resonance scan
            meta["excitation_hz"] = format_lines(lines)
        extra = {"omega_ref": np.gradient(trace.phi_ref, trace.t), "phi_ref": trace.phi_ref}
        # The voltage the excitation added after the law, averaged per sample as u is: exogenous,
        # so the doctor's instrument (tvsd.analysis.instrument), as `tvsctl export` writes it.
        n_rec = len(trace.t)
        extra["u_exc"] = exc[: n_rec * decim, 1].reshape(n_rec, decim).mean(axis=1)
    cols = measure(trace, m, rng)
    meta["u_unit"] = u_unit
    meta["u_sampling"] = "mean"  # u and ω are both means over the row's interval (measure())
    if u_unit == "A":
        cols["u"] = trace.current
    elif u_unit == "N*m":
        cols["u"] = cfg.plant.kM * trace.current
    elif u_unit == "duty":
        cols["u"] = cols["u"] / setup.u_max
        meta["u_scale"] = setup.u_max
    meta.update(
        {
            "source": "tvsctl sim record",
            "params": params_name,
            "seed": seed,
            "vibration_model": setup.vibration_model,
            "encoder_counts_per_rev": m.encoder_counts_per_rev,
        }
    )
    write(out, cols["t"], cols["u"], cols["omega"], cols["phi"], m.sample_rate_hz, meta, extra)
    return RecordResult(out, profile, seconds, len(trace.t), m.sample_rate_hz)
