"""The colour test's band stopped where the quantisation floor reaches a fraction of the flat level
(docs/measurements/peakfix.md §3): a family null regenerated as scripts/bandfloor_peaks.py --mix
draws it, its colour p with the band to the floor = 1, 0.5, 0.25 × the flat level.

    .venv/bin/python scripts/peakfix_colour_probe.py [SEED CASE]     # default 1202 208
"""

import dataclasses
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import bandfloor_peaks as bp
import quantisation_nulls as qn

from tvsd.analysis import noise, quantisation

seed, i = (int(sys.argv[1]), int(sys.argv[2])) if len(sys.argv) > 2 else (1202, 208)
rng = np.random.default_rng([seed, i])
null = dataclasses.replace(qn.draw(rng), profile=bp.MIX_PROFILES[i % 4])
gaps = (i // 4) % 2 == 0
every, keep, prep = qn.rows(null, rng)
rate = null.fs / prep.band.decim
resid, floor = (
    quantisation.gated(prep, keep, every, rate)
    if gaps
    else (every, quantisation.floor(prep, np.ones(len(every), bool)))
)
r = noise.analyse(resid, rate, 1.0, 100.0, floor)
print(
    null,
    "gaps",
    gaps,
    "named",
    noise.spectral_cause(r, 1e-3),
    "colour p",
    r.colour_p,
    "lr",
    r.colour_lr,
    "tau",
    r.tau_s,
    "band",
    r.colour_band_hz,
)
f, p, seg = noise._welch(resid, rate)
fw, pw, kw, a0, cut = noise._whole_band(f, p, 100.0, floor)
for frac in (1.0, 0.5, 0.25):
    above = np.nonzero(kw > frac * a0)[0]
    c = int(above[0]) if len(above) else len(fw)
    fm, pm, known = fw[:c], pw[:c], kw[:c]
    white, best = noise._colour_fits(fm, pm, known, a0, noise._slope(fm, pm, known))
    lr = max(0.0, 2 * noise.effective_segments(seg, 2 * (len(f) - 1)) * (white.fun - best.fun))
    print(f"band to floor = {frac} flat: top {fm[-1]:.2f} Hz, colour p {chi2.sf(lr, 1):.3g}")
