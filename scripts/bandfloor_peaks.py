"""The spectral tests on randomised encoder-difference residuals, with and without a structural mode.

    nice -n 19 .venv/bin/python scripts/bandfloor_peaks.py --nulls 200 --seed 4 --out N4.jsonl
    nice -n 19 .venv/bin/python scripts/bandfloor_peaks.py --nulls 100 --seed 5 --size 6 --out M6.jsonl
    .venv/bin/python scripts/bandfloor_peaks.py --summary N4.jsonl [--c 1 2 3]

Each case: tests/quantisation_nulls.py's family (encoder 256–8192 counts/rev, 500–2000 Hz,
staircase / multisine / fast steps, σv 0.05–1 rad/s^1.5, 30 s), the stuck rows left out and the
rest ramped as the doctor passes them (quantisation.gated); with `--size m` a mode of amplitude
m·1.5·σv at 30–90 Hz (a tone, or Q 31–208, as tests/outsider_bench.py draws it). One JSON line
each: the draw, where the floor cut the colour's band, the peak test's statistics over the band
it covers and the cause the spectrum names (noise.spectral_cause at the doctor's p < 1e-3), and
the colour test over the cut band and over the whole band (the floor in its model).

Run with another checkout's `tvsd` first on PYTHONPATH (e.g. integ3) the same seeds give the
cases as that code judges them ("before"): fields that code lacks are left out.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy.stats import beta, chi2

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import quantisation_nulls as qn

from tvsd.analysis import noise, peak, quantisation
from tvsd.analysis.noise import COLOUR_P
from tvsd.analysis.prep import Band, Prepared


def cp95(k: int, n: int) -> tuple[float, float]:
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return lo, hi


def _whole_band_colour(resid: np.ndarray, rate: float, floor: quantisation.Floor | None) -> float | None:
    """The colour test's p over the whole band, the floor in both shapes (not the doctor's)."""
    if not hasattr(noise, "_whole_band"):
        return None
    f, p, segments = noise._welch(resid, rate)
    fm, pm, known, a0, _ = noise._whole_band(f, p, 100.0, floor)
    white, best = noise._colour_fits(fm, pm, known, a0, noise._slope(fm, pm, known))
    lr = max(0.0, 2 * noise.effective_segments(segments, 2 * (len(f) - 1)) * (white.fun - best.fun))
    return float(chi2.sf(lr, 1))


# `--mix`: the excitation and the gaps by the case's index (the rest drawn as ever), so the
# staircase (whose quantisation lines stand highest over the floor) gets half the cases and each
# kind is gapped in half of its own.
MIX_PROFILES = ("staircase", "multisine", "staircase", "steps")


def _wide(null: qn.Null, rng: np.random.Generator, top_hz: float, gaps: bool) -> dict[str, object]:
    """The spectral tests over 0.5–top_hz instead of the doctor's 0.5–50 Hz (not the doctor's):
    500 Hz records decimated ×2 (rows at 250 Hz, their anti-alias corner at 100 Hz, as at 1–2 kHz),
    and the spectrum and floor divided by the chain's known gain for a white acceleration
    (band and anti-alias filters, the central difference: `_vibration_gain`), which is the
    Whittle fit of G·(flat + f² + peak) + F; the band filter's roll-off (≈ 0.5 at 90 Hz) would
    otherwise read as a low-pass colour. `rng`: the case's generator before its rows."""
    band = Band(decim=2) if null.fs <= 500.0 else Band()
    every, keep, prep = qn.rows(null, rng, band)
    rate = null.fs / prep.band.decim
    if gaps:
        resid, floor = quantisation.gated(prep, keep, every, rate)
    else:
        resid, floor = every, quantisation.floor(prep, np.ones(len(every), dtype=bool))
    f, p, segments = noise._welch(resid, rate)
    g = _vibration_gain(prep, f)

    def flat_floor(x: np.ndarray) -> np.ndarray:
        assert floor is not None
        return np.asarray(floor(x)) / _vibration_gain(prep, np.asarray(x, dtype=float))

    r = noise.spectrum_report(
        f, p / g, segments, 1.0, 2 * top_hz, math.nan, None if floor is None else flat_floor
    )
    return {
        "wide_named": noise.spectral_cause(r, COLOUR_P),
        "wide_band_hi_hz": None if r.peak_band_hz is None else r.peak_band_hz[1],
        "wide_colour_p": r.colour_p,
        "wide_peak_hz": r.peak_hz,
        "wide_peak_q": r.peak_q,
        "wide_peak_lr": r.peak_lr,
        "wide_peak_white_lr": r.peak_white_lr,
        "wide_flanked": noise._flanked(r),
        "wide_peak_over_floor": None if math.isinf(r.peak_over_floor) else r.peak_over_floor,
    }


