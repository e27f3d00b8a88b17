"""Review of the session's merged doctor (docs/measurements/review6.md): defects at the seams."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import outsider_bench as ob

from tvsd.analysis import spectral_fit
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, prepare
from tvsd.config import load_config


def _kept_for(mask: np.ndarray, order: int) -> np.ndarray:
    """calibrate.test_all's rows: in `mask`, and no row out of it in an AR(order)'s memory."""
    keep = mask.copy()
    for lag in range(1, order + 1):
        keep[lag:] &= mask[:-lag]
    keep[:order] = False
    return keep


def test_the_refit_ignores_the_rows_the_doctor_left_out(tmp_path: Path) -> None:
    """Open loop on a 256-count encoder: refit whitens with AR(FLOOR_AR_ORDER), longer than the
    doctor's AR whose memory `keep` was cleared for. The residual on the rows left out (the shaft
    stuck: the model does not hold there) must not reach the rows kept through that longer
    filter's memory. Changed there by 1e3× the residual's scale, the rows kept may move only by
    the solve's rounding (relative 1e-9: the normal equations' condition number squared, ~1e6,
    times float64's 1e-16 is 1e-10)."""
    s = ob.draw(14083, "none", 0.0, closed=False)
    s.seconds, s.sensor["cpr"], s.sensor["omega"], s.sensor["declare_cpr"] = 20.0, 256, "diff", True
    path = tmp_path / "open.csv"
    ob.write(path, s, ob.make(s))
    prep = prepare(load(path, load_config()), Band())
    n = len(prep.t_rows)
    g = np.random.default_rng(3)
    moving = np.ones(n, dtype=bool)
    moving[n // 3 : n // 3 + 50] = False
    ar = np.array([1.0, -0.5])
    keep = _kept_for(moving, len(ar) - 1)
    resid, X = g.standard_normal(n), g.standard_normal((n, 4))
    rate = 1.0 / float(np.median(np.diff(prep.t_rows)))
    r0, f0 = spectral_fit.refit(prep, keep, resid, rate, (X, ar))
    assert f0 is not None  # the floor's AR(48) is the one under test
    stuck = resid.copy()
    stuck[~moving] += 1e3
    r1, _ = spectral_fit.refit(prep, keep, stuck, rate, (X, ar))
    np.testing.assert_allclose(r1[keep], r0[keep], rtol=0, atol=1e-9 * float(np.std(r0[keep])))
