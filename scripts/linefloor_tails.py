"""The line scan's ordinates on recordings, split by whether the encoder's quantisation floor
makes up most of the residual's level there (docs/measurements/linefloor.md): how many stand
above 8, 10, 12 times the flat level, against the exponential tail the scan's null assumes.

    nice -n 19 .venv/bin/python scripts/linefloor_tails.py OUT.jsonl FILE.csv ...
    .venv/bin/python scripts/linefloor_tails.py --summary OUT.jsonl ...
"""

import json
import sys
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from tvsd.analysis import absorber, quantisation
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.dataset import load
from tvsd.analysis.linescan import RES_BAND, block_floor, excitation_rows, line_scan
from tvsd.analysis.noise import _welch
from tvsd.analysis.prep import Band, prepare
from tvsd.config import load_config

LEVELS = (8.0, 10.0, 12.0)
NULL_DRAWS = 50
SHARE = 0.5  # a bin is "the floor's" where the floor is at least this share of the Welch level


def one(path: Path) -> dict[str, object]:
    data = load(path, load_config())
    prep = prepare(data, Band())
    design = absorber.absorb(D.build(prep, data.offset_term, data.units.axis == "rotary"))
    out = C.test_all(design, seed=0)
    fs_rows = 1.0 / float(np.median(np.diff(prep.t_rows)))
    f_hi = RES_BAND * min(prep.band.cutoff_hz, fs_rows / 2)
    e = out.resid
    scan = line_scan(e, [x[out.keep] for x in excitation_rows(design)], fs_rows, f_hi, data.excitation_hz)
    z = scan.ordinates(e) / (2.0 * float(e @ e) / len(e))
    th = np.linalg.lstsq(design.X[out.keep], design.y[out.keep], rcond=None)[0]
    resid = np.where(out.keep, design.y - design.X @ th, 0.0)
    g, fl = quantisation.gated(prep, out.keep, resid, fs_rows)
    share = np.zeros(len(scan.f))
    if fl is not None:
        f, p, _ = _welch(g, fs_rows)
        share = np.interp(scan.f, f, fl(f) / np.maximum(p, 1e-300))
    res = next(t for t in out.tested if t.cause == "resonance")
    k = int(np.argmax(np.where(scan.scan, z, -np.inf)))
    row: dict[str, object] = {
        "file": path.name,
        "floor": fl is not None,
        "res_z": res.z,
        "gate": out.threshold,
        "named": out.significant and out.tested[0].cause == "resonance",
        "peak_hz": float(scan.f[k]),
        "peak": float(z[k]),
        "peak_share": float(share[k]),
    }
    # the scan's own null (LineScan.null_peaks' ordinates: exponentials through the same block
    # medians), NULL_DRAWS periodograms: its expected count above each level in each class
    rng = np.random.default_rng(1)
    E = 2.0 * rng.exponential(size=(NULL_DRAWS, len(scan.f)))
    Z = E * 2.0 / np.maximum(block_floor(E, scan.width), 1e-300) / 2.0
    for name, sel in (("on", scan.scan & (share >= SHARE)), ("off", scan.scan & (share < SHARE))):
        row[f"n_{name}"] = int(np.count_nonzero(sel))
        for lv in LEVELS:
            row[f"{name}_{lv:g}"] = int(np.count_nonzero(z[sel] > lv))
            row[f"null_{name}_{lv:g}"] = float(np.count_nonzero(Z[:, sel] > lv)) / NULL_DRAWS
    return row


def summary(paths: list[str]) -> None:
    rows = [json.loads(x) for p in paths for x in Path(p).read_text().splitlines() if x.strip()]
    print(f"{len(rows)} files, {sum(r['floor'] for r in rows)} with a quantisation floor")
    for name in ("on", "off"):
        n = sum(int(r[f"n_{name}"]) for r in rows)
        parts = [
            f"{sum(int(r[f'{name}_{lv:g}']) for r in rows)} (null {sum(float(r[f'null_{name}_{lv:g}']) for r in rows):.2f})"
            for lv in LEVELS
        ]
        print(
            f"bins {name} the floor: {n}; above "
            + ", ".join(f"{lv:g}: {s}" for lv, s in zip(LEVELS, parts, strict=True))
        )
    top = sorted(rows, key=lambda r: -float(r["res_z"]))[:8]
    for r in top:
        print(
            f"  {r['file']}: resonance z {r['res_z']:.2f} (gate {r['gate']:.2f}), peak {r['peak']:.1f}× at {r['peak_hz']:.2f} Hz, floor share {r['peak_share']:.2f}"
        )


def main() -> None:
    if sys.argv[1] == "--summary":
        summary(sys.argv[2:])
        return
    with Path(sys.argv[1]).open("a") as out:
        for p in sys.argv[2:]:
            try:
                out.write(json.dumps(one(Path(p))) + "\n")
            except Exception as exc:  # a file the doctor refuses: one line, carry on
                print(f"{p}: {exc}", file=sys.stderr)
            out.flush()


if __name__ == "__main__":
    with threadpool_limits(limits=1, user_api="blas"):
        main()