def _vibration_gain(prep: Prepared, f: np.ndarray) -> np.ndarray:
    """|transfer|² from a white acceleration to the residual rows: the chain's (quantisation._gain,
    from the speed) over the integration's (2πf)²; 1 at 0 Hz."""
    f = np.asarray(f, dtype=float)
    safe = np.where(f > 0, f, 1.0)
    g = quantisation._gain(prep, safe) / (2 * np.pi * safe) ** 2
    return np.asarray(np.where(f > 0, g, 1.0))


def _spread_over_floor(r: noise.NoiseReport, floor: quantisation.Floor | None) -> float | None:
    """The peak over the floor as bandfloor measured it (before peak.seen_height): the fitted
    top, or its power over the window's 1.5 bins when narrower, whatever the model shows on the
    bins."""
    if floor is None or not math.isfinite(r.peak_q) or r.peak_q <= 0:
        return None
    power = r.peak_rms**2
    top = power * 2 * r.peak_q / (math.pi * r.peak_hz)
    seen = min(top, power / (1.5 * float(r.freq[1] - r.freq[0])))
    return seen / max(float(floor(np.array([r.peak_hz]))[0]), 1e-300)


def case(
    seed: int,
    i: int,
    size: float,
    tau_s: float,
    lo_hz: float,
    hi_hz: float,
    whole: bool = True,
    mix: bool = False,
    wide_hz: float = 0.0,
) -> dict[str, object]:
    rng = np.random.default_rng([seed, i])
    null = qn.draw(rng, colour_tau_s=tau_s)
    gaps = True
    if mix:
        null = dataclasses.replace(null, profile=MIX_PROFILES[i % 4])
        gaps = (i // 4) % 2 == 0
    if size > 0:
        null = qn.with_mode(null, rng, size, lo_hz, hi_hz)
    before_rows = copy.deepcopy(rng)
    every, keep, prep = qn.rows(null, rng)
    rate = null.fs / prep.band.decim
    if gaps:
        resid, floor = quantisation.gated(prep, keep, every, rate)
    else:
        resid, floor = every, quantisation.floor(prep, np.ones(len(every), dtype=bool))
    r = noise.analyse(resid, rate, 1.0, 100.0, floor)
    row: dict[str, object] = {"i": i, **dataclasses.asdict(null), "gaps": gaps, "kept": float(np.mean(keep))}
    row["mode_q"] = None if math.isinf(null.mode_q) else null.mode_q
    f, p, _ = noise._welch(resid, rate)
    seen = noise._in_band(f, p, 100.0, floor)[0]
    row |= {
        "cut_hz": float(seen[-1]) if len(seen) else 0.0,
        "colour_p": r.colour_p,
        "peak_hz": r.peak_hz,
        "peak_q": r.peak_q,
        "peak_lr": r.peak_lr,
        "peak_white_lr": r.peak_white_lr,
        "flanked": noise._flanked(r),
        "band_hi_hz": None if r.peak_band_hz is None else r.peak_band_hz[1],
        "named": noise.spectral_cause(r, COLOUR_P),
    }
    if hasattr(r, "peak_over_floor"):
        row["peak_over_floor"] = None if math.isinf(r.peak_over_floor) else r.peak_over_floor
        row["peak_over_floor_spread"] = _spread_over_floor(r, floor)
        if whole:
            row["colour_p_whole_band"] = _whole_band_colour(resid, rate, floor)
    if wide_hz > 0:
        row |= _wide(null, before_rows, wide_hz, gaps)
    return row


def run(a: argparse.Namespace) -> None:
    with a.out.open("a") as fh:
        for i in range(a.first, a.nulls, a.step):
            row = case(a.seed, i, a.size, a.tau_ms / 1e3, a.lo_hz, a.hi_hz, not a.peak_only, a.mix, a.wide_hz)
            fh.write(json.dumps(row) + "\n")
            fh.flush()


def _low_flank_only(r: dict[str, object]) -> bool:
    """The flank rule before 23a5055: two bins inside the band's bottom, none asked at its top
    (the Welch bins are 1/SEGMENT_S apart)."""
    return float(r["peak_hz"]) >= noise.BAND_LOW_HZ + 2 / noise.SEGMENT_S  # type: ignore[arg-type]


def _peak_passes(r: dict[str, object], c: float, top_edge: bool = True) -> bool:
    """noise.spectral_cause's resonance with the floor constant c (the other gates as they are);
    `top_edge` False: the flank rule without the band's top edge."""
    over = r.get("peak_over_floor")
    return (
        float(r["peak_q"]) >= peak.PEAK_Q  # type: ignore[arg-type]
        and (bool(r["flanked"]) if top_edge else _low_flank_only(r))
        and float(r["peak_white_lr"]) > peak.PEAK_WHITE_LR  # type: ignore[arg-type]
        and float(r["peak_lr"]) > chi2.isf(COLOUR_P, 2)  # type: ignore[arg-type]
        and (over is None or float(over) >= c)  # type: ignore[arg-type]
    )


def summary(paths: list[Path], cs: list[float]) -> None:
    rows = [json.loads(line) for p in paths for line in p.read_text().splitlines() if line.strip()]
    n = len(rows)

    def rate(k: int, of: int = n) -> str:
        lo, hi = cp95(k, of)
        return f"{k}/{of} ({100 * k / of:.1f} %, 95 % CI {100 * lo:.1f}–{100 * hi:.1f} %)"

    named: dict[str, int] = {}
    for r in rows:
        named[str(r["named"])] = named.get(str(r["named"]), 0) + 1
    print(f"named by the spectrum (the code that ran, its PEAK_FLOOR_C): {named}")
    cuts = sorted(float(r["cut_hz"]) for r in rows)
    spread = f"10–90 % {cuts[n // 10]:.1f}–{cuts[9 * n // 10]:.1f} Hz"
    print(f"colour band's top: median {cuts[n // 2]:.1f} Hz, {spread}")
    print(f"colour p < {COLOUR_P:g}, cut band: {rate(sum(r['colour_p'] < COLOUR_P for r in rows))}")
    whole = [r["colour_p_whole_band"] for r in rows if r.get("colour_p_whole_band") is not None]
    if whole:
        print(f"colour p < {COLOUR_P:g}, whole band: {rate(sum(p < COLOUR_P for p in whole), len(whole))}")
    for c in cs:
        k = sum(_peak_passes(r, c) for r in rows)
        above = sum(_peak_passes(r, c) and float(r["peak_hz"]) > float(r["cut_hz"]) for r in rows)
        print(f"resonance at c = {c:g}: {rate(k)}; above the colour's band {above}")
    if any(r["mode_size"] for r in rows):
        right = [r for r in rows if r["named"] == "resonance" and abs(r["peak_hz"] - r["mode_hz"]) < 1.0]
        print(f"resonance named at the mode's frequency (± 1 Hz): {rate(len(right))}")
        for lo, hi in ((30, 50), (50, 90)):
            sub = [r for r in rows if lo <= r["mode_hz"] < hi]
            k = sum(r in right for r in sub)
            print(f"  mode {lo}–{hi} Hz: {k}/{len(sub)}")
    gates = [r for r in rows if r.get("peak_over_floor") is not None and _peak_passes(r, 0.0)]
    top = sorted(float(r["peak_over_floor"]) for r in gates)[-5:]
    print(f"peaks passing every other gate: {len(gates)}; their height/floor, largest: {top}")
    for c in cs:
        k = sum(_peak_passes(r, c, top_edge=False) for r in rows)
        print(f"resonance at c = {c:g} without the top edge's flank: {rate(k)}")
    for key in ("profile", "gaps"):
        for value in sorted({str(r.get(key)) for r in rows}):
            sub = [r for r in rows if str(r.get(key)) == value]
            passing = [r for r in sub if r.get("peak_over_floor") is not None and _peak_passes(r, 0.0)]
            heights = sorted(round(float(r["peak_over_floor"]), 2) for r in passing)[-5:]
            by_c = "; ".join(f"c = {c:g}: {rate(sum(_peak_passes(r, c) for r in sub), len(sub))}" for c in cs)
            print(f"{key} {value}: {by_c}; every other gate {len(passing)}, height/floor largest {heights}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nulls", type=int, default=200)
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--size", type=float, default=0.0, help="a mode of m·1.5·σv (0: a null)")
    ap.add_argument("--tau-ms", type=float, default=0.0, help="colour the vibration (OU, as the outsider)")
    ap.add_argument("--lo-hz", type=float, default=30.0)
    ap.add_argument("--hi-hz", type=float, default=90.0)
    ap.add_argument("--out", type=Path, help="appended to")
    ap.add_argument("--first", type=int, default=0, help="the first case's index (a split run)")
    ap.add_argument("--step", type=int, default=1, help="every step-th case from --first")
    ap.add_argument("--peak-only", action="store_true", help="leave out the whole-band colour test")
    ap.add_argument("--mix", action="store_true", help="excitation and gaps by the index (MIX_PROFILES)")
    ap.add_argument("--wide-hz", type=float, default=0.0, help="also the tests over 0.5–this (see _wide)")
    ap.add_argument("--summary", type=Path, nargs="+")
    ap.add_argument("--c", type=float, nargs="*", default=[peak.__dict__.get("PEAK_FLOOR_C", 1.0)])
    a = ap.parse_args()
    if a.summary:
        summary(a.summary, a.c)
    else:
        run(a)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
