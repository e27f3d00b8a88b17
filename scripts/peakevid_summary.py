"""The figures of docs/measurements/peakevid.md from scripts/bandfloor_peaks.py's rows.

    .venv/bin/python scripts/peakevid_summary.py docs/measurements/peakevid/nulls-seed1202.jsonl

For the rows given (nulls or modes, `--mix` runs): the resonance named at PEAK_FLOOR_C with the
peak's height as peak.seen_height takes it (`peak_over_floor`) and as bandfloor took it
(`peak_over_floor_spread`; rows run on bandfloor's code have only the first, which is then
bandfloor's), by excitation, gaps and rate, with 95 % Clopper–Pearson intervals; the heights
over the floor of the peaks that pass every other gate (the c that would have named them); with
`--wide-hz` rows, the same over the wider band (bandfloor_peaks._wide); with modes, how many are
named at their frequency (± 1 Hz) in each band.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bandfloor_peaks import _peak_passes, cp95

from tvsd.analysis.peak import PEAK_FLOOR_C

Row = dict[str, object]


def rate(k: int, n: int) -> str:
    if n == 0:
        return "0/0"
    lo, hi = cp95(k, n)
    return f"{k}/{n} ({100 * k / n:.1f} %, {100 * lo:.1f}–{100 * hi:.1f} %)"


def _old(r: Row) -> Row:
    """The row as bandfloor's height judges it."""
    if r.get("peak_over_floor_spread") is None:
        return r
    return r | {"peak_over_floor": r["peak_over_floor_spread"]}


def _wide(r: Row) -> Row:
    """The row's wide-band fields in the doctor-band fields' names."""
    return r | {k[5:]: v for k, v in r.items() if k.startswith("wide_")}


def _near_mode(r: Row) -> bool:
    return abs(float(r["peak_hz"]) - float(r["mode_hz"])) < 1.0  # type: ignore[arg-type]


def _split(rows: list[Row], label: str, named: Callable[[Row], bool]) -> None:
    parts: list[tuple[str, list[Row]]] = [("all", rows)]
    for key in ("profile", "gaps"):
        for value in sorted({str(r[key]) for r in rows}):
            parts.append((f"{key} {value}", [r for r in rows if str(r[key]) == value]))
    parts += [
        ("500 Hz", [r for r in rows if r["fs"] == 500.0]),
        ("1-2 kHz", [r for r in rows if r["fs"] != 500.0]),
    ]
    if any(r["mode_size"] for r in rows):
        parts += [
            ("mode 30-50 Hz", [r for r in rows if float(r["mode_hz"]) < 50.0]),  # type: ignore[arg-type]
            ("mode 50-90 Hz", [r for r in rows if float(r["mode_hz"]) >= 50.0]),  # type: ignore[arg-type]
        ]
    print(
        f"{label}: "
        + "; ".join(f"{name} {rate(sum(named(r) for r in sub), len(sub))}" for name, sub in parts)
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("rows", type=Path, nargs="+")
    a = ap.parse_args()
    rows: list[Row] = [json.loads(x) for p in a.rows for x in p.read_text().splitlines() if x.strip()]
    modes = any(r["mode_size"] for r in rows)
    c = PEAK_FLOOR_C

    def hit(r: Row) -> bool:
        return _peak_passes(r, c) and (not modes or _near_mode(r))

    print(
        f"{len(rows)} rows; {'modes: named at the mode (± 1 Hz)' if modes else 'nulls: resonance named'}",
        f"c = {c:g}",
    )
    _split(rows, "doctor's band, bandfloor's height", lambda r: hit(_old(r)))
    if any("peak_over_floor_spread" in r for r in rows):
        _split(rows, "doctor's band, the height on the bins", hit)
    for label, view in (("bandfloor's height", _old), ("the height on the bins", lambda r: r)):
        other = [view(r) for r in rows if r.get("peak_over_floor") is not None and _peak_passes(view(r), 0.0)]
        tall = sorted(round(float(r["peak_over_floor"]), 2) for r in other)  # type: ignore[arg-type]
        print(
            f"  passing every other gate ({label}): {len(other)};",
            f"height/floor ≥ 2: {[h for h in tall if h >= 2]}",
        )
    wide = [_wide(r) for r in rows if "wide_named" in r]
    if wide:
        _split(wide, f"0.5-{wide[0]['band_hi_hz']:g} Hz band (G-corrected)", hit)
        other = [r for r in wide if r.get("peak_over_floor") is not None and _peak_passes(r, 0.0)]
        tall = sorted(round(float(r["peak_over_floor"]), 2) for r in other)  # type: ignore[arg-type]
        print(f"  passing every other gate: {len(other)}; height/floor ≥ 2: {[h for h in tall if h >= 2]}")
        colour = sum(float(r["colour_p"]) < 1e-3 for r in wide)  # type: ignore[arg-type]
        print(f"  colour p < 1e-3 over the wide band's cut: {rate(colour, len(wide))}")
        named = sum(r["named"] is not None for r in wide)
        print(f"  named anything (resonance or colour) over the wide band: {rate(named, len(wide))}")
        if not modes:
            tops = [r for r in wide if _peak_passes(r, c)]
            print(f"  the wide band's alarms at: {sorted(round(float(r['peak_hz']), 1) for r in tops)}")  # type: ignore[arg-type]
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
