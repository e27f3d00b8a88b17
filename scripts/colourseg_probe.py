"""The colour test on one recording's residual rows, counted three ways (docs/measurements/colourseg.md):
on every Welch segment (integ3), on the segments' equal-level equivalent (peak.segment_share), and
on the rows from the first kept one only (the left-out start cut off, not only rescaled).

    python scripts/colourseg_probe.py FILE.csv [...]
    python scripts/colourseg_probe.py --scan FILE.csv   # also with the left-out start cut away bit by bit

The doctor runs in-process; its residual rows are read where it hands them to noise.analyse (this
script wraps that name in the doctor module; library code is not changed)."""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from scipy.stats import chi2

from tvsd.analysis import doctor, noise, peak
from tvsd.analysis.dataset import load
from tvsd.config import load_config


def rows_of(path: str) -> dict[str, Any]:
    """The residual rows (and rate, band, floor, gain) the doctor hands to noise.analyse."""
    cfg = load_config()
    seen: dict[str, Any] = {}
    inner = doctor.analyse

    def grab(resid: np.ndarray, rate: float, J: float, band: float, floor: Any, gain: Any) -> Any:
        seen.update(resid=resid.copy(), rate=rate, band=band, floor=floor, gain=gain)
        return inner(resid, rate, J, band, floor, gain)

    doctor.analyse = grab  # type: ignore[assignment]
    try:
        doctor.diagnose(load(path, cfg), cfg.plant.v0)
    finally:
        doctor.analyse = inner  # type: ignore[assignment]
    return seen


def main(paths: list[str]) -> None:
    for path in paths:
        s = rows_of(path)
        r, rate, band, floor, gain = (s[k] for k in ("resid", "rate", "band", "floor", "gain"))
        nper = min(len(r), int(noise.SEGMENT_S * rate))
        share = peak.segment_share(r, nper)
        worth, count = noise.rows_worth(r, nper), noise.effective_segments(2 * len(r) // nper - 1, nper)
        lr, p = noise.colour_test(r, rate, band, floor, gain)
        lr_count = lr / worth * count
        first = int(np.argmax(r != 0))
        # the floor is the level over every row (zeros included): over the kept rows it is higher
        scale = len(r) / (len(r) - first)
        kept = None if floor is None else (lambda f, q=floor, c=scale: q(f) * c)
        lr_cut, p_cut = noise.colour_test(r[first:], rate, band, kept, gain)
        print(
            f"{path}: rows {len(r)}, first kept {first} ({first / len(r):.0%}); segments' worth: "
            f"count {count:.2f}, rows {worth:.2f}, count×share {count * share:.2f}; colour lr on the "
            f"count {lr_count:.2f} (p {chi2.sf(lr_count, 1):.2g}), ×share {lr_count * share:.2f} "
            f"(p {chi2.sf(lr_count * share, 1):.2g}), on the rows {lr:.2f} (p {p:.2g}); "
            f"start cut lr {lr_cut:.2f} (p {p_cut:.2g})"
        )


def scan(path: str) -> None:
    """The counts as the left-out start is cut away 500 rows at a time (zeros kept from row j),
    then as the kept rows are cut from their first 0–2000 rows on (the segments' alignment)."""
    s = rows_of(path)
    r, rate, band, floor, gain = (s[k] for k in ("resid", "rate", "band", "floor", "gain"))
    nper = min(len(r), int(noise.SEGMENT_S * rate))
    first = int(np.argmax(r != 0))
    for j in [*range(0, first, 500), *(first + k for k in range(0, 2001, 250))]:
        x = r[j:]
        scale = len(r) / len(x)
        kept = None if floor is None else (lambda f, q=floor, c=scale: q(f) * c)
        lr, _ = noise.colour_test(x, rate, band, kept, gain)
        worth = noise.rows_worth(x, nper)
        count = noise.effective_segments(2 * len(x) // nper - 1, nper)
        share = peak.segment_share(x, nper)
        print(
            f"from row {j} ({'zeros kept' if j < first else 'kept rows only'}): ratio on the count "
            f"{lr / worth * count:.2f}, ×share {lr / worth * count * share:.2f}, on the rows {lr:.2f}"
        )


if __name__ == "__main__":
    if sys.argv[1:2] == ["--scan"]:
        for one in sys.argv[2:]:
            scan(one)
    else:
        main(sys.argv[1:])
