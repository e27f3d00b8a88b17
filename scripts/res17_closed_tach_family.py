"""Forced closed-loop outsider nulls with the tach's noise at its maximum (tach_white 0.02, t5
vibration), seeds LO..HI: what the doctor names (docs/measurements/res17.md, "Found, not fixed").

    cd /tmp && nice -n 19 /work/wt/res17/.venv/bin/python /work/wt/res17/scripts/res17_closed_tach_family.py \
        9000000 9000040 /tmp/res17fam
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import outsider_bench as ob

from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.matrix_open import heldout_gain_skipped
from tvsd.config import load_config


def main() -> int:
    lo, hi, folder = int(sys.argv[1]), int(sys.argv[2]), Path(sys.argv[3])
    folder.mkdir(parents=True, exist_ok=True)
    cfg = load_config()
    for seed in range(lo, hi):
        s = ob.draw(seed, "none", 0.0, closed=True)
        s.sensor["omega"], s.sensor["tach_white"], s.noise["dist"] = "tach", 0.02, "t5"
        path = folder / f"c{seed}.csv"
        if not path.exists():
            ob.write(path, s, ob.make(s))
        with heldout_gain_skipped():
            d = diagnose(load(path, cfg), cfg.plant.v0)
        r = next((x for x in d.ranked if x.cause == "resonance"), None)
        z = round(float(r.z), 2) if r else None
        print(json.dumps({"seed": seed, "found": d.cause, "z_resonance": z}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
