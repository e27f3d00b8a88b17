"""How much of each outsider case's hidden effect the recording can show (no doctor run).

    .venv/bin/python scripts/outsider_exposure.py --seed 7 --reps 2 --nulls 30 [--markdown]

The outsider bench (tests/outsider_bench.py) sizes a dead zone and a clip by the command's
nominal top (`u_top`), not by the commands a file holds, and draws a mode's frequency up to
90 Hz whatever the sample rate. So a case can hide an effect its recording never exercises:
a clip above every command, a hard dead zone narrower than the staircase's smallest non-zero
level, a mode above the doctor's line scan. Per case this prints what the command actually does
(the same open-loop command `make` plays: `_command` is the first draw of its generator; closed
loop is left out, its command comes from the loop):

- saturation: share of samples with |u| > u_max, and the clipped part's rms over u's rms;
- dead zone: share of samples with 0 < |u| < u0 (inside the zone, where a hard one acts); a
  shifted one also moves every other command by u0, which only reversals tell from Coulomb
  friction;
- resonance: the mode's frequency against the top of the doctor's line scan
  (RES_BAND × min(band corner, the rows' Nyquist), tvsd.analysis.linescan / prep).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import outsider_bench as ob

from tvsd.analysis.linescan import RES_BAND
from tvsd.analysis.prep import Band


def scan_top_hz(fs: float, band: Band | None = None) -> float:
    """The highest frequency the doctor's resonance line scan reaches at sample rate fs."""
    band = band or Band()
    corner = min(band.cutoff_hz, 0.4 * fs)
    return RES_BAND * min(corner, fs / band.decim / 2)


def exposure(s: ob.Spec, u_rec: np.ndarray | None = None) -> dict[str, float | str]:
    """What the command does to the case's effect; `u_rec` the recorded command (closed loop:
    the loop's own output, which no replay gives), else the open-loop command replayed."""
    if u_rec is None:
        n = int(s.seconds * s.fs)
        u_rec, _ = ob._command(s, np.random.default_rng([s.seed, 0x0B]), n)
    u = u_rec * s.drive["u_scale"]  # thresholds are in the drive's own unit (duty → V)
    tr = s.truth
    if s.cause == "saturation":
        over = np.maximum(np.abs(u) - tr["u_max"], 0.0)
        return {
            "acts_share": float(np.mean(over > 0)),
            "excess_rms_rel": float(np.sqrt(np.mean(over**2)) / u.std()),
        }
    if s.cause == "deadzone":
        inside = (np.abs(u) < tr["u0"]) & (u != 0)
        smallest = float(np.min(np.abs(u[u != 0]))) if np.any(u != 0) else math.nan
        return {
            "acts_share": float(np.mean(inside)),
            "kind": "shifted" if tr["shifted"] else "hard",
            "u0_over_smallest": tr["u0"] / smallest,
        }
    if s.cause == "resonance":
        top = scan_top_hz(s.fs)
        return {
            "acts_share": float(tr["frequency_hz"] <= top),
            "f_hz": tr["frequency_hz"],
            "scan_top_hz": top,
        }
    return {}


def showable(s: ob.Spec, u_rec: np.ndarray | None = None) -> str:
    """'no' when the recording cannot hold the effect (a clip never reached, a hard dead zone no
    command enters, a mode above the line scan), 'marginal' when it acts on under 1 % of the
    samples (the doctor's support for a threshold), else 'yes'."""
    e = exposure(s, u_rec)
    if not e or (s.cause == "deadzone" and e["kind"] == "shifted"):
        return "yes"  # a shifted zone moves every command by u0
    share = float(e["acts_share"])
    return "no" if share == 0 else "marginal" if share < 0.01 else "yes"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--nulls", type=int, default=30)
    a = ap.parse_args(argv)
    print("| case | cause | size | excitation | unit | fs | what the recording shows |")
    print("|---|---|---|---|---|---|---|")
    for seed, cause, m in ob.plan(a.seed, a.reps, a.nulls):
        if cause not in ("saturation", "deadzone", "resonance"):
            continue
        s = ob.draw(seed, cause, m)
        if s.excitation == "closed":
            continue
        e = exposure(s)
        text = ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in e.items())
        print(f"| {s.name} | {cause} | {m:g} | {s.excitation} | {s.unit} | {s.fs:g} | {text} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
