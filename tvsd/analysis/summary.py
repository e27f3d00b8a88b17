"""The doctor's verdict as the DESIGN.md JSON object and as one sentence a technician understands."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tvsd.analysis.doctor import Diagnosis, Scored
from tvsd.analysis.lyapunov import exponents
from tvsd.analysis.simulate import no_effect

# What each cause means on the machine, for the one-sentence verdict.
SENTENCES = {
    "none": "The paper's model explains this recording: nothing the model misses is significant.",
    "imbalance": "The rotor is out of balance: a torque of {amplitude:.3g} {effort} pulls once per "
    "revolution (phase {phase:.2f} rad); balance the mirror assembly or check it for a loose part.",
    "cogging": "The motor cogs: a torque of {amplitude:.3g} {effort} repeats {order:d} times per revolution; "
    "this is the motor's magnet/slot structure or a damaged bearing race.",
    "resonance": "A structural mode rings at {frequency_hz:.2f} Hz ({amplitude:.3g} {effort}) whatever the "
    "speed; stiffen or damp the mount, and keep the scanning rate away from it.",
    "saturation": "The drive clips the voltage at ±{u_max:.3g} V, below what the controller asks for; "
    "check the supply voltage or lower the requested speed/acceleration.",
    "deadzone": "The drive does nothing for commands below {u0:.3g} V (a dead band); "
    "check the H-bridge's minimum duty or compensate it in the controller.",
    "delay": "The drive applies the command {delay_ms:.1f} ms late; check the PWM update path "
    "and the MCU link latency.",
    "friction_asymmetry": "Friction is {ratio:.2f}× as strong turning backwards as forwards; "
    "inspect the bearings or the transmission for wear or preload on one side.",
    "colored_noise": "The vibration disturbance is low-pass correlated (correlation time {tau_ms:.0f} ms), "
    "not white as the paper assumes: look for a slow external source (floor, robot base).",
    "drift": "The motor's {parameter} changed by {relative_change_pct:+.1f} % during the recording; "
    "check for heating (R, kM) or lubrication changes (kv, friction).",
}


def sentence(dg: Diagnosis) -> str:
    best = dg.best
    if best is None:
        return SENTENCES["none"]
    values: dict[str, Any] = {**best.effect, "effort": dg.data.units.effort}
    if best.cause == "delay":
        values["delay_ms"] = 1e3 * float(best.effect["delay_s"])
    if best.cause == "colored_noise":
        values["tau_ms"] = 1e3 * float(best.effect["tau_s"])
    if best.cause == "drift":
        values["relative_change_pct"] = 100 * float(best.effect["relative_change"])
    if "order" in values:
        values["order"] = int(values["order"])
    text = SENTENCES[best.cause].format(**values)
    if best.ambiguous_with:
        text += (
            f" (At the steady speed held out, a fixed {best.ambiguous_with} line at the same "
            "frequency fits as well; a recording that changes speed would tell them apart.)"
        )
    return text


def _effect_json(s: Scored) -> dict[str, Any]:
    keep = {
        "imbalance": ("order", "amplitude", "phase"),
        "cogging": ("order", "amplitude", "phase"),
        "resonance": ("frequency_hz", "amplitude", "phase"),
        "saturation": ("u_max",),
        "deadzone": ("u0",),
        "delay": ("delay_s",),
        "friction_asymmetry": ("ratio",),
        "colored_noise": ("tau_s",),
        "drift": ("parameter", "relative_change"),
    }[s.cause]
    out = {k: s.effect[k] for k in keep if k in s.effect}
    if "order" in out:
        out["order"] = int(out["order"])
    return out


def as_json(dg: Diagnosis, report: str | None = None) -> dict[str, Any]:
    best = dg.best
    base = dg.baseline
    ext_params = dict(base.fit.params())
    if best is not None and best.fit is not None:
        ext_params = best.fit.params()
        ext_params.update({k: v for k, v in _effect_json(best).items()})
    lam1, lam_speed = lyapunov(dg)
    units = dg.data.units
    out: dict[str, Any] = {
        "cause": dg.cause,
        "effect": _effect_json(best) if best else {},
        "candidates": [
            {
                "cause": s.cause,
                "score": s.z,
                "gain_pct": s.heldout_gain_pct,
                "significant": s.significant,
                "effect": _effect_json(s),
                **({"ambiguous_with": s.ambiguous_with} if s.ambiguous_with else {}),
            }
            for s in dg.ranked
        ],
        "baseline": {
            "params": base.fit.params(),
            "stderr": {n: base.fit.stderr(n) for n in base.fit.names},
            "static_map": base.static,
            "idim_ls": base.ls.params(),
            "heldout_rmse": dg.heldout_rmse_base,
        },
        "extended": {"params": ext_params, "heldout_rmse": dg.heldout_rmse_ext},
        "gain_pct": dg.gain_pct,
        "summary": sentence(dg),
        "units": {"speed": units.speed, "effort": units.effort, "axis": units.axis},
        "heldout": "file" if dg.heldout_cols is not None else "last third of the recording",
        "noise": {
            "sigma_v": dg.noise.sigma_v,
            "ljung_box_p": dg.noise.ljung_box_p,
            "colour_p": dg.noise.colour_p,
            "tau_s": dg.noise.tau_s,
        },
        "lyapunov": {
            "lambda1_per_s": lam1,
            "lambda_speed_per_s": lam_speed,
            "chaotic": bool(lam1 > 0.05 * abs(lam_speed)),
        },
        "inverse_error_pct": inverse_error_pct(dg),
        "spectrum": spectral_view(dg),
    }
    if report:
        out["report"] = report
    return out


def lyapunov(dg: Diagnosis) -> tuple[float, float]:
    cols = dg.cols
    d = cols.prep.data
    effect = dg.best.candidate.effect_array() if dg.best and dg.best.candidate else no_effect()
    speed = d.speed if d.speed is not None else cols.prep.speed
    return exponents(dg.baseline.model, d.t, speed, d.position, effect)


def spectral_view(dg: Diagnosis) -> dict[str, float]:
    """Dominant line of the measured acceleration and of the simulated models' (paper Table 2).

    The acceleration is the derivative of the band-limited speed on the held-out part, as an SA
    IMU would see it; the models are simulated from the recorded command.
    """
    from tvsd.sim.metrics import dominant_frequency

    sim, d = dg.sim, dg.data
    m = sim["heldout"]
    rate = d.sample_rate_hz
    out = {}
    for key in ("measured", "baseline", "extended"):
        accel = np.gradient(dg.cols.prep.lowpass(sim[key]), 1.0 / rate)[m]
        hz, amp = dominant_frequency(accel, rate, min_hz=1.0, resolution_hz=0.25)
        out[f"{key}_dominant_hz"] = hz
        out[f"{key}_dominant_amplitude"] = amp
    w = np.abs(sim["measured"][m])
    out["rotation_hz"] = float(np.median(w)) / (2 * math.pi) if d.units.axis == "rotary" else math.nan
    return out


def inverse_error_pct(dg: Diagnosis) -> dict[str, float]:
    """Relative error of the inverse (effort) model on the fitting rows, % — EMPS' 'force error'."""
    cols = dg.cols
    m = cols.fit_rows
    y = cols.y[m]

    def rel(resid: np.ndarray) -> float:
        return 100 * math.sqrt(float(np.mean(resid**2)) / float(np.mean(y**2)))

    out = {"baseline": rel(dg.baseline.fit.residual), "baseline_idim_ls": rel(dg.baseline.ls.residual)}
    if dg.best is not None and dg.best.fit is not None:
        out["extended"] = rel(dg.best.fit.residual)
    asym = next((s for s in dg.ranked if s.cause == "friction_asymmetry" and s.candidate), None)
    if asym is not None and asym.candidate is not None:
        out["friction_asymmetry_idim_ls"] = rel(asym.candidate.fit.residual)  # EMPS' asymmetric model
    return out
