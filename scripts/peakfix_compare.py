"""Before → after on the rows of scripts/bandfloor_peaks.py (docs/measurements/peakfix.md).

    .venv/bin/python scripts/peakfix_compare.py BEFORE.jsonl AFTER.jsonl

The cases both files hold (by index): what each names at the doctor's p, PEAK_FLOOR_C = 5, and the
after file re-judged with the top edge's rule of this branch (the fitted centre inside the bins the
peak test saw, noise._flanked) — the rows record the rule of the code that ran them. On mode rows
(--size): the modes named `resonance` within 1 Hz, and those at 49–50.5 Hz (the band's top).
95 % Clopper–Pearson intervals.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import bandfloor_peaks as bp

from tvsd.analysis.noise import COLOUR_P


def load(path: str) -> dict[int, dict[str, object]]:
    return {int(r["i"]): r for r in (json.loads(x) for x in Path(path).read_text().splitlines() if x.strip())}


def inside_top(r: dict[str, object]) -> str | None:
    """What the row names with the fitted centre inside the band's top (not two bins inside it)."""
    top = r.get("band_hi_hz")
    inside = top is None or float(r["peak_hz"]) <= float(top)  # type: ignore[arg-type]
    if bp._peak_passes(r, 5.0, top_edge=False) and inside:
        return "resonance"
    return "colored_noise" if float(r["colour_p"]) < COLOUR_P else None  # type: ignore[arg-type]


def rate(k: int, n: int) -> str:
    lo, hi = bp.cp95(k, n)
    return f"{k}/{n} ({100 * k / max(n, 1):.2f} %, {100 * lo:.2f}–{100 * hi:.2f} %)"


def at_mode(r: dict[str, object], named: object) -> bool:
    return named == "resonance" and abs(float(r["peak_hz"]) - float(r["mode_hz"])) < 1.0  # type: ignore[arg-type]


def main() -> int:
    before, after = load(sys.argv[1]), load(sys.argv[2])
    common = sorted(set(before) & set(after))
    modes = any(before[i].get("mode_size") for i in common)
    for kind in ("all", "staircase", "multisine", "steps"):
        sub = [i for i in common if kind == "all" or before[i]["profile"] == kind]
        if not sub:
            continue
        if modes:
            edge = [i for i in sub if 49.0 <= float(before[i]["mode_hz"]) <= 50.5]  # type: ignore[arg-type]
            b = sum(at_mode(before[i], before[i]["named"]) for i in sub)
            a = sum(at_mode(after[i], after[i]["named"]) for i in sub)
            n = sum(at_mode(after[i], inside_top(after[i])) for i in sub)
            e0 = sum(at_mode(before[i], before[i]["named"]) for i in edge)
            e1 = sum(at_mode(after[i], after[i]["named"]) for i in edge)
            e2 = sum(at_mode(after[i], inside_top(after[i])) for i in edge)
            print(
                f"{kind}: modes named at the mode: before {rate(b, len(sub))}; floor spread "
                f"{rate(a, len(sub))}; + top edge {rate(n, len(sub))}; "
                f"modes at 49–50.5 Hz {len(edge)}: {e0} → {e1} → {e2}"
            )
        else:
            named = {
                "before": [i for i in sub if before[i]["named"]],
                "floor spread": [i for i in sub if after[i]["named"]],
                "+ top edge": [i for i in sub if inside_top(after[i])],
            }
            print(f"{kind}: " + "; ".join(f"{k} {rate(len(v), len(sub))} {v}" for k, v in named.items()))
    changed = [
        (i, before[i]["named"], inside_top(after[i]))
        for i in common
        if before[i]["named"] != inside_top(after[i])
    ]
    print(f"answers changed (before → after with both changes): {changed}")
    for name, rows in (("before", before), ("after", after)):
        passing = [
            r for i in common if (r := rows[i]).get("peak_over_floor") is not None and bp._peak_passes(r, 0.0)
        ]
        top = sorted(round(float(r["peak_over_floor"]), 2) for r in passing)[-5:]  # type: ignore[arg-type]
        print(f"{name}: peaks passing every other gate {len(passing)}, their height/floor, largest {top}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
