"""The colour test with the rows chain's own roll-off of a white vibration in both shapes (docs/measurements/colour14.md §4):

nice -n 19 .venv/bin/python scripts/colour14_rolloff.py prbs500 141006    # a class of tests/outsider_classes.py and a case seed
nice -n 19 .venv/bin/python scripts/colour14_rolloff.py o 14073           # an outsider case as drawn
"""

import math
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.signal import freqz
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import colour14_probe as cp
import outsider_classes as oc

from tvsd.analysis import noise
from tvsd.analysis.prep import antialias

cls, case = sys.argv[1], int(sys.argv[2])
s = oc.spec_of(cls, case, "none", 0.0) if cls != "o" else cp.ob.draw(case, "none", 0.0)
r = cp.run(s, Path(tempfile.mkdtemp()))
prep, rate, band, floor, resid = r["prep"], r["rate"], r["band"], r["floor"], r["resid"]
fs = prep.data.sample_rate_hz


def G(f):
    w = 2 * np.pi * f / fs
    _, hb = freqz(prep.b, prep.a, worN=w)
    g = np.abs(hb) ** 4 * (np.sin(w) / w) ** 2 * np.sinc(f / fs) ** 2
    if prep.band.decim > 1:
        bc, ac = antialias(prep.band.decim)
        _, hc = freqz(bc, ac, worN=w)
        g = g * np.abs(hc) ** 4
    return g


f, p, seg = noise._welch(resid, rate)
fm, pm, known, a0, cut = noise._whole_band(f, p, band, floor)
fm, pm, known = fm[:cut], pm[:cut], known[:cut]
g = G(fm)
print("G at band top", fm[-1], g[-1], "at 20 Hz", G(np.array([20.0]))[0])


def wh(params, coloured, gg):
    if np.any(np.abs(params) > 300):
        return math.inf
    a, b = math.exp(params[0]), math.exp(params[1])
    lp = 1.0 if not coloured else 1 / (1 + (2 * math.pi * fm * math.exp(params[2])) ** 2)
    S = a * gg * lp + b * fm**2 + known
    return float(np.sum(np.log(S) + pm / S))


b0 = noise._slope(fm, pm, known)
for name, gg in (("flat (as the doctor)", np.ones_like(fm)), ("chain roll-off", g)):
    white = minimize(wh, [math.log(a0), math.log(b0)], args=(False, gg), method="Nelder-Mead")
    best = min(
        (
            minimize(
                wh,
                [math.log(a0), math.log(b0), math.log(t)],
                args=(True, gg),
                method="Nelder-Mead",
                options={"maxiter": 2000},
            )
            for t in (0.003, 0.01, 0.03, 0.1, 0.3)
        ),
        key=lambda x: x.fun,
    )
    lr = max(0.0, 2 * noise.effective_segments(seg, 2 * (len(f) - 1)) * (white.fun - best.fun))
    print(f"{name}: colour p {chi2.sf(lr, 1):.3g} tau {math.exp(best.x[2]) * 1e3:.2f} ms")
