"""Before/after of the family's 500 Hz cases (scripts/linescan2_family500.py rows against the stored
rows of the same seed, e.g. docs/measurements/peakevid/nulls-seed1202.jsonl): what each test named.

    .venv/bin/python scripts/linescan2_family_compare.py BEFORE.jsonl AFTER.jsonl [B2 A2 ...]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bandfloor_peaks as bp
from outsider_run import cp95


def main() -> int:
    pairs = list(zip(sys.argv[1::2], sys.argv[2::2], strict=True))
    n = kb = ka = 0
    for b_path, a_path in pairs:
        before = {r["i"]: r for r in map(json.loads, Path(b_path).read_text().splitlines())}
        for a in map(json.loads, Path(a_path).read_text().splitlines()):
            b = before[a["i"]]
            # the before's answer re-judged by the current gates (its rows hold the statistics)
            nb = b["named"] if b["named"] != "resonance" else ("resonance" if bp._peak_passes(b, bp.peak.PEAK_FLOOR_C) else None)
            n, kb, ka = n + 1, kb + (nb is not None), ka + (a["named"] is not None)
            if nb != a["named"]:
                print(f"{Path(a_path).name} #{a['i']}: {nb} -> {a['named']} (counts {a['counts']}, {a['profile']}, "
                      f"gaps {a['gaps']}; colour p {b['colour_p']:.2g} -> {a['colour_p']:.2g}, "
                      f"peak {b['peak_hz']:.2f} Hz {b.get('peak_over_floor')} -> {a['peak_hz']:.2f} Hz {a.get('peak_over_floor')})")  # fmt: skip
    for label, k in (("before", kb), ("after", ka)):
        lo, hi = cp95(k, n)
        print(f"{label}: {k}/{n} named ({100 * k / n:.2f} %, 95 % CP {100 * lo:.2f}–{100 * hi:.2f} %)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
