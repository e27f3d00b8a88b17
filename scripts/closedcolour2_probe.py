"""The colour of one daemon export, probed (docs/measurements/closedcolour2.md, id05): its colour
test's likelihood ratio (rule on) as exported, with the interpolated angle's floor at each frame
offset over a frame period (2 kHz frames: (1 − a)² + a² from 0.5 to 1, the floor's whole range),
with ω replaced by the control thread's own measurement (`omega_loop`), and with ω from φ
differenced (the export's φ is the angle at each sample's end, so this is its ω where the frames
cover the sample, and differs only where the loop's own values fill a bin).

    nice -n 19 .venv/bin/python scripts/closedcolour2_probe.py FILE.csv [--frame-hz 2000]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> int:
    from closedcolour2_judge import colour_row
    from doctor_nulls import _no_gain

    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.analysis.rules import DEFAULT
    from tvsd.config import load_config
    from tvsd.recording.csvfile import read, write

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("file", type=Path)
    ap.add_argument("--frame-hz", type=float, default=2000.0)
    ap.add_argument("--offsets", type=int, default=5, help="frame offsets tried over half a frame period")
    a = ap.parse_args()
    _no_gain()
    cfg = load_config()
    data = load(a.file, cfg)
    rules = dataclasses.replace(DEFAULT, closed_colour=True)

    def run(name: str, d: object) -> None:
        row = {"file": a.file.name, "variant": name, **colour_row(diagnose(d, cfg.plant.v0, rules=rules))}
        print(json.dumps(row), flush=True)

    meta = {k: v for k, v in data.meta.items() if not k.startswith("encoder_frame")}
    meta.setdefault("encoder_counts_per_rev", "8192")
    run("as exported", data)
    period = 1.0 / a.frame_hz
    # (1 − a)² + a² is symmetric about a = ½: half a period spans the floor's range
    for off in np.linspace(0.0, period / 2, a.offsets):
        framed = {**meta, "encoder_frame_hz": f"{a.frame_hz:g}", "encoder_frame_offset_s": f"{off:.6g}"}
        run(f"floor, offset {1e3 * off:.3f} ms", dataclasses.replace(data, meta=framed))
    # ω swapped in the file itself, so the loader treats it as a user's file (a late speed re-timed)
    rec = read(a.file)
    w_phi = np.diff(rec.phi, prepend=rec.phi[0]) * rec.sample_rate_hz
    w_phi[0] = w_phi[1]
    swaps = {"phi differenced": w_phi}
    if "omega_loop" in rec.extra:
        swaps["omega_loop as omega"] = rec.extra["omega_loop"]
    with tempfile.TemporaryDirectory() as tmp:
        for name, omega in swaps.items():
            path = Path(tmp) / a.file.name
            meta_out = {k: v for k, v in rec.meta.items() if k not in ("tvs-recording", "sample_rate_hz")}
            write(path, rec.t, rec.u, omega, rec.phi, rec.sample_rate_hz, meta_out, rec.extra)
            run(name, load(path, cfg))
    return 0


if __name__ == "__main__":
    sys.exit(main())
