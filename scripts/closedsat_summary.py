"""Closed-loop saturation and drift: the tables of docs/measurements/closedsat.md (branch closedsat).

    .venv/bin/python scripts/closedsat_summary.py [docs/measurements/closedsat]

Reads the rows of `python -m tvsd.analysis.matrix_closed` in that folder: sat71.jsonl (seed 71's
24 clips; ls = the default, lsm = the rule before on the first 14, lss on the last 10),
sat71-lss.jsonl (lss on the refused ones of the first 14), nulls76*.jsonl (fresh nulls, ls). Units: tvsd.analysis.confusion.units (a clip's and a dead zone's
`exposed_units`, a drift's `visible`, measured on the recording).
"""

from __future__ import annotations

import glob
import json
import math
import sys
from collections import Counter
from typing import Any

from tvsd.analysis.confusion import units
from tvsd.analysis.matrix import clopper_pearson

D = sys.argv[1] if len(sys.argv) > 1 else "docs/measurements/closedsat"


def rows(pattern: str) -> list[dict[str, Any]]:
    return [json.loads(line) for f in sorted(glob.glob(f"{D}/{pattern}")) for line in open(f) if line.strip()]


def cp(k: int, n: int) -> str:
    lo, hi = clopper_pearson(k, n)
    return f"{k}/{n} (95 % CI {100 * lo:.1f}-{100 * hi:.1f} %)"


def per_size(rs: list[dict[str, Any]], cause: str, variants: tuple[str, ...]) -> None:
    sizes = sorted({r["size"] for r in rs})
    print(f"{cause}: named per size (median units of the cell)")
    for v in variants:
        cells = []
        for m in sizes:
            g = [r for r in rs if r["size"] == m and v in r]
            med = sorted(units(r) for r in g)[len(g) // 2] if g else math.nan
            cells.append(f"{m:g}x {sum(r[v] == cause for r in g)}/{len(g)} ({med:.3g})")
        print(f"  {v:4s} " + "  ".join(cells))
    for v in variants:
        for x in (1.0, 2.0, 4.0, 8.0, 16.0):
            above = [r for r in rs if v in r and units(r) >= x]
            hits = sum(r[v] == cause for r in above)
            print(f"  {v:4s} from {x:g} u: {cp(hits, len(above)) if above else '-'}")
    print(f"  misses ({variants[0]}): units, z, gate, why")
    for r in sorted(rs, key=units):
        v = variants[0]
        if r.get(v) != cause:
            w = r.get(f"{v}_why", {})
            print(
                f"    {r['seed']} {r['size']:g}x σv {r['sigma_v']} {units(r):.2f} u share "
                f"{(r.get('seen') or {}).get('share', '')} z {w.get('z', {}).get(cause)} "
                f"gate {w.get('threshold')} {w.get('why_not', {}).get(cause)} -> {r.get(v)}"
                + "".join(f" | {o}: {r[o]}" for o in variants[1:] if o in r)
            )


def nulls(rs: list[dict[str, Any]]) -> None:
    if not rs:
        return
    fa = [r for r in rs if r["ls"] != "none"]
    print(f"nulls (ls): false alarms {cp(len(fa), len(rs))}: {dict(Counter(r['ls'] for r in fa))}")
    for cause in ("saturation", "drift", "deadzone", "delay"):
        up = [r for r in rs if r["ls_why"]["z"].get(cause, -9) > r["ls_why"]["threshold"]]
        named = sum(r["ls"] == cause for r in up)
        whys = Counter(r["ls_why"].get("why_not", {}).get(cause) for r in up)
        print(f"  {cause} above the gate on {len(up)}: named {named}; refused by {dict(whys)}")
    for v in ("lsm", "lsd"):
        both = [r for r in rs if v in r]
        if both:
            diff = [(r["seed"], r["ls"], r[v]) for r in both if r[v] != r["ls"]]
            print(f"  re-judged with {v}: {len(both)}, answers differing from ls: {diff}")


def saturation() -> list[dict[str, Any]]:
    """sat71's rows with `lss` from sat71-lss merged in, and `before`: main's rule as stored by
    branch cldz on the same recordings (cldz/seed71.jsonl's `ls`)."""
    rs = {r["seed"]: r for r in rows("sat71.jsonl")}
    for r in rows("sat71-lss.jsonl"):
        rs[r["seed"]].update({k: v for k, v in r.items() if k.startswith("lss")})
    before = {r["seed"]: r for r in rows("../cldz/seed71.jsonl")}
    for seed, r in rs.items():
        r["before"], r["before_why"] = before[seed]["ls"], before[seed]["ls_why"]
    return list(rs.values())


def unique(rs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return list({r["seed"]: r for r in rs}.values())


if __name__ == "__main__":
    per_size(saturation(), "saturation", ("ls", "before", "lsm", "lss"))
    nulls(unique(rows("nulls76*.jsonl")))
