"""The doctor's verdict as the DESIGN.md JSON object and as one sentence a technician understands."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tvsd.analysis import speed_source
from tvsd.analysis.doctor import ALPHA, Diagnosis
from tvsd.analysis.heldout_sim import effect_array
from tvsd.analysis.lyapunov import Lyapunov, estimate
from tvsd.model import effects as E

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
    "model_mismatch": "The paper's model does not fit this recording, so no cause is named: {reason}. "
    "Check the input unit (# u_unit), the columns, and that the data come from one rigid drive.",
    "drift": "The motor's {parameter} changed by {relative_change_pct:+.1f} % during the recording; "
    "check for heating (R, kM) or lubrication changes (kv, friction).",
}


def refused(dg: Diagnosis) -> list[Any]:
    """Candidates that looked like a cause and were not named: above the z gate, or coloured
    noise below its own spectral test's p-value (noise.COLOUR_P)."""
    from tvsd.analysis.noise import COLOUR_P

    out = []
    for s in dg.ranked:
        if s.significant or s.why_not is None or s.cause == dg.cause:
            continue
        colour = s.cause == "colored_noise"
        if (colour and s.p < COLOUR_P) or (
            not colour and dg.outcome.significant and s.z > dg.outcome.threshold
        ):
            out.append(s)
    return out


def _refused_text(dg: Diagnosis) -> str:
    parts = []
    for s in sorted(refused(dg), key=lambda s: s.cause == "colored_noise"):
        if s.cause == "colored_noise" and s.why_not[0] == "closed_loop_colour":
            parts.append(
                f"colored_noise is judged by its own spectral test (p = {s.p:.3g}), not by the z gate, "
                "and not in closed loop, where the feedback shapes the residual's spectrum"
            )
        elif s.cause == "colored_noise":
            parts.append(f"colored_noise is not named: {s.why_not[1]}")
        else:
            parts.append(
                f"{s.cause} was above the gate (z {s.z:.1f} > {dg.outcome.threshold:.2f}) but {s.why_not[1]}"
            )
    return "; ".join(parts)


def period_warning(data: Any, cause: str, effect: dict[str, Any]) -> str | None:
    """A torque periodic N times per revolution shows its period only over at least 1/N of a
    turn (tvsd.analysis.exposure's `revolutions`); below that its sine and cosine columns are
    a slow trend in the angle, which many things fit. The cause stays named (the decision's
    gate and checks passed), with this said."""
    if cause not in ("imbalance", "cogging") or data.units.axis != "rotary":
        return None
    order = max(int(effect.get("order", 1)), 1)
    phi = np.asarray(data.position, dtype=float)
    revs = float(np.max(phi) - np.min(phi)) / (2 * math.pi) if len(phi) else 0.0
    if revs >= 1.0 / order:
        return None
    turn = "a turn" if order == 1 else f"1/{order} turn"
    return (
        f"the shaft's angle spans {revs:.2g} revolutions, less than one period of this "
        f"{order}-per-revolution torque ({turn}): the period is not established in this recording"
    )


def _band(band: tuple[float, float] | None) -> list[float] | None:
    return None if band is None else [round(float(band[0]), 3), round(float(band[1]), 3)]  # Welch bins


def floor_note(dg: Diagnosis) -> str | None:
    """One short clause when the encoder's quantisation cut the colour test's band."""
    n = dg.noise
    if n.floor_cut_hz is None or n.peak_band_hz is None:
        return None
    colour = "not tested" if n.colour_band_hz is None else f"tested to {n.colour_band_hz[1]:.3g} Hz"
    return (
        f"above {n.floor_cut_hz:.3g} Hz the residual is the encoder's quantisation: noise colour "
        f"{colour}, a structural mode to {n.peak_band_hz[1]:.3g} Hz"
    )


def sentence(dg: Diagnosis) -> str:
    warn = period_warning(dg.data, dg.cause, dg.effect)
    text = _sentence(dg)
    if warn:
        text = f"{text} Caution: {warn}."
    if band := floor_note(dg):
        text = f"{text} Note: {band}."
    if retimed := dg.data.meta.get("omega_timing"):
        text = f"{text} Note: {retimed}."
    if source := dg.data.meta.get(speed_source.KEY):
        text = f"{text} Note: {source}."
    return text


