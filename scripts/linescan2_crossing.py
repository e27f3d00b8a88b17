"""The colour test's bins next to the quantisation floor's crossing (docs/measurements/linescan2.md):
the residual's Welch spectrum against the flat level plus the floor, band by band, on a recording
as the doctor sees it, and the colour p with the band stopped where the floor reaches a fraction
of the flat level.

    .venv/bin/python scripts/linescan2_crossing.py RECORDING.csv
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from tvsd.analysis import doctor, noise
from tvsd.config import load_config
from tvsd.analysis.dataset import load

seen: dict[str, Any] = {}
_analyse = doctor.analyse


def _capture(resid: np.ndarray, rate: float, J: float, band: float, floor: Any = None) -> Any:
    seen.update(resid=resid, rate=rate, band=band, floor=floor)
    return _analyse(resid, rate, J, band, floor)


def main() -> int:
    doctor.analyse = _capture  # this script's own wrapper: the doctor's noise input, unchanged
    data = load(Path(sys.argv[1]), load_config())
    cfg = load_config()
    doctor.diagnose(data, cfg.plant.v0)
    resid, rate, band, floor = seen["resid"], seen["rate"], seen["band"], seen["floor"]
    f, p, seg = noise._welch(resid, rate)
    fw, pw, kw, a0, cut = noise._whole_band(f, p, band, floor)
    print(f"rows {rate:g} Hz; flat a0 {a0:.4g}; floor passes it at {fw[cut] if cut < len(fw) else None} Hz")
    edges = [0.5, 2, 5, 10, 15, 20, 25, 30, 35, 40, 45, 50]
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        s = (fw >= lo) & (fw < hi)
        if s.any():
            sp, fl = float(pw[s].mean()), float(kw[s].mean())
            print(f"  {lo:4g}-{hi:<4g} Hz: spectrum/flat {sp / a0:6.2f}  floor/flat {fl / a0:6.2f}  (spectrum-floor)/flat {(sp - fl) / a0:6.2f}")
    for frac in (1.0, 0.5, 0.25):
        above = np.nonzero(kw > frac * a0)[0]
        c = int(above[0]) if len(above) else len(fw)
        fm, pm, known = fw[:c], pw[:c], kw[:c]
        white, best = noise._colour_fits(fm, pm, known, a0, noise._slope(fm, pm, known))
        lr = max(0.0, 2 * noise.effective_segments(seg, 2 * (len(f) - 1)) * (white.fun - best.fun))
        print(f"band to floor = {frac} flat: top {fm[-1]:.2f} Hz, colour p {chi2.sf(lr, 1):.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
