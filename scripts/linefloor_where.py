"""Where the line scan's o13049 ordinate at 44.363 Hz comes from (docs/measurements/linefloor.md): each
2 s of rows' share of it (its projection on the total's phase), the count rate there, and the share of
the 2 s in which harmonic n of the count rate folds to within 0.5 Hz of it.

    .venv/bin/python scripts/linefloor_where.py RECORDING.csv
"""

import sys
import numpy as np
from tvsd.analysis import absorber, calibrate as C, design as D, quantisation
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, prepare
from tvsd.config import load_config
from scipy.signal import butter, filtfilt

data = load(sys.argv[1], load_config())
prep = prepare(data, Band())
design = absorber.absorb(D.build(prep, data.offset_term, True))
out = C.test_all(design, seed=0)
e = out.resid
t = prep.t_rows[out.keep]
f0 = 44.363
flat = 2.0 * float(e @ e) / len(e)
z = e * np.exp(-2j * np.pi * f0 * t)
tot = z.sum()
u = tot / abs(tot)
fs = 500.0
step = quantisation.count_step(prep)
q = step / fs
b, a = butter(2, 5 / (fs / 2))
sp = filtfilt(b, a, data.speed)
rate = np.abs(sp) / q


# where harmonic n of the count rate folds (full rate, then the rows' aliases) near f0
def fold(x, m):
    x = np.mod(x, m)
    return np.minimum(x, m - x)


for s in np.arange(6, 60, 2.0):
    sel = (t >= s) & (t < s + 2)
    proj = float(np.real(z[sel].sum() * np.conj(u)))
    w = (data.t >= s) & (data.t < s + 2)
    hits = []
    for n in range(1, 9):
        fr = fold(fold(n * rate[w], fs), 125.0)
        frac = np.mean(np.abs(fr - f0) < 0.5)
        if frac > 0:
            hits.append(f"n{n}:{frac:.2f}")
    print(
        f"{s:4.0f}-{s + 2:3.0f}s proj {proj:+8.1f} ({proj**2 * 2 / len(e) / flat:6.2f}× flat alone)  rate {rate[w].min():7.0f}-{rate[w].max():7.0f} c/s  near f0: {' '.join(hits)}"
    )
print("total", abs(tot) ** 2 * 2 / len(e) / flat)