def _sentence(dg: Diagnosis) -> str:
    if dg.cause == "none":
        text = _refused_text(dg)
        if text:
            return f"No cause is named, as nothing passes every check: {text}."
        return SENTENCES["none"]
    values: dict[str, Any] = {**dg.effect, "effort": dg.data.units.effort}
    if dg.cause == "delay":
        values["delay_ms"] = 1e3 * float(dg.effect["delay_s"])
    if dg.cause == "colored_noise":
        values["tau_ms"] = 1e3 * float(dg.effect["tau_s"])
    if dg.cause == "friction_asymmetry" and "offset_equivalent" in dg.effect:
        # dataset.offset_term: the data cannot tell the split from a constant torque.
        text = SENTENCES["friction_asymmetry"].format(**values)
        return (
            f"{text} A constant {'torque' if dg.data.units.axis == 'rotary' else 'force'} of "
            f"{float(dg.effect['offset_equivalent']):.3g} {dg.data.units.effort} (a load, or the drive's "
            "zero offset) would show the same: no recording can tell them apart."
        )
    if dg.cause == "drift":
        values["relative_change_pct"] = 100 * float(dg.effect["relative_change"])
    if "order" in values:
        values["order"] = int(values["order"])
    return SENTENCES[dg.cause].format(**values)


KEEP = {
    "imbalance": ("order", "amplitude", "phase", "amplitude_se"),
    "cogging": ("order", "amplitude", "phase", "amplitude_se"),
    "resonance": ("frequency_hz", "amplitude", "phase", "amplitude_se"),
    "saturation": ("u_max",),
    "deadzone": ("u0", "u0_interval"),
    "delay": ("delay_s",),
    "friction_asymmetry": ("ratio", "offset_equivalent"),
    "colored_noise": ("tau_s",),
    "drift": ("parameter", "relative_change"),
    "model_mismatch": ("reason",),
    "none": (),
}


def _effect_json(cause: str, effect: dict[str, Any]) -> dict[str, Any]:
    out = {k: effect[k] for k in KEEP[cause] if k in effect}
    if "order" in out:
        out["order"] = int(out["order"])
    return {k: (float(v) if isinstance(v, (np.floating, np.integer)) else v) for k, v in out.items()}


