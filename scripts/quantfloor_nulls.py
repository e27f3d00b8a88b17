"""The colour test alone on randomised encoder-difference nulls (tests/quantisation_nulls.py).

    nice -n 19 .venv/bin/python scripts/quantfloor_nulls.py --nulls 200 --seed 1 --out F.jsonl
    nice -n 19 .venv/bin/python scripts/quantfloor_nulls.py --nulls 60 --seed 3 --tau-ms 6 --out E.jsonl
    nice -n 19 .venv/bin/python scripts/quantfloor_nulls.py --nulls 100 --seed 2 --gaps --out G.jsonl
    .venv/bin/python scripts/quantfloor_nulls.py --summary F.jsonl

Each null: encoder 256–8192 counts/rev, 500/1000/2000 Hz, a staircase, multisine or fast steps
up to 1–40 counts per sample, white vibration σv 0.05–1 rad/s^1.5, 30 s; its residual rows
through the doctor's chain with the model part taken off exactly. One JSON line each: the draw,
the colour test's p with the quantisation floor (the doctor's) and without it (the test before).
The summary: the rate of p < 1e-3 (the doctor's COLOUR_P) with its 95 % Clopper–Pearson interval
(with `--tau-ms`, the vibration is OU-coloured as the outsider bench colours it: a detection rate).
With `--gaps` the rows where the shaft is stuck are left out as the doctor leaves them out, and
the test runs on the rows the doctor passes (tvsd.analysis.quantisation.gated) and, beside it,
with the gaps' hard edges (the doctor of branch quantfloor).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
from scipy.stats import beta

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import quantisation_nulls as qn

from tvsd.analysis import quantisation
from tvsd.analysis.noise import COLOUR_P, _in_band, _welch, colour_test


def cp95(k: int, n: int) -> tuple[float, float]:
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return lo, hi


def run(nulls: int, seed: int, out: Path, tau_s: float = 0.0, gaps: bool = False) -> None:
    rng = np.random.default_rng(seed)
    with out.open("w") as fh:
        for i in range(nulls):
            null = qn.draw(rng, colour_tau_s=tau_s)
            row: dict[str, object] = {"i": i, **dataclasses.asdict(null)}
            if gaps:  # the doctor's stuck rows left out: ramped (now) and hard-edged (quantfloor's)
                every, keep, prep = qn.rows(null, rng)
                rate = null.fs / prep.band.decim
                resid, floor = quantisation.gated(prep, keep, every, rate)
                hard = np.where(keep, every, 0.0)
                row["p_hard_edges"] = colour_test(hard, rate, 100.0, quantisation.floor(prep, keep))[1]
                row["kept"] = float(np.mean(keep))
            else:
                resid, rate, floor = qn.residual(null, rng)
                hard = resid
            p_floor = colour_test(resid, rate, 100.0, floor)[1]
            p_none = colour_test(hard, rate, 100.0, None)[1]
            f, p, _ = _welch(resid, rate)
            seen = _in_band(f, p, 100.0, floor)[0]  # the band left above the quantisation's floor
            top = float(seen[-1]) if len(seen) else 0.0
            row |= {"p_floor": p_floor, "p_without": p_none, "band_top_hz": top}
            fh.write(json.dumps(row) + "\n")
            fh.flush()


def summary(paths: list[Path]) -> None:
    rows = [json.loads(line) for p in paths for line in p.read_text().splitlines() if line.strip()]
    n = len(rows)
    labels = [("p_without", "without the floor"), ("p_floor", "with the floor")]
    if all("p_hard_edges" in r for r in rows):  # --gaps
        labels.insert(1, ("p_hard_edges", "with the floor, gaps' hard edges"))
    for key, label in labels:
        k = sum(r[key] < COLOUR_P for r in rows)
        lo, hi = cp95(k, n)
        rate = f"{100 * k / n:.1f} %, 95 % CI {100 * lo:.1f}–{100 * hi:.1f} %"
        print(f"{label}: {k}/{n} coloured at p < {COLOUR_P:g} ({rate})")
    tops = sorted(r["band_top_hz"] for r in rows if "band_top_hz" in r)  # rows of an older run lack it
    short = sum(t < 3.5 for t in tops)
    if tops:
        top = f"median top {tops[len(tops) // 2]:.1f} Hz, 10 % point {tops[len(tops) // 10]:.1f} Hz"
        print(f"band seen above the floor: {top}; {short}/{len(tops)} too short to test (< 3 Hz)")
    for prof in qn.PROFILES:
        sub = [r for r in rows if r["profile"] == prof]
        k = sum(r["p_floor"] < COLOUR_P for r in sub)
        print(f"  {prof}: {k}/{len(sub)} with the floor")
    for lo_c, hi_c in ((256, 1024), (1024, 4096), (4096, 8193)):
        sub = [r for r in rows if lo_c <= r["counts"] < hi_c]
        k = sum(r["p_floor"] < COLOUR_P for r in sub)
        print(f"  {lo_c}–{hi_c - 1} counts/rev: {k}/{len(sub)} with the floor")
    for r in rows:
        if r["p_floor"] < COLOUR_P:
            speed = f"{r['top_counts_per_sample']:.1f} counts/sample"
            what = f"{r['counts']} counts, {r['fs']:g} Hz, {r['profile']}, {speed}, σv {r['sigma_v']:.3f}"
            print(f"  coloured: {what}, τ {1e3 * r['colour_tau_s']:g} ms: p {r['p_floor']:.2g}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nulls", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--tau-ms", type=float, default=0.0, help="colour the vibration (an effect, not a null)")
    ap.add_argument("--gaps", action="store_true", help="leave the stuck rows out, as the doctor does")
    ap.add_argument("--summary", type=Path, nargs="+")
    a = ap.parse_args()
    if a.summary:
        summary(a.summary)
    else:
        run(a.nulls, a.seed, a.out, a.tau_ms / 1000.0, a.gaps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
