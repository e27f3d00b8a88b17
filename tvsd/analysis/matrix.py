"""The randomised test matrix of the model doctor (issue 12, item 5): cases nobody tuned for.

Each case draws its own plant (J, kv, τc, R, kM each log-uniform over a 10× span around the
config's; L moves with R, as both go with the winding's turns squared, so the electrical time
constant stays the config's), an excitation (open-loop staircase, open-loop PRBS on a multisine,
or closed-loop scanning with `tvsctl identify`'s excitation on top: reference steps and multisine,
PRBS on the voltage), a vibration level (the paper's three σv), and either nothing (a null) or
one cause at a size m·base, m in SIZES (1× … 30× a base near the detection limit). Sizes are
reported in noise units: a torque (or its equivalent through the drive) over J·σv.
The closed-loop cases scan at a speed the drawn plant holds with 40 % of the drive (at most
CLOSED_RPS): a plant with 3× the friction and a third of the torque constant cannot scan at 20 rev/s.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.causes import Effect, parse_effect
from tvsd.config import Config, load_config

SIGMAS = (0.0838, 0.3381, 0.8069)
OPEN_PROFILES = ("steps", "multisine")
CLOSED_PROFILES = ("identify",)
PROFILES = OPEN_PROFILES + CLOSED_PROFILES
CLOSED_RPS = 10.0  # scanning speed of the closed-loop cases (lower where the plant needs it)
CLOSED_DRIVE_SHARE = 0.4
SIZES = (1.0, 3.0, 10.0, 30.0)
SPAN = math.sqrt(10.0)  # each plant parameter within [÷√10, ×√10] of the config's


@dataclass(frozen=True)
class Case:
    seed: int
    cause: str
    size: float  # m: multiple of the base
    noise_units: float  # the effect's size over J·σv (torque-equivalent), nan where not a torque
    effect: str | None
    profile: str
    sigma_v: float
    plant: dict[str, float]
    rps: float = 0.0  # scanning speed (closed-loop profiles)


def _plant(cfg: Config, g: np.random.Generator) -> Any:
    p = cfg.plant
    draw = {k: getattr(p, k) * math.exp(g.uniform(-1, 1) * math.log(SPAN)) for k in ("J", "kv", "R", "kM")}
    fric = math.exp(g.uniform(-1, 1) * math.log(SPAN))
    return dataclasses.replace(
        p,
        **draw,
        kb=draw["kM"] * p.kb / p.kM,
        L=p.L * draw["R"] / p.R,
        tau_c=p.tau_c * fric,
        tau_s=p.tau_s * fric,
    )


def scan_rps(plant: Any, u_max: float) -> float:
    """The closed-loop cases' scanning speed: CLOSED_RPS, or less where holding it (plus the
    identify steps) would take more than CLOSED_DRIVE_SHARE of the drive."""
    volts_per_rad_s = plant.R * plant.kv / plant.kM + plant.kb
    held = (CLOSED_DRIVE_SHARE * u_max - plant.R * plant.tau_c / plant.kM) / volts_per_rad_s
    return float(max(1.5, min(CLOSED_RPS, held / (2 * math.pi) - 1.0)))


SAT_TOP_Q = 0.99  # open loop: saturation thresholds are set below this quantile of |command|
SAT_STEP = 0.01  # … by m × this share of it (1×: 1 % below, 30×: 30 % below)


def open_loop_command(cfg: Config, profile: str, seconds: float, seed: int) -> np.ndarray:
    """The command `sim record` will play for this case (its rng is the record's seed): known
    before the run, so an effect that acts on the command can be sized where the command is."""
    from tvsd.sim.record import multisine, staircase

    shape = staircase if profile == "steps" else multisine
    return shape(np.random.default_rng(seed), seconds, cfg.drive.u_max_v, 1.0 / cfg.control.rate_hz)


def saturation_size(command: np.ndarray, m: float) -> tuple[float, float]:
    """u_max for size m, and the command's rms excess over it (V).

    The threshold sits m·SAT_STEP below the command's SAT_TOP_Q quantile, so at every size at
    least 1 % of the samples exceed it — the clip is in the data. (The drive limit was the
    reference before: 0.99–0.90 × u_max lay above every command in 20 of 24 cases.)"""
    mag = np.abs(command)
    u_max = float(np.quantile(mag, SAT_TOP_Q)) * (1.0 - SAT_STEP * m)
    excess = float(np.sqrt(np.mean(np.maximum(mag - u_max, 0.0) ** 2)))
    return u_max, excess


COLOUR_TAU_S = 0.0005  # colored_noise: τ = m × this (corner 1/(2πτ): 318 Hz at 1×, 11 Hz at 30×)


def coloured_sigma(sigma_v: float, tau_s: float) -> float:
    """The OU vibration's standard deviation whose low-frequency intensity is the white one's.

    The SIL's colored_noise replaces the white Δv (two-sided acceleration PSD σv²) by an OU
    acceleration of standard deviation σ (PSD 2σ²τ at low frequency): with σ = σv the coloured
    vibration was 2τ/s of the null's (1 % at 5 ms) and sank under the speed-measurement noise,
    so the case tested the vibration's level, not its colour. With σ = σv/√(2τ) the spectrum is
    the null's below the corner 1/(2πτ) and falls above it: the colour alone differs."""
    return sigma_v / math.sqrt(2.0 * tau_s)


def delay_torque(command: np.ndarray | None, delay_s: float, b_u: float, dt: float) -> float:
    """A delay's torque-equivalent size: the drive's torque error from applying the command late,
    b_u·rms(u(t) − u(t − τ)) (nan where the command is not known before the run)."""
    if command is None:
        return math.nan
    k = max(1, round(delay_s / dt))
    return b_u * float(np.sqrt(np.mean((command[k:] - command[:-k]) ** 2)))


# cause -> (effect text for size m, torque-equivalent size for J·σv units)
def _effects(
    plant: Any,
    u_max: float,
    g: np.random.Generator,
    command: np.ndarray | None = None,
    dt: float = 1e-4,
) -> dict[str, Callable[[float], tuple[str, float]]]:
    """`command`: the open-loop case's command on the plant's step `dt` (saturation is sized on
    it, a delay's noise units measured on it); None in closed loop, where the thresholds stay
    relative to the drive limit."""
    b_u = plant.kM * plant.ku / plant.R  # N·m per volt, the open-loop drive gain
    jsv = plant.J

    def saturation(m: float) -> tuple[str, float]:
        if command is None:
            return f"saturation:u_max={u_max * (1 - 0.01 * m):.6g}", m * 0.01 * u_max * b_u
        x, excess = saturation_size(command, m)
        return f"saturation:u_max={x:.6g}", excess * b_u

    def torque(name: str, extra: str) -> Callable[[float], tuple[str, float]]:
        return lambda m: (f"{name}:amplitude={m * 0.5 * jsv:.6g}{extra}", m * 0.5 * jsv)

    return {
        "imbalance": torque("imbalance", f",phase={g.uniform(-3, 3):.3f}"),
        "cogging": torque("cogging", f",order={int(g.integers(2, 9))}"),
        "resonance": torque("resonance", f",frequency_hz={g.uniform(20, 70):.3f}"),
        "deadzone": lambda m: (f"deadzone:u0={m * 0.004 * u_max:.6g}", m * 0.004 * u_max * b_u),
        "saturation": saturation,
        "delay": lambda m: (f"delay:delay_s={m * 0.0005:.6g}", delay_torque(command, m * 0.0005, b_u, dt)),
        "friction_asymmetry": lambda m: (
            f"friction_asymmetry:ratio={(1 + 0.01 * m) ** (1 if g.random() < 0.5 else -1):.6g}",
            0.01 * m * plant.tau_c,
        ),
        "drift": lambda m: (
            f"drift:parameter={['R', 'kv', 'friction'][int(g.integers(3))]},relative_change={0.005 * m:.6g}",
            math.nan,
        ),
        "colored_noise": lambda m: (f"colored_noise:tau_s={m * COLOUR_TAU_S:.6g}", math.nan),
    }


def cases(
    n_null: int = 50,
    reps: int = 3,
    seed: int = 0,
    causes: tuple[str, ...] | None = None,
    profiles: tuple[str, ...] = OPEN_PROFILES,
    seconds: float = 30.0,
) -> list[Case]:
    """`seconds`: the cases' length (open-loop saturation is sized on the command of that length)."""
    cfg = load_config()
    out: list[Case] = []
    plan: list[tuple[str, float]] = [("none", 0.0)] * n_null
    names = causes or tuple(_effects(cfg.plant, cfg.drive.u_max_v, np.random.default_rng(0)))
    plan += [(c, m) for c in names for m in SIZES for _ in range(reps)]
    for k, (cause, m) in enumerate(plan):
        g = np.random.default_rng([seed, k])
        plant = _plant(cfg, g)
        text, torque = (None, math.nan)
        sigma = SIGMAS[k % 3]
        profile = profiles[(k // 3) % len(profiles)]
        if cause != "none":
            command = None
            if cause in ("saturation", "delay") and profile in OPEN_PROFILES:
                command = open_loop_command(cfg, profile, seconds, 10_000 * seed + k)
            dt = 1.0 / cfg.control.rate_hz
            text, torque = _effects(plant, cfg.drive.u_max_v, g, command, dt)[cause](m)
        units = torque / (plant.J * sigma) if math.isfinite(torque) else math.nan
        if cause == "colored_noise":
            sigma = coloured_sigma(sigma, m * COLOUR_TAU_S)
        p = {k2: getattr(plant, k2) for k2 in ("J", "kv", "R", "kM", "tau_c")}
        rps = scan_rps(plant, cfg.drive.u_max_v) if profile in CLOSED_PROFILES else 0.0
        out.append(Case(10_000 * seed + k, cause, m, units, text, profile, sigma, p, rps))
    return out


def case_config(cfg: Config, case: Case) -> Config:
    """The config with the case's plant and vibration level."""
    plant = dataclasses.replace(cfg.plant, **case.plant)  # type: ignore[arg-type]
    plant = dataclasses.replace(
        plant, kb=plant.kM * cfg.plant.kb / cfg.plant.kM, L=cfg.plant.L * plant.R / cfg.plant.R
    )
    sil = cfg.sil_or_default
    vib = dataclasses.replace(sil.vibration, sigma_v=case.sigma_v)
    return dataclasses.replace(cfg, plant=plant, sil=dataclasses.replace(sil, vibration=vib))


def run_case(case: Case, seconds: float, tmp: Path, iv: bool = False) -> dict[str, Any]:
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.sim.record import record

    cfg = case_config(load_config(), case)
    if case.profile in CLOSED_PROFILES:  # a clip sized on the case's own command (matrix_closed)
        from tvsd.analysis.closed_plan import sized

        case = sized(case, cfg, tmp, seconds)
    effects: tuple[Effect, ...] = (parse_effect(case.effect),) if case.effect else ()
    path = tmp / f"case{case.seed}.csv"
    record(cfg, path, case.profile, seconds, effects, case.seed, rps=case.rps or 20.0)
    t0 = time.perf_counter()
    try:
        dg = diagnose(load(path, cfg), cfg.plant.v0, iv=iv)
        found = dg.cause
    except Exception as exc:  # a bad case is a result too (reported, not hidden)
        found = f"error: {type(exc).__name__}: {exc}"[:120]
    return {"case": case, "found": found, "seconds": time.perf_counter() - t0}


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact two-sided interval of a binomial rate (k of n)."""
    from scipy.stats import beta

    a = (1 - level) / 2
    lo = float(beta.ppf(a, k, n - k + 1)) if k > 0 else 0.0
    hi = float(beta.ppf(1 - a, k + 1, n - k)) if k < n else 1.0
    return lo, hi


def run(
    n_null: int = 50,
    reps: int = 3,
    seconds: float = 30.0,
    seed: int = 0,
    loop: str = "open",
    causes: tuple[str, ...] | None = None,
    iv: bool = False,
) -> dict[str, Any]:
    """The matrix's figures for one loop (open: staircase and multisine; closed: scanning with the
    identify excitation): false alarms on the nulls with their 95 % Clopper–Pearson interval, and
    per cause the naming rate by size, keyed doctor_<loop>_… (iv: the closed-loop files through
    the reference-instrumented design, tvsd.analysis.instrument; keyed doctor_<loop>_iv_…)"""
    profiles = OPEN_PROFILES if loop == "open" else CLOSED_PROFILES
    t0 = time.perf_counter()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases(n_null, reps, seed, causes, profiles, seconds):
            results.append(run_case(case, seconds, Path(tmp), iv))
    return summarise(results, f"doctor_{loop}{'_iv' if iv else ''}", time.perf_counter() - t0)


def summarise(results: list[dict[str, Any]], key: str, wall_s: float) -> dict[str, Any]:
    nulls = [r for r in results if r["case"].cause == "none"]
    fa = sum(r["found"] != "none" for r in nulls)
    lo, hi = clopper_pearson(fa, len(nulls)) if nulls else (math.nan, math.nan)
    figures: dict[str, Any] = {
        f"{key}_nulls": len(nulls),
        f"{key}_false_alarm_pct": 100.0 * fa / max(len(nulls), 1),
        f"{key}_false_alarm_ci95_pct": [round(100 * lo, 2), round(100 * hi, 2)],
        f"{key}_false_alarms": sorted({r["found"] for r in nulls if r["found"] != "none"}),
    }
    by_cause: dict[str, dict[float, list[dict[str, Any]]]] = {}
    for r in results:
        c = r["case"]
        if c.cause != "none":
            by_cause.setdefault(c.cause, {}).setdefault(c.size, []).append(r)
    for cause, sizes in by_cause.items():
        rates = {m: sum(x["found"] == cause for x in rs) / len(rs) for m, rs in sorted(sizes.items())}
        figures[f"{key}_{cause}_named_pct_by_size"] = {f"{m:g}x": round(100 * v) for m, v in rates.items()}
        noise = {f"{m:g}x": _median_units(rs) for m, rs in sorted(sizes.items())}
        if any(math.isfinite(v) for v in noise.values()):
            figures[f"{key}_{cause}_noise_units_by_size"] = noise
        for pct in (90, 95):  # the stated limit (issue 12: ≥ 95 % above it), and where 90 % is reached
            limit = lowest_size_from(rates, pct / 100)
            figures[f"{key}_{cause}_{pct}pct_at_size"] = limit
            units = [x["case"].noise_units for x in sizes.get(limit, [])]
            if units and all(math.isfinite(u) for u in units):
                figures[f"{key}_{cause}_{pct}pct_noise_units"] = float(np.median(units))
        wrong = sorted({x["found"] for rs in sizes.values() for x in rs if x["found"] != cause})
        figures[f"{key}_{cause}_named_instead"] = wrong
    figures[f"{key}_cases"] = len(results)
    figures[f"{key}_mean_analyze_s"] = float(np.mean([r["seconds"] for r in results])) if results else 0.0
    figures[f"{key}_wall_s"] = wall_s
    return figures


def lowest_size_from(rates: dict[float, float], rate: float) -> float:
    """The lowest size whose naming rate, and every larger size's, is ≥ `rate` (nan: none)."""
    return next((m for m in sorted(rates) if all(v >= rate for mm, v in rates.items() if mm >= m)), math.nan)


def _median_units(rs: list[dict[str, Any]]) -> float:
    u = [x["case"].noise_units for x in rs]
    return round(float(np.median(u)), 3) if u and all(math.isfinite(v) for v in u) else math.nan