def as_json(dg: Diagnosis, report: str | None = None) -> dict[str, Any]:
    units = dg.data.units
    base_params = {k: dg.params[k] for k in ("J", "kv", "damping", "tau_c", "d_stribeck", "v0", "offset")}
    ext = dict(dg.ext_params) if dg.ext_params else dict(dg.params)
    ext_params = {k: ext[k] for k in base_params if k in ext}
    ext_params.update(_effect_json(dg.cause, dg.effect) if dg.cause != "model_mismatch" else {})
    idim = _idim(dg)
    out: dict[str, Any] = {
        "cause": dg.cause,
        "effect": _effect_json(dg.cause, dg.effect),
        # every cause named, best first: forward selection (tvsd.analysis.selection); [] for none
        "causes": [
            {
                "cause": c.cause,
                "effect": _effect_json(c.cause, c.effect),
                "score": float(c.z),
                "threshold": float(c.threshold),
                "p_value": float(c.p),
                "cv_gain": float(c.cv_gain),
                "step": c.step,
                **(
                    {"warning": {"code": "period_not_established", "reason": w}}
                    if (w := period_warning(dg.data, c.cause, c.effect))
                    else {}
                ),
            }
            for c in dg.causes
        ],
        "candidates": [
            {
                "cause": s.cause,
                "score": float(s.z),
                "p_value": float(s.p),
                "gain_pct": float(s.heldout_gain_pct) if math.isfinite(s.heldout_gain_pct) else None,
                "significant": bool(s.significant),
                "effect": _effect_json(s.cause, s.effect),
                # why not named (verdict.WHY codes, doctor._colour_why): absent when named
                **({"why_not": {"code": s.why_not[0], "reason": s.why_not[1]}} if s.why_not else {}),
            }
            for s in dg.ranked
        ],
        "decision": {
            "rule": "largest likelihood ratio, each standardised by its own bootstrap null; "
            "named above the (1 - alpha) point of the bootstrap maxima",
            "alpha": ALPHA,
            "threshold": dg.outcome.threshold,
            "rows": dg.outcome.n,
            "ar_order": len(dg.outcome.ar) - 1,
        },
        "baseline": {
            "params": base_params,
            "stderr": {k: float(v) for k, v in dg.stderr.items()},
            "input_gain": dg.params["input_gain"],
            "time_constant_s": dg.params["time_constant_s"],
            "idim_ls": idim[1].params(),
            "heldout_rmse": dg.heldout_rmse_base,
        },
        "extended": {"params": ext_params, "heldout_rmse": dg.heldout_rmse_ext},
        "gain_pct": dg.gain_pct,
        "summary": sentence(dg),
        "units": {"speed": units.speed, "effort": units.effort, "axis": units.axis, "u": dg.data.u_unit},
        "heldout": "file" if dg.heldout_file else "last third of the recording",
        "noise": {
            "sigma_v": dg.noise.sigma_v,
            "ljung_box_p": dg.noise.ljung_box_p,
            "colour_p": dg.noise.colour_p,
            "tau_s": dg.noise.tau_s,
            # the bins each spectral test saw, [low, high] Hz (None: not run); the colour test stops
            # where an encoder's quantisation floor passes the flat level (`quantisation_floor_hz`)
            "band_tested_hz": {
                "colour": _band(dg.noise.colour_band_hz),
                "peak": _band(dg.noise.peak_band_hz),
            },
            "quantisation_floor_hz": None if (c := dg.noise.floor_cut_hz) is None else round(c, 3),
        },
        # chaotic only when λ1's confidence interval lies above zero (tvsd/analysis/lyapunov.py)
        "lyapunov": lyapunov(dg).as_json(),
        "inverse_error_pct": inverse_error_pct(idim),
    }
    if dg.reason:
        out["reason"] = dg.reason
    warnings = []
    if warn := period_warning(dg.data, dg.cause, dg.effect):
        warnings.append({"code": "period_not_established", "cause": dg.cause, "reason": warn})
    if retimed := dg.data.meta.get("omega_timing"):
        # the doctor moved the recorded speed (dataset.load): any delay it names is after the move
        warnings.append({"code": "omega_retimed", "reason": retimed})
    if source := dg.data.meta.get(speed_source.KEY):
        # the doctor differentiated the encoder, not the recorded speed (speed_source.choose)
        warnings.append({"code": "omega_from_encoder", "reason": source})
    if warnings:
        out["warnings"] = warnings
    if report:
        out["report"] = report
    return out


def lyapunov(dg: Diagnosis) -> Lyapunov:
    d = dg.data
    eff = effect_array(dg.cause, dg.effect)
    speed = d.speed if d.speed is not None else dg.design.prep.speed
    return estimate(dg.model, d.t, speed, d.position, E.neutral() if eff is None else eff)


def _idim(dg: Diagnosis) -> tuple[Any, Any, Any]:
    """The published inverse model (effort = J·accel + friction), plain least squares, as EMPS'
    reference reports it; with its direction-split friction."""
    from tvsd.analysis.candidates import fit_friction_asymmetry
    from tvsd.analysis.inverse import Columns

    v0 = dg.v0_config if math.isfinite(dg.v0_config) else 1.0
    cols = Columns(dg.design.prep, v0)
    ls = cols.baseline()
    return cols, ls, fit_friction_asymmetry(cols, ls)


def inverse_error_pct(idim: tuple[Any, Any, Any]) -> dict[str, float]:
    """Relative error of the inverse (effort) model, % — EMPS' 'force error'."""
    cols, ls, asym = idim
    y = cols.y

    def rel(resid: np.ndarray) -> float:
        return 100 * math.sqrt(float(np.mean(resid**2)) / float(np.mean(y**2)))

    return {"baseline_idim_ls": rel(ls.residual), "friction_asymmetry_idim_ls": rel(asym.fit.residual)}
