"""The line scan on an encoder-difference recording, traced (docs/measurements/linefloor.md):
its winning ordinate, the held levels' count rates and where their sawtooth lines fold, and the
quantisation floor against the residual's Welch spectrum at the winning frequency.

    .venv/bin/python scripts/linefloor_probe.py RECORDING.csv
"""

import sys
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from tvsd.analysis import absorber, quantisation
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.dataset import load
from tvsd.analysis.linescan import RES_BAND, excitation_rows, line_scan
from tvsd.analysis.noise import _welch
from tvsd.analysis.prep import Band, prepare
from tvsd.config import load_config


def main() -> None:
    path = Path(sys.argv[1])
    data = load(path, load_config())
    prep = prepare(data, Band())
    design = absorber.absorb(D.build(prep, data.offset_term, data.units.axis == "rotary"))
    out = C.test_all(design, seed=0)
    fs_rows = 1.0 / float(np.median(np.diff(prep.t_rows)))
    f_hi = RES_BAND * min(prep.band.cutoff_hz, fs_rows / 2)
    scan = line_scan(
        out.resid, [x[out.keep] for x in excitation_rows(design)], fs_rows, f_hi, data.excitation_hz
    )
    d, f0 = scan.peak(out.resid)
    res = next(t for t in out.tested if t.cause == "resonance")
    e = out.resid
    flat = 2.0 * float(e @ e) / len(e)
    print(
        f"rows {fs_rows:g} Hz, scan to {f_hi:.1f} Hz; peak ordinate {d / flat:.1f}× the flat level at {f0:.3f} Hz"
    )
    print(
        f"resonance z {res.z:.2f} (gate {out.threshold:.2f}), refined {res.frequency_hz:.3f} Hz; top {out.tested[0].cause}"
    )
    step = quantisation.count_step(prep)
    fs = data.sample_rate_hz
    print(f"count step {step} rad/s per count/sample; fs {fs:g} Hz, decim {prep.band.decim}")
    assert data.speed is not None and step is not None
    # Held levels: the command's runs; each level's mean speed and its count rate.
    u = data.u
    edges = np.flatnonzero(np.diff(u) != 0) + 1
    q = step / fs
    for lo, hi in zip(np.r_[0, edges], np.r_[edges, len(u)], strict=True):
        if hi - lo < fs:  # a level held under 1 s
            continue
        w = data.speed[lo + (hi - lo) // 2 : hi]  # its settled half
        r = abs(float(np.mean(w))) / q  # counts/s
        lines = []
        for n in range(1, 6):
            fa = np.mod(n * r, fs)
            fa = min(fa, fs - fa)
            fr = np.mod(fa, fs_rows)
            fr = min(fr, fs_rows - fr)  # and folded again into the rows' band
            lines.append(f"{fr:.2f}")
        t_rows = prep.t_rows[out.keep]
        sel = (t_rows >= data.t[lo]) & (t_rows < data.t[hi - 1])
        share = 0.0
        if np.count_nonzero(sel) > 10:
            z = e[sel] @ np.exp(-2j * np.pi * f0 * t_rows[sel])
            share = float(abs(z) ** 2) * 2.0 / len(e) / flat  # this level's part of the ordinate (amplitude²)
        end = abs(float(np.mean(data.speed[max(hi - int(fs), lo) : hi]))) / q
        fa = np.mod(end, fs)
        fa = min(fa, fs - fa)
        fr = np.mod(fa, fs_rows)
        fr = min(fr, fs_rows - fr)
        print(
            f"   last 1 s rate {end:9.2f} counts/s, n=1 line at rows {fr:.2f} Hz; |DFT at f0|² of this level {share:.1f}× flat"
        )
        print(
            f"t {lo / fs:6.1f}-{hi / fs:6.1f} s u {u[lo]:+.3f} rate {r:9.2f} counts/s ({r / fs:.3f}/sample) lines n=1..5 at rows: {' '.join(lines)}"
        )
    # The floor vs the residual's Welch spectrum (the peak test's view) around f0.
    resid = np.where(
        out.keep,
        design.y - design.X @ np.linalg.lstsq(design.X[out.keep], design.y[out.keep], rcond=None)[0],
        0.0,
    )
    g, fl = quantisation.gated(prep, out.keep, resid, fs_rows)
    assert fl is not None
    f, p, _ = _welch(g, fs_rows)
    k = int(np.argmin(np.abs(f - f0)))
    for j in range(k - 4, k + 5):
        print(
            f"welch {f[j]:7.2f} Hz  resid {p[j]:.3e}  floor {float(fl(np.array([f[j]]))[0]):.3e}  ratio {p[j] / float(fl(np.array([f[j]]))[0]):.2f}"
        )


if __name__ == "__main__":
    with threadpool_limits(limits=1, user_api="blas"):
        main()
