"""The paper's experiments on the model: step responses (Table 6), spin-ups (Table 2).

Each function returns a result object with `as_dict()` in the JSON shape `tvsctl sim` prints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tvsd.causes import Effect, parse_effects
from tvsd.config import Config, Gains
from tvsd.control.conditions import check_gains, warnings
from tvsd.control.setup import Setup
from tvsd.errors import UsageError
from tvsd.sim import metrics, runs
from tvsd.sim.record import substeps_for
from tvsd.sim.spectrum import Spectrum, welch_lines

# A spin is judged once the reference has reached its speed and the loop has settled: the default
# loop settles in ≈ 0.5 s (8 Hz, ζ 0.7); 1 s leaves margin for the paper set's slower modes.
SETTLE_AFTER_RAMP_S = 1.0
MIN_STEADY_S = 1.0
IMU_RATE_HZ = 1000.0  # the SA vibration is analysed as the IMU samples it (MODEL-NOTES §4: ≥ 1 kHz)


def _finite(trace: runs.Trace, cfg: Config, setup: Setup) -> runs.Trace:
    """The run, or a usage error when the plant's numbers put a mode beyond the integrator's step:
    `sim step` printed `final_deg: null`, exit 0, for a J of 1e-10 kg·m²."""
    bad = ~(np.isfinite(trace.phi) & np.isfinite(trace.omega))
    if not bad.any():
        return trace
    p, h = cfg.plant, setup.dt / setup.substeps
    raise UsageError(
        f"the simulation diverged at t = {float(trace.t[int(np.argmax(bad))]):.4g} s: the plant's numbers "
        f"put a mode beyond the {h * 1e6:.3g} µs integration step (bristle h·√(σ0/J) = "
        f"{h * math.sqrt(p.sigma0 / p.J):.3g}, electrical h·R/L = {h * p.R / p.L:.3g}; each must stay "
        f"below ~2.8); check plant.J = {p.J:g} kg·m², plant.sigma0, plant.R and plant.L in the config"
    )


@dataclass(frozen=True)
class StepResult:
    ref_deg: float
    settling_time_s: float
    overshoot_pct: float
    final_deg: float
    warnings: tuple[str, ...]
    trace: runs.Trace = field(repr=False)

    def as_dict(self) -> dict[str, Any]:
        return {
            "ref_deg": self.ref_deg,
            "settling_time_s": self.settling_time_s,
            "overshoot_pct": self.overshoot_pct,
            "final_deg": self.final_deg,
            "warnings": list(self.warnings),
        }


def step(
    cfg: Config,
    ref_deg: float,
    seconds: float = 1.0,
    gains: Gains | None = None,
    ku: float | None = None,
    vibration_off: bool = True,
    substeps: int = 1,
) -> StepResult:
    """Position step from rest; the paper's Table 6 runs have no vibration (vibration_off)."""
    if not 0 < abs(ref_deg) <= 360:
        raise UsageError(f"--ref-deg {ref_deg:g} is outside (0, 360] degrees in magnitude")
    if not 0.001 <= seconds <= 60:
        raise UsageError(f"--seconds {seconds:g} is outside [0.001, 60] s")
    from tvsd.config import VibrationConfig

    vib = VibrationConfig(model="off") if vibration_off else None
    substeps = max(substeps, substeps_for(cfg, ()))
    setup = Setup.from_config(cfg, gains=gains, ku=ku, vibration=vib, substeps=substeps)
    ref = math.radians(ref_deg)
    trace = _finite(runs.step_response(setup, ref, seconds), cfg, setup)
    conds = check_gains(setup.gains, cfg.plant, cfg.control.disturbance_bound_rad_s2, ku=ku)
    return StepResult(
        ref_deg=ref_deg,
        settling_time_s=metrics.settling_time(trace.t, trace.phi, ref),
        overshoot_pct=metrics.overshoot_pct(trace.phi, ref),
        final_deg=math.degrees(float(trace.phi[-1])),
        warnings=tuple(warnings(conds)),
        trace=trace,
    )


@dataclass(frozen=True)
class Table6Row:
    ref_deg: float
    paper_s: float
    ours_s: float
    error_pct: float


@dataclass(frozen=True)
class Table6Result:
    rows: tuple[Table6Row, ...]
    rms_error_pct: float
    ku: float
    gains: Gains

    def as_dict(self) -> dict[str, Any]:
        return {
            "rows": [r.__dict__ for r in self.rows],
            "rms_error_pct": self.rms_error_pct,
            "ku": self.ku,
            "gains": self.gains.__dict__,
        }


