"""The closed-loop matrix's confusion table: per true cause and size, what the doctor named.

    python -m tvsd.analysis.matrix_closed 'OUT*.jsonl' --confusion [--variant ls]

Rows are the cases of tvsd.analysis.matrix_closed (JSON lines). A case's size is stated in noise
units (torque over J·σv), measured on its recording where tvsd.analysis.exposure can (`seen`),
else the generator's; a dead zone, a clip or friction asymmetry also shows the share of samples
where the effect acts (what the test can see of it), and why the doctor said what it said (the
true cause's z against the threshold, a mismatch's reason). The limit is the lowest noise-unit
bin from which every bin with cases is named at ≥ 90 % (≥ 95 %), with the rate over all cases
from there up and its 95 % Clopper–Pearson interval.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from typing import Any

import numpy as np

BINS = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, math.inf)


def units(r: dict[str, Any]) -> float:
    """The effect's size as the recording shows it: a drift as refits over time see it
    (exposure.py's `visible`), a dead zone as the part of its torque a Coulomb level cannot take
    (`exposed_units`), where the row has them."""
    seen = r.get("seen") or {}
    u = seen.get("visible", seen.get("exposed_units", seen.get("units")))
    u = r["noise_units"] if u is None else u
    return float(u) if u is not None and math.isfinite(float(u)) else math.nan


def _bin(u: float) -> int:
    return next(k for k in range(len(BINS) - 1) if u < BINS[k + 1]) if math.isfinite(u) else -1


def _label(k: int) -> str:
    if k < 0:
        return "n/a"
    hi = BINS[k + 1]
    return f"{BINS[k]:g}-{hi:g}" if math.isfinite(hi) else f"≥{BINS[k]:g}"


def limit(rs: list[dict[str, Any]], cause: str, variant: str, rate: float) -> str:
    from tvsd.analysis.matrix import clopper_pearson

    by: dict[int, list[bool]] = defaultdict(list)
    for r in rs:
        by[_bin(units(r))].append(r[variant] == cause)
    ks = sorted(k for k in by if k >= 0)
    for k in ks:
        above = [k2 for k2 in ks if k2 >= k]
        if all(np.mean(by[k2]) >= rate for k2 in above):
            hits = sum(sum(by[k2]) for k2 in above)
            n = sum(len(by[k2]) for k2 in above)
            lo, hi = clopper_pearson(hits, n)
            return f"from {BINS[k]:g}u: {hits}/{n} (CI {100 * lo:.0f}-{100 * hi:.0f} %)"
    top = max(units(r) for r in rs) if rs else math.nan
    return f"not reached up to {top:.3g}u"


def table(rows: list[dict[str, Any]], variant: str) -> str:
    rows = [r for r in rows if variant in r]
    out = [f"variant {variant}: {len(rows)} cases"]
    by_cause: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        by_cause[r["cause"]].append(r)
    head = f"{'cause':19s} {'size':>5s} {'units':>11s} {'n':>3s} {'named':>5s} {'share':>6s}"
    out.append(head + "  named instead (z of the true cause / threshold)")
    for cause in sorted(by_cause, key=lambda c: (c != "none", c)):
        rs = by_cause[cause]
        groups: dict[tuple[float, int], list[dict[str, Any]]] = defaultdict(list)
        for r in rs:
            groups[(r["size"], _bin(units(r)))].append(r)
        for (size, k), g in sorted(groups.items()):
            truth = "none" if cause == "none" else cause
            ok = sum(r[variant] == truth for r in g)
            shares = [r.get("seen", {}).get("share") for r in g]
            share = (
                f"{np.median([s for s in shares if s is not None]):6.3f}"
                if any(s is not None for s in shares)
                else "     -"
            )
            wrong = Counter(str(r[variant])[:30] for r in g if r[variant] != truth)
            zs = [r.get(f"{variant}_why", {}).get("z", {}).get(cause) for r in g if r[variant] != truth]
            thr = [r.get(f"{variant}_why", {}).get("threshold") for r in g if r[variant] != truth]
            zt = ", ".join(
                f"{z:.1f}/{t:.1f}" for z, t in zip(zs, thr, strict=True) if z is not None and t is not None
            )
            detail = ", ".join(f"{c} {n}" for c, n in wrong.most_common()) + (f"  (z {zt})" if zt else "")
            out.append(f"{cause:19s} {size:5g}x {_label(k):>11s} {len(g):3d} {ok:5d} {share}  {detail}")
        if cause != "none":
            out.append(
                f"{'':19s} 90 %: {limit(rs, cause, variant, 0.9)}; 95 %: {limit(rs, cause, variant, 0.95)}"
            )
    names = sorted({str(r[variant])[:14] for r in rows} | set(by_cause))
    out.append("")
    out.append("confusion (rows: true cause, columns: named), all sizes")
    out.append(f"{'':19s}" + "".join(f"{n[:9]:>10s}" for n in names))
    for cause in sorted(by_cause, key=lambda c: (c != "none", c)):
        cnt = Counter(str(r[variant])[:14] for r in by_cause[cause])
        out.append(f"{cause:19s}" + "".join(f"{cnt.get(n, 0):10d}" for n in names))
    return "\n".join(out)
