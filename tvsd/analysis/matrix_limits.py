"""The per-cause limits of a matrix batch, read from its JSON-lines rows (issue 12, item 5): shared
by the open-loop (tvsd.analysis.matrix_open) and closed-loop (tvsd.analysis.matrix_closed) batches.

A row holds the case (cause, size m, noise units, profile, σv), `seen` (its effect measured on the
recording) and, under `key` (the variant: `ls` by default), what the doctor named and `<key>_why`.
The stated limit of a cause is the lowest size from which naming is ≥ 95 % at that size and at
every larger one (and the 90 % one likewise), with the rate over all cases from there up and its
95 % Clopper–Pearson interval; `pooled` states it in noise units measured on the recording.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from tvsd.analysis import matrix as M


def _units(rs: list[dict[str, Any]]) -> float:
    from tvsd.analysis.confusion import units

    u = [units(r) for r in rs]
    return float(np.median(u)) if u and all(math.isfinite(x) for x in u) else math.nan


def limits(rows: list[dict[str, Any]], rate: float = 0.95, key: str = "ls") -> dict[str, dict[str, Any]]:
    """Per cause: named k/n and median noise units per size; the lowest size from which every
    size is named at ≥ `rate`, the cases from there up and their 95 % interval; what was named
    instead, and on the misses the true cause's z against the gate."""
    out: dict[str, dict[str, Any]] = {}
    for cause in sorted({r["cause"] for r in rows} - {"none"}):
        rs = [r for r in rows if r["cause"] == cause]
        by = {m: [r for r in rs if r["size"] == m] for m in sorted({r["size"] for r in rs})}
        ok = {m: sum(r[key] == cause for r in g) for m, g in by.items()}
        lim = M.lowest_size_from({m: ok[m] / len(g) for m, g in by.items()}, rate)
        entry: dict[str, Any] = {
            "named_by_size": {f"{m:g}x": f"{ok[m]}/{len(g)}" for m, g in by.items()},
            "units_by_size": {f"{m:g}x": round(_units(g), 3) for m, g in by.items()},
            "limit_size": lim,
        }
        if math.isfinite(lim):
            above = [r for r in rs if r["size"] >= lim]
            hits = sum(r[key] == cause for r in above)
            lo, hi = M.clopper_pearson(hits, len(above))
            entry.update(
                limit_units=round(_units(by[lim]), 3),
                above=f"{hits}/{len(above)}",
                above_ci95_pct=[round(100 * lo), round(100 * hi)],
            )
        misses = [r for r in rs if r[key] != cause]
        entry["named_instead"] = dict(Counter(str(r[key])[:40] for r in misses).most_common())
        entry["misses"] = [
            [f"{r['size']:g}x", r["profile"], round(r["sigma_v"], 3), str(r[key])[:30],
             r.get(f"{key}_why", {}).get("z", {}).get(cause), r.get(f"{key}_why", {}).get("threshold")]
            for r in misses
        ]  # fmt: skip
        out[cause] = entry
    return out


def nulls(rows: list[dict[str, Any]], key: str = "ls") -> dict[str, Any]:
    ns = [r for r in rows if r["cause"] == "none"]
    fa = [r for r in ns if r[key] != "none"]
    lo, hi = M.clopper_pearson(len(fa), len(ns)) if ns else (math.nan, math.nan)
    return {
        "nulls": len(ns),
        "false_alarms": len(fa),
        "ci95_pct": [round(100 * lo, 1), round(100 * hi, 1)],
        "named": dict(Counter(str(r[key])[:40] for r in fa)),
    }


POOLED_UNITS = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)


def pooled(rs: list[dict[str, Any]], cause: str, rate: float = 0.95, key: str = "ls") -> str:
    """The lowest X (of POOLED_UNITS) for which the cases whose effect measures ≥ X noise units
    are named at ≥ `rate`, all sizes pooled, with the count and its 95 % interval."""
    from tvsd.analysis.confusion import units

    for x in POOLED_UNITS:
        above = [r for r in rs if units(r) >= x]
        hits = sum(r[key] == cause for r in above)
        if above and hits >= rate * len(above):
            lo, hi = M.clopper_pearson(hits, len(above))
            return f"from {x:g}u: {hits}/{len(above)} (CI {100 * lo:.0f}-{100 * hi:.0f} %)"
    return "not reached"


def table(rows: list[dict[str, Any]], key: str = "ls") -> str:
    from tvsd.analysis.confusion import limit

    lim95, lim90 = limits(rows, 0.95, key), limits(rows, 0.90, key)
    sizes = sorted({r["size"] for r in rows if r["cause"] != "none"})
    head = f"{'cause':19s}" + "".join(f"{f'{m:g}x':>14s}" for m in sizes)
    out = [head + "  95 % from (units; cases above, CI)   90 % from   named instead"]
    for cause, e in lim95.items():
        cells = "".join(
            f"{e['named_by_size'].get(f'{m:g}x', '-'):>7s}{_u(e['units_by_size'].get(f'{m:g}x')):>7s}"
            for m in sizes
        )
        if math.isfinite(e["limit_size"]):
            ci = e["above_ci95_pct"]
            s95 = f"{e['limit_size']:g}x ({_u(e['limit_units']).strip()}u; {e['above']}, {ci[0]}-{ci[1]} %)"
        else:
            s95 = "never"
        l90 = lim90[cause]["limit_size"]
        s90 = f"{l90:g}x" if math.isfinite(l90) else "never"
        inst = ", ".join(f"{k} {v}" for k, v in e["named_instead"].items())
        out.append(f"{cause:19s}{cells}  {s95:37s} {s90:10s} {inst}")
        rs = [r for r in rows if r["cause"] == cause]
        by_bin = limit(rs, cause, key, 0.95)
        out.append(f"{'':19s}noise units measured on the recording, 95 %: every bin {by_bin}")
        out.append(f"{'':19s}{'':44s}pooled, cases at ≥ X u: {pooled(rs, cause, key=key)}")
    n = nulls(rows, key)
    out.append(
        f"nulls: {n['false_alarms']}/{n['nulls']} false alarms (CI {n['ci95_pct'][0]}-{n['ci95_pct'][1]} %)"
        + (f": {n['named']}" if n["named"] else "")
    )
    out.append("cells: named/cases and the median noise units (torque over J·σv; n/a: not a torque)")
    return "\n".join(out)


def _u(x: float | None) -> str:
    return f"{x:7.3g}" if x is not None and math.isfinite(x) else "    n/a"
