"""The command's lines the spectral peak test now leaves out, on recordings as the doctor sees
them (docs/measurements/freshnulls.md). One JSON line per file: the answer, the command's
detected lines, the residual's spectral peak, and `skipped`: whether the peak test fired, was
not on a declared line, and is now left out on a detected one — the only files whose answer
this change can move (elsewhere the doctor's statements are integ3's); and the colour test's p
with its band to where the quantisation floor passes the flat level (the doctor's) and ½ of it.

    .venv/bin/python scripts/freshnulls_lines.py OUT.jsonl RECORDING.csv [...] [--shard I/N]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from tvsd.analysis import doctor, noise
from tvsd.analysis.dataset import load
from tvsd.analysis.noise import COLOUR_P, spectral_cause
from tvsd.analysis.peak import on_declared_line
from tvsd.config import load_config

seen: dict[str, Any] = {}
_lines = doctor.command_lines_hz
_analyse = doctor.analyse


def _capture_lines(signals: Any, fs: float) -> tuple[float, ...]:
    out = _lines(signals, fs)
    seen["lines"] = out
    return out


def _capture_noise(*args: Any) -> Any:
    seen["noise"] = _analyse(*args)
    seen["args"] = args
    return seen["noise"]


def colour_p_at(frac: float) -> float:
    """The colour test's p with its band stopped where the quantisation floor passes `frac` of
    the flat level (1: the doctor's rule), on the residual the doctor just tested."""
    resid, rate, _, band, floor = seen["args"]
    f, p, seg = noise._welch(resid, rate)
    fw, pw, kw, a0, _ = noise._whole_band(f, p, band, floor)
    above = np.nonzero(kw > frac * a0)[0]
    c = int(above[0]) if len(above) else len(fw)
    if c < noise.MIN_SEEN_BINS:
        return 1.0
    fm, pm, known = fw[:c], pw[:c], kw[:c]
    white, best = noise._colour_fits(fm, pm, known, a0, noise._slope(fm, pm, known))
    lr = max(0.0, 2 * noise.effective_segments(seg, 2 * (len(f) - 1)) * (white.fun - best.fun))
    return float(chi2.sf(lr, 1))


def main() -> int:
    doctor.command_lines_hz = _capture_lines  # this script's own wrappers: the doctor unchanged
    doctor.analyse = _capture_noise
    args = sys.argv[1:]
    shard = (0, 1)
    if "--shard" in args:
        i = args.index("--shard")
        a, b = args[i + 1].split("/")
        shard = (int(a), int(b))
        del args[i : i + 2]
    out, files = Path(args[0]), args[1:]
    done = {json.loads(line)["file"] for line in out.open()} if out.exists() else set()
    cfg = load_config()
    for k, name in enumerate(files):
        if k % shard[1] != shard[0] or name in done:
            continue
        row: dict[str, Any] = {"file": name}
        try:
            data = load(Path(name), cfg)
            d = doctor.diagnose(data, cfg.plant.v0)
        except Exception as exc:  # a refused file: its line, as tvsctl's exit 2
            row["error"] = str(exc)[:200]
        else:
            lines, nz = seen["lines"], seen["noise"]
            fired = spectral_cause(nz, COLOUR_P) == "resonance"
            declared = on_declared_line(nz, data.excitation_hz)
            row |= {
                "cause": d.cause,
                "lines_hz": [round(f, 3) for f in lines],
                "peak_hz": nz.peak_hz,
                "peak_q": nz.peak_q,
                "peak_lr": nz.peak_lr,
                "skipped": bool(fired and not declared and on_declared_line(nz, lines)),
                "colour_p": nz.colour_p,
                "colour_p_half": colour_p_at(0.5),
                "floor_hz": nz.floor_cut_hz,
            }
        with out.open("a") as fh:
            fh.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