def table6(cfg: Config, ku: float | None = None) -> Table6Result:
    rep = cfg.reproduction
    if rep is None or not rep.table6_refs_deg:
        raise UsageError("this config has no Table 6 to reproduce; use --params paper")
    ku_used = rep.table6_ku if ku is None else ku
    rows = []
    for ref_deg, paper_s in zip(rep.table6_refs_deg, rep.table6_settling_s, strict=True):
        ours = step(cfg, ref_deg, 0.3, ku=ku_used).settling_time_s
        rows.append(Table6Row(ref_deg, paper_s, ours, 100.0 * (ours - paper_s) / paper_s))
    rms = float(np.sqrt(np.mean([r.error_pct**2 for r in rows])))
    return Table6Result(tuple(rows), rms, ku_used, cfg.control.gains)


@dataclass(frozen=True)
class SpinResult:
    rps: float
    rps_mean: float
    rps_std: float
    omega_std_rad_s: float
    dominant_hz: float | None  # None: no line clears the noise floor (spectrum.Spectrum's test)
    dominant_amplitude_rad_s2: float | None
    line_to_floor: float  # the strongest bin's power over the floor there
    line_threshold: float  # what a line must exceed (1 % false alarms per spectrum)
    steady_from_s: float
    vibration_model: str
    effects: tuple[str, ...]
    reference_slips: int
    trace: runs.Trace = field(repr=False)
    spectrum: Spectrum = field(repr=False)

    def as_dict(self) -> dict[str, Any]:
        return {
            "rps_mean": self.rps_mean,
            "rps_std": self.rps_std,
            "omega_std_rad_s": self.omega_std_rad_s,
            "dominant_hz": self.dominant_hz,
            "dominant_amplitude_rad_s2": self.dominant_amplitude_rad_s2,
            "line_to_floor": self.line_to_floor,
            "line_threshold": self.line_threshold,
            "rps_setpoint": self.rps,
            "steady_from_s": self.steady_from_s,
            "vibration_model": self.vibration_model,
            "effects": list(self.effects),
            "reference_slips": self.reference_slips,
        }


def spin(
    cfg: Config,
    rps: float,
    seconds: float,
    effects: tuple[Effect, ...] | None = None,
    seed: int | None = None,
) -> SpinResult:
    """Spin up in scanning mode and measure speed steadiness and the SA vibration's dominant line."""
    if not 0.5 <= abs(rps) <= 100:
        raise UsageError(f"--rps {rps:g} is outside the drive's range 0.5–100 rev/s (either sign)")
    ramp_s = abs(rps) / cfg.control.scan_accel_rps2
    steady_from = ramp_s + SETTLE_AFTER_RAMP_S
    if seconds > 3600:
        raise UsageError(f"--seconds {seconds:g} is over an hour; simulate at most 3600 s")
    if seconds < steady_from + MIN_STEADY_S:
        raise UsageError(
            f"--seconds {seconds:g} is too short: reaching {rps:g} rev/s at "
            f"{cfg.control.scan_accel_rps2:g} rev/s² and settling takes {steady_from:.1f} s; "
            f"use --seconds {math.ceil(steady_from + 2)} or more"
        )
    # The paper's spinning runs were open loop with ku ≈ 166 (MODEL-NOTES §3); its closed-loop ku
    # (≈ 10) cannot reach scanning speed within the drive's voltage.
    ku = cfg.reproduction.open_loop_ku if cfg.reproduction is not None else None
    used = effects if effects is not None else parse_effects(cfg.sil_or_default.effects)
    setup = Setup.from_config(cfg, effects=used, seed=seed, ku=ku, substeps=substeps_for(cfg, used))
    decim = round(1.0 / (setup.dt * IMU_RATE_HZ))
    trace = _finite(runs.spin(setup, rps, seconds, decim), cfg, setup)
    steady = trace.t >= steady_from
    omega = trace.omega_mean[steady]
    dom_hz, dom_amp = metrics.dominant_frequency(trace.disturbance[steady], IMU_RATE_HZ)
    # The strongest bin of pure noise is no line: report one only where the Welch estimate's
    # bin clears the floor by the test of tvsd.sim.spectrum (the plot draws the same estimate).
    lines = welch_lines(trace.disturbance[steady], IMU_RATE_HZ)
    ratio = lines.ratio_at(dom_hz) if math.isfinite(dom_hz) else 0.0
    is_line = ratio > lines.threshold
    return SpinResult(
        rps=rps,
        rps_mean=float(np.mean(omega) / (2 * math.pi)),
        rps_std=float(np.std(omega) / (2 * math.pi)),
        omega_std_rad_s=float(np.std(omega)),
        dominant_hz=dom_hz if is_line else None,
        dominant_amplitude_rad_s2=dom_amp if is_line else None,
        line_to_floor=ratio,
        line_threshold=lines.threshold,
        steady_from_s=steady_from,
        vibration_model=setup.vibration_model,
        effects=tuple(str(e) for e in setup.effect_list),
        reference_slips=trace.slips,
        trace=trace,
        spectrum=lines,
    )
