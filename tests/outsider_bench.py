"""An outsider's bench: drive recordings made without any of tvsd's model or simulation code.

Written from the paper's physics (eqs. 9–17, the LuGre form of MODEL-NOTES §2) and DESIGN.md's
recording contract only, and deliberately built the way another lab's bench differs from tvsd's
own simulator (tvsd/analysis/simulate.py, tvsd/model): it imports numpy, scipy and numba, never
`tvsd`. Per file, drawn from a seed:

- plant: J, kv, τc (τs = 1.2–2×τc) log-uniform over ÷3…×3 of the paper motor's, R and kM over
  ÷2…×2, σ0, σ1, v0 spread too; L/R from 50 µs to 0.5 ms;
- drive: `u` in V (u → voltage, with L di/dt = u − R i − kb ω), `duty` (×u_scale, PWM quantised to
  8–10 bits), `A` (an inner current loop, first order, 300–3000 Hz bandwidth) or `N*m` (the same
  loop on τ/kM);
- integration: classical RK4 for (φ, ω, i) at ≈ 20 kHz (an integer multiple of the sample rate),
  the bristle state z by a backward-Euler step (not the exponential step tvsd uses);
- sensors: φ from an incremental encoder (256–8192 counts/rev, quantised, taken 0–150 µs before
  the sample instant); ω either the encoder's backward difference (half a sample late, quantised
  to 2π·fs/CPR) or an analogue tach through an RC anti-alias filter with white + 1/f noise;
- disturbance: a vibration torque J·σv·ξ/√h per integration step with ξ Gaussian, Laplace or
  Student-t(5) (unit variance), σv log-uniform over 0.05–1 rad/s^1.5;
- excitation: open-loop staircase, staircase + PRBS, staircase + multisine, or closed loop (a PI
  speed loop at the sample rate tracking reference steps, `omega_ref` recorded);
- sample rate 500, 1000 or 2000 Hz, 20–120 s.

Effects (DESIGN.md's vocabulary; `size` m scales the cause's base, see `_effect`): imbalance,
cogging (order 2–8), resonance (a pure tone or a resonator with Q 30–200 driven by noise),
deadzone (shifted or hard), saturation, delay, friction_asymmetry, colored_noise (OU torque, plus
a white floor), drift (kv, friction, R or kM, linear in time).

    python tests/outsider_bench.py OUTDIR --seed 7 --reps 3 --nulls 36   # writes OUTDIR/*.csv + truth.json
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numba
import numpy as np
from scipy.signal import lfilter

CAUSES = (
    "imbalance", "cogging", "resonance", "deadzone", "saturation", "delay",
    "friction_asymmetry", "colored_noise", "drift",
)  # fmt: skip
SIZES = (2.0, 6.0, 20.0)
SIM_RATE_HZ = 20_000.0
# The paper motor (DESIGN.md, config's physically consistent set), the centre of every spread.
NOMINAL = dict(J=6.378e-5, kv=2.0e-5, kM=8.526e-3, R=11.36, tau_c=3.0e-4, sigma0=0.3, sigma1=1e-3, v0=0.029)


@dataclass
class Spec:
    """Everything one recording is made from; `truth` is what it hides (DESIGN.md's names)."""

    name: str
    seed: int
    cause: str
    size: float
    unit: str
    fs: float
    seconds: float
    excitation: str
    plant: dict[str, float]
    sensor: dict[str, Any]
    noise: dict[str, Any]
    drive: dict[str, Any]
    truth: dict[str, Any] = field(default_factory=dict)


# --- the plant, one kernel --------------------------------------------------------------------


@numba.njit(cache=True)
def _g(w: float, tc: float, ts: float, v0: float, ratio: float) -> float:
    g = tc + (ts - tc) * math.exp(-((w / v0) ** 2))
    return g * ratio if w < 0.0 else g


@numba.njit(cache=True)
def _accel(
    w: float, i: float, z: float, phi: float, p: np.ndarray, ext: float, mult: np.ndarray
) -> tuple[float, float]:
    """(ω̇, di/dt without the input) — p: J kv kM R L tc ts s0 s1 v0 ratio A_per N psi wc mode."""
    J, kv, kM, R, L = p[0], p[1] * mult[0], p[2] * mult[3], p[3] * mult[2], p[4]
    tc, ts, s0, s1, v0, ratio = p[5] * mult[1], p[6] * mult[1], p[7], p[8], p[9], p[10]
    g = _g(w, tc, ts, v0, ratio)
    zdot = w - s0 * abs(w) * z / g
    tf = s0 * z + s1 * zdot
    tp = p[11] * math.sin(p[12] * phi + p[13])  # imbalance / cogging
    wdot = (kM * i - kv * w - tf - tp + ext) / J
    # a voltage drive (the caller adds u/L), or an inner current loop of bandwidth wc (+ wc·i_cmd)
    di = (-R * i - kM * w) / L if p[15] == 0.0 else -p[14] * i
    return wdot, di


@numba.njit(cache=True)
def simulate(
    p: np.ndarray,  # plant and effect constants (see _accel)
    k_sub: int,
    n: int,
    u_open: np.ndarray,  # open-loop command per sample (ignored in closed loop)
    w_ref: np.ndarray,  # closed-loop reference per sample
    closed: bool,
    pi: np.ndarray,  # kp, ki, u_lim, u_exc amplitude
    exc: np.ndarray,  # ±1 PRBS per sample (closed loop's dither)
    torque: np.ndarray,  # vibration + structural torque per sub-step
    drv: np.ndarray,  # u_scale, pwm_step, delay_sub, deadzone, dz_shift, sat, drift_which, drift_rel
    sens: np.ndarray,  # cpr, omega_mode, tach_rc_a, sensor_delay_sub
    tach_noise: np.ndarray,  # per sample
    out: np.ndarray,  # n × 3: u recorded, omega measured, phi measured
) -> None:
    h = p[16]
    phi, w, i, z = 0.0, 0.0, 0.0, 0.0
    delay_sub = int(drv[2])
    buf = np.zeros(delay_sub + 1)
    hist_len = int(sens[3]) + 1
    hphi = np.zeros(hist_len)
    tach = 0.0
    integ = 0.0
    wf = 0.0
    u_rec = 0.0
    cpr = sens[0]
    prev_phi_m = 0.0
    mult = np.ones(4)  # kv, friction, R, kM
    total = n * k_sub
    meas_w = 0.0
    for k in range(n):
        # --- sample: the sensors, then the command for the coming period ---
        phi_s = hphi[(k * k_sub + 1) % hist_len]  # the state sens[3] sub-steps ago
        phi_m = math.floor(phi_s * cpr / (2 * math.pi)) * 2 * math.pi / cpr
        if sens[1] == 0.0:
            meas_w = (phi_m - prev_phi_m) / (h * k_sub) if k > 0 else 0.0
        else:
            meas_w = tach + tach_noise[k]
        prev_phi_m = phi_m
        if closed:
            wf += pi[4] * (meas_w - wf)  # the controller's own speed filter
            e = w_ref[k] - wf
            u_try = pi[0] * e + integ + pi[3] * exc[k]
            if abs(u_try) < pi[2] or u_try * e < 0:  # conditional integration: anti-windup
                integ += pi[1] * e * (h * k_sub)
            u_rec = min(max(pi[0] * e + integ + pi[3] * exc[k], -pi[2]), pi[2])
        else:
            u_rec = u_open[k]
        out[k, 0], out[k, 1], out[k, 2] = u_rec, meas_w, phi_m
        # the drive: scale, PWM quantisation, transport delay, dead zone, clip
        u = u_rec * drv[0]
        if drv[1] > 0:  # the bridge's PWM resolution, in volts (or A, N·m)
            u = round(u / drv[1]) * drv[1]
        for s in range(k_sub):
            j = k * k_sub + s
            if drv[6] > 0:
                mult[int(drv[6]) - 1] = 1.0 + drv[7] * j / total
            buf[j % (delay_sub + 1)] = u
            ua = buf[(j + 1) % (delay_sub + 1)] if delay_sub > 0 else u
            if abs(ua) < drv[3]:
                ua = 0.0
            elif drv[4] > 0:
                ua -= math.copysign(drv[3], ua)
            ua = min(max(ua, -drv[5]), drv[5])
            if p[15] == 0.0:
                drive = ua / p[4]
            elif p[15] == 1.0:
                drive = p[14] * ua
            else:  # a torque command: the drive's current is τ/kM with the motor's nominal kM
                drive = p[14] * ua / p[2]
            ext = torque[j]
            a1, b1 = _accel(w, i, z, phi, p, ext, mult)
            b1 += drive
            a2, b2 = _accel(w + 0.5 * h * a1, i + 0.5 * h * b1, z, phi + 0.5 * h * w, p, ext, mult)
            b2 += drive
            phi3 = phi + 0.5 * h * (w + 0.5 * h * a1)
            a3, b3 = _accel(w + 0.5 * h * a2, i + 0.5 * h * b2, z, phi3, p, ext, mult)
            b3 += drive
            a4, b4 = _accel(w + h * a3, i + h * b3, z, phi + h * (w + 0.5 * h * a2), p, ext, mult)
            b4 += drive
            phi += h * (w + h * (a1 + a2 + a3) / 6.0)
            w_new = w + h * (a1 + 2 * a2 + 2 * a3 + a4) / 6.0
            i += h * (b1 + 2 * b2 + 2 * b3 + b4) / 6.0
            # bristles: backward Euler, stable for any stiffness
            g = _g(w_new, p[5] * mult[1], p[6] * mult[1], p[9], p[10])
            z = (z + h * w_new) / (1.0 + h * p[7] * abs(w_new) / g)
            w = w_new
            tach += sens[2] * (w - tach)
            hphi[(j + 1) % hist_len] = phi


# --- drawing a case ----------------------------------------------------------------------------


def _logu(g: np.random.Generator, centre: float, factor: float) -> float:
    return float(centre * math.exp(g.uniform(-math.log(factor), math.log(factor))))


def _unit_noise(g: np.random.Generator, kind: str, n: int) -> np.ndarray:
    if kind == "laplace":
        return g.laplace(0.0, 1 / math.sqrt(2), n)
    if kind == "t5":
        return g.standard_t(5, n) / math.sqrt(5 / 3)
    return g.standard_normal(n)


def _pink(g: np.random.Generator, n: int) -> np.ndarray:
    """Unit-std 1/f noise by spectral shaping."""
    spec = np.fft.rfft(g.standard_normal(n))
    f = np.arange(len(spec), dtype=float)
    f[0] = 1.0
    x = np.fft.irfft(spec / np.sqrt(f), n)
    return x / x.std()


def draw(seed: int, cause: str, size: float, closed: bool | None = None) -> Spec:
    g = np.random.default_rng([seed, 0x0075])
    unit = str(g.choice(["V", "duty", "A", "N*m"], p=[0.4, 0.2, 0.2, 0.2]))
    fs = float(g.choice([500.0, 1000.0, 2000.0], p=[0.25, 0.5, 0.25]))
    seconds = float(g.choice([20.0, 30.0, 60.0, 120.0], p=[0.25, 0.35, 0.3, 0.1]))
    if closed is None:
        closed = bool(g.random() < 0.25)
    excitation = "closed" if closed else str(g.choice(["staircase", "prbs", "multisine"]))
    J = _logu(g, NOMINAL["J"], 3)
    tc = _logu(g, NOMINAL["tau_c"], 3)
    plant = dict(
        J=J, kv=_logu(g, NOMINAL["kv"], 3), kM=_logu(g, NOMINAL["kM"], 2), R=_logu(g, NOMINAL["R"], 2),
        tau_c=tc, tau_s=tc * g.uniform(1.2, 2.0), sigma0=_logu(g, NOMINAL["sigma0"], 3),
        sigma1=_logu(g, NOMINAL["sigma1"], 3), v0=_logu(g, NOMINAL["v0"], 2),
    )  # fmt: skip
    plant["L"] = plant["R"] * _logu(g, 1.5e-4, 3)
    ratio_encoder = int(g.choice([256, 1024, 2000, 4096, 8192]))
    sensor = dict(
        cpr=ratio_encoder, omega="diff" if g.random() < 0.6 else "tach",
        tach_fc_hz=fs * g.uniform(0.15, 0.35), tach_white=g.uniform(0.002, 0.02),
        tach_pink=g.uniform(0.0, 0.01), delay_s=float(g.uniform(0, 150e-6)),
        declare_cpr=bool(g.random() < 0.7),
    )  # fmt: skip
    noise = dict(
        sigma_v=_logu(g, math.sqrt(0.05 * 1.0), math.sqrt(20)), dist=str(g.choice(["gauss", "laplace", "t5"]))
    )
    # the command range: what holds ≈ 120–160 rad/s at the top step, in the drive's unit
    w_top = g.uniform(100, 170)
    back = plant["kM"] ** 2 / plant["R"]
    if unit in ("V", "duty"):
        u_top = (w_top * (plant["kv"] + back) + tc) * plant["R"] / plant["kM"]
    elif unit == "A":
        u_top = (w_top * plant["kv"] + tc) / plant["kM"]
    else:
        u_top = w_top * plant["kv"] + tc
    drive = dict(
        u_scale=float(g.choice([12.0, 24.0])) if unit == "duty" else 1.0,
        pwm_bits=int(g.choice([8, 10])) if unit in ("duty", "V") else 0,
        inner_bw_hz=g.uniform(300, 3000), u_top=u_top,
    )  # fmt: skip
    if unit == "duty":  # a supply that holds the top step at ≤ 90 % duty
        drive["u_scale"] = max(drive["u_scale"], u_top / 0.9)
        drive["u_top"] = u_top / drive["u_scale"]
    spec = Spec(f"o{seed:05d}", seed, cause, size, unit, fs, seconds, excitation, plant, sensor, noise, drive)
    spec.truth = _effect(spec, g)
    return spec


def _effect(s: Spec, g: np.random.Generator) -> dict[str, Any]:
    """The hidden effect at size m. Torques scale with J·σv (so m is in units of the noise);
    input thresholds with the command range."""
    m, J, sv = s.size, s.plant["J"], s.noise["sigma_v"]
    top = s.drive["u_top"] * s.drive["u_scale"]  # thresholds in the drive's own unit (duty → V)
    if s.cause == "none":
        return {"name": "none"}
    if s.cause == "imbalance":
        amp = m * 1.5 * J * sv
        return {"name": "imbalance", "order": 1, "amplitude": amp, "phase": g.uniform(0, 2 * math.pi)}
    if s.cause == "cogging":
        return {"name": "cogging", "order": int(g.integers(2, 9)), "amplitude": m * 1.5 * J * sv,
                "phase": g.uniform(0, 2 * math.pi)}  # fmt: skip
    if s.cause == "resonance":
        q = math.inf if g.random() < 0.5 else _logu(g, 80, 2.6)
        return {"name": "resonance", "frequency_hz": g.uniform(15, min(90, 0.2 * s.fs)),
                "amplitude": m * 1.5 * J * sv, "q": q}  # fmt: skip
    if s.cause == "deadzone":
        return {"name": "deadzone", "u0": m * 0.004 * top, "shifted": bool(g.random() < 0.5)}
    if s.cause == "saturation":
        return {"name": "saturation", "u_max": top * (1 - 0.01 * m)}
    if s.cause == "delay":
        return {"name": "delay", "delay_s": m * 0.0005}
    if s.cause == "friction_asymmetry":
        r = (1 + 0.025 * m) ** (1 if g.random() < 0.5 else -1)
        return {"name": "friction_asymmetry", "ratio": r}
    if s.cause == "drift":
        pars = ["kv", "friction", "R", "kM"] if s.unit in ("V", "duty") else ["kv", "friction", "kM"]
        par = str(g.choice(pars))
        rel = 0.015 * m * (1 if g.random() < 0.6 else -1)
        return {"name": "drift", "parameter": par, "relative_change": rel}
    if s.cause == "colored_noise":
        return {"name": "colored_noise", "tau_s": m * 0.001}
    raise ValueError(s.cause)


# --- making the recording --------------------------------------------------------------------


def _command(s: Spec, g: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(open-loop command, reference speed) per sample."""
    fs, top = s.fs, s.drive["u_top"]
    P = s.plant
    back = P["kM"] ** 2 / P["R"] if s.unit in ("V", "duty") else 0.0
    tau = P["J"] / (P["kv"] + back)  # the mechanical time constant: steps hold 1–3 of it
    t = np.arange(n) / fs
    levels, holds = [], []
    sign = 1.0
    while sum(holds) < n:  # both directions: the sign flips at 70 % of the steps
        sign = -sign if g.random() < 0.7 else sign
        levels.append(0.0 if g.random() < 0.1 else sign * g.uniform(0.2, 1.0))
        holds.append(int(g.uniform(1.0, 3.0) * min(max(tau, 0.8), 4.0) * fs))
    stair = np.repeat(levels, holds)[:n]
    if s.excitation == "prbs":
        bits = np.repeat(g.choice([-1.0, 1.0], size=n // int(0.02 * fs) + 1), int(0.02 * fs))[:n]
        stair = 0.8 * stair + 0.2 * bits
    elif s.excitation == "multisine":
        f = np.geomspace(0.3, min(25.0, fs / 20), 12)
        ms = sum(np.sin(2 * np.pi * fk * t + g.uniform(0, 2 * np.pi)) for fk in f)
        stair = 0.8 * stair + 0.2 * ms / np.max(np.abs(ms))
    u = stair * top
    w_ref = stair * g.uniform(90, 150)
    return u, w_ref


def _torques(s: Spec, g: np.random.Generator, k_sub: int, n: int) -> np.ndarray:
    """Vibration (+ structural mode) torque per integration step."""
    h = 1.0 / (s.fs * k_sub)
    N = n * k_sub
    J, sv, tr = s.plant["J"], s.noise["sigma_v"], s.truth
    xi = _unit_noise(g, s.noise["dist"], N)
    if tr["name"] == "colored_noise":
        tau = tr["tau_s"]
        a = math.exp(-h / tau)
        # OU acceleration whose spectrum below its corner is the null's (σv² one-sided/2), plus a floor
        s_ou = sv / math.sqrt(2 * tau)
        ou = lfilter([s_ou * math.sqrt(1 - a * a)], [1, -a], xi)
        floor = 0.3 * sv * _unit_noise(g, s.noise["dist"], N) / math.sqrt(h)
        acc = ou + floor
    else:
        acc = sv * xi / math.sqrt(h)
    torque = J * acc
    if tr["name"] == "resonance":
        t = np.arange(N) * h
        f0, A = tr["frequency_hz"], tr["amplitude"]
        if math.isinf(tr["q"]):  # a pure tone whose phase wanders slowly (0.02 Hz line width)
            ph = np.cumsum(g.standard_normal(N)) * math.sqrt(2 * math.pi * 0.02 * h)
            torque += A * np.sin(2 * np.pi * f0 * t + ph)
        else:  # a lightly damped mode driven by broadband noise
            w0 = 2 * math.pi * f0 * h
            r = math.exp(-w0 / (2 * tr["q"]))
            x = lfilter([1.0], [1, -2 * r * math.cos(w0), r * r], g.standard_normal(N))
            torque += A * x / (x.std() * math.sqrt(2))
    return torque


def make(s: Spec) -> dict[str, np.ndarray]:
    g = np.random.default_rng([s.seed, 0x0B])
    k_sub = round(SIM_RATE_HZ / s.fs)
    h = 1.0 / (s.fs * k_sub)
    n = int(s.seconds * s.fs)
    u_open, w_ref = _command(s, g, n)
    tr, P, sen, dr = s.truth, s.plant, s.sensor, s.drive
    A, order, psi = 0.0, 1.0, 0.0
    if tr["name"] in ("imbalance", "cogging"):
        A, order, psi = tr["amplitude"], float(tr["order"]), tr["phase"]
    mode = {"V": 0.0, "duty": 0.0, "A": 1.0, "N*m": 2.0}[s.unit]
    wc = 2 * math.pi * dr["inner_bw_hz"]
    ratio = tr.get("ratio", 1.0) if tr["name"] == "friction_asymmetry" else 1.0
    p = np.array([P["J"], P["kv"], P["kM"], P["R"], P["L"], P["tau_c"], P["tau_s"], P["sigma0"],
                  P["sigma1"], P["v0"], ratio, A, order, psi, wc, mode, h])  # fmt: skip
    top = dr["u_top"]
    u_lim = top * 1.15
    b = {"V": P["kM"] / P["R"], "duty": P["kM"] / P["R"] * dr["u_scale"], "A": P["kM"], "N*m": 1.0}[s.unit]
    bw = 2 * math.pi * g.uniform(1, 4)  # speed loop bandwidth
    kp = bw * P["J"] / b
    pi = np.array([kp, kp * bw / 4, u_lim, 0.05 * top, 1 - math.exp(-2 * math.pi * 40 / s.fs)])
    bit = max(1, int(0.01 * s.fs))  # the closed loop's dither: a 10 ms PRBS on the command
    exc = np.repeat(g.choice([-1.0, 1.0], size=n // bit + 1), bit)[:n]
    torque = _torques(s, g, k_sub, n)
    dz = tr["u0"] if tr["name"] == "deadzone" else 0.0
    sat = tr["u_max"] if tr["name"] == "saturation" else math.inf
    scale = dr["u_scale"]
    drift_which = {"kv": 1, "friction": 2, "R": 3, "kM": 4}.get(tr.get("parameter", ""), 0)
    delay = tr["delay_s"] if tr["name"] == "delay" else 0.0
    pwm_step = 0.0
    if dr["pwm_bits"]:  # ±2^(bits−1) steps over the bridge's supply (duty: u_scale; V: 1.3 × the top step)
        pwm_step = (scale if s.unit == "duty" else 1.3 * top) / 2 ** (dr["pwm_bits"] - 1)
    drv = np.array([scale, pwm_step, round(delay / h),
                    dz, 1.0 if tr.get("shifted") else 0.0, sat,
                    float(drift_which), tr.get("relative_change", 0.0)])  # fmt: skip
    tach_rc = 1 - math.exp(-2 * math.pi * sen["tach_fc_hz"] * h)
    sens = np.array([sen["cpr"], 0.0 if sen["omega"] == "diff" else 1.0, tach_rc, round(sen["delay_s"] / h)])
    tn = sen["tach_white"] * g.standard_normal(n) + sen["tach_pink"] * _pink(g, n)
    tn *= 100.0  # rad/s: noise as a fraction of a 100 rad/s full scale
    out = np.zeros((n, 3))
    simulate(p, k_sub, n, u_open, w_ref, s.excitation == "closed", pi, exc, torque, drv, sens, tn, out)
    cols = {"t": np.arange(n) / s.fs, "u": out[:, 0], "omega": out[:, 1], "phi": out[:, 2]}
    if s.excitation == "closed":
        cols["omega_ref"] = w_ref
    return cols


def write(path: Path, s: Spec, cols: dict[str, np.ndarray]) -> None:
    names = ["t", "u", "omega", "phi"] + (["omega_ref"] if "omega_ref" in cols else [])
    head = [
        "# tvs-recording: 1",
        f"# sample_rate_hz: {s.fs:g}",
        "# source: outsider bench (tests/outsider_bench.py)",
        f"# u_unit: {s.unit}",
    ]
    if s.unit == "duty":
        head.append(f"# u_scale: {s.drive['u_scale']:.6g}")
    if s.sensor["declare_cpr"]:
        head.append(f"# encoder_counts_per_rev: {s.sensor['cpr']}")
    data = np.column_stack([cols[c] for c in names])
    with open(path, "w") as fh:
        fh.write("\n".join(head) + "\n" + ",".join(names) + "\n")
        np.savetxt(fh, data, fmt=["%.6f"] + ["%.7g"] * (len(names) - 1), delimiter=",")


def plan(seed: int, reps: int, nulls: int, sizes: tuple[float, ...] = SIZES) -> list[tuple[int, str, float]]:
    cases = [("none", 0.0)] * nulls + [(c, m) for c in CAUSES for m in sizes for _ in range(reps)]
    return [(seed * 1000 + k, c, m) for k, (c, m) in enumerate(cases)]


def truth_of(s: Spec) -> dict[str, Any]:
    d = asdict(s)
    d["truth"] = {k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in s.truth.items()}
    return d


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--nulls", type=int, default=36)
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    truth = {}
    for case_seed, cause, m in plan(a.seed, a.reps, a.nulls):
        s = draw(case_seed, cause, m)
        write(a.out / f"{s.name}.csv", s, make(s))
        truth[s.name] = truth_of(s)
    (a.out / "truth.json").write_text(json.dumps(truth, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
