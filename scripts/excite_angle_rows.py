"""Moving rows by the speed and by the angle, per file (docs/measurements/badinput.md).

    nice -n 19 .venv/bin/python scripts/excite_angle_rows.py FILE...

For each recording: the regression rows whose speed stands clear of CLEAR·σ (the check before),
the rows needed (ROWS_PER_COLUMN × the baseline's columns), and the check added
(tvsd.analysis.excitation.angle_agrees): of the 20 stretches in which the speed's integral says
the shaft turned clear of the angle's noise, how many φ's change agrees with (refused under half).
Loading errors are printed as such. The last line counts the files each check refuses.
"""

from __future__ import annotations

import sys
from pathlib import Path

from tvsd.analysis import absorber, excitation
from tvsd.analysis import design as D
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import EMPS_BAND, Band, prepare
from tvsd.config import load_config
from tvsd.errors import DataFileError


def main(paths: list[str]) -> int:
    cfg = load_config()
    by_speed = by_angle = n = 0
    for name in paths:
        try:
            data = load(Path(name), cfg)
        except DataFileError as exc:
            print(f"{name}: not loaded: {exc}")
            continue
        band = EMPS_BAND if data.units.axis == "linear" else Band()
        prep = prepare(data, band)
        need = (
            excitation.ROWS_PER_COLUMN
            * absorber.absorb(D.build(prep, data.offset_term, data.units.axis == "rotary")).X.shape[1]
        )
        moving, rows, sigma = excitation.moving_rows(prep)
        has_angle = data.speed is not None and data.position_measured
        claimed, agreed, clear = excitation.angle_agrees(data) if has_angle else (-1, -1, 0.0)
        n += 1
        by_speed += moving < need
        by_angle += moving >= need and 2 * agreed < claimed
        print(
            f"{Path(name).name}: rows {rows}, need {need}, speed moving {moving} (5σ {5 * sigma:.3g}), "
            f"angle agrees in {agreed} of {claimed} stretches (threshold {clear:.3g})"
        )
    print(f"{n} files: refused by the speed {by_speed}, by the angle (new) {by_angle}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
