"""The drift's before/after per loop and size, by visible units, nulls and other causes (branch drift).

    .venv/bin/python scripts/drift_summary.py [docs/measurements/drift]

Rows re-judged by scripts/drift_rejudge.py replace the stored matrix rows (docs/measurements/
open-matrix/heldout-*, closed-matrix/seed71); the others are copied (their drift z was below the
gate, where neither rule acts). visible.json: scripts/drift_visible.py.
"""

import collections
import glob
import json
import sys

R = sys.argv[1] if len(sys.argv) > 1 else "docs/measurements/drift"
from scipy.stats import beta


def cp(k, n):
    lo = beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    hi = beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return f"{k}/{n} (CI {100 * lo:.1f}-{100 * hi:.1f} %)"


vis = {int(k): v for k, v in json.load(open(R + "/visible.json")).items()}
new = {}
for f in glob.glob(R + "/open.w*.jsonl") + [R + "/closed71.jsonl"]:
    for l in open(f):
        r = json.loads(l)
        new[r["seed"]] = r
D = "docs/measurements/"
srcs = {
    "open": glob.glob(D + "open-matrix/heldout-seed3[134].w*.jsonl")
    + glob.glob(D + "open-matrix/heldout-nulls-seed32.w*.jsonl"),
    "closed": glob.glob(D + "closed-matrix/seed71.w*.jsonl"),
}
out = {}
for loop, fs in srcs.items():
    rows = []
    for f in fs:
        for l in open(f):
            r = json.loads(l)
            if r["seed"] in new:
                n = new[r["seed"]]
                r2 = dict(r, before=n["before"], after=n["ls"], rerun=True)
            else:
                r2 = dict(r, before=r["ls"], after=r["ls"], rerun=False)
            rows.append(r2)
    if loop == "closed":
        for l in (x for f in glob.glob(R + "/nulls72.w*.jsonl") for x in open(f)):
            r = json.loads(l)
            rows.append(dict(r, before=r["ls"], after=r["ls"], rerun=True, fresh=True))
    dr = [r for r in rows if r["cause"] == "drift"]
    print(
        f"== {loop} loop: drift named/n per size (before -> after); re-analysed {sum(r['rerun'] for r in dr)}/{len(dr)}"
    )
    for m in sorted({r["size"] for r in dr}):
        g = [r for r in dr if r["size"] == m]
        b = sum(r["before"] == "drift" for r in g)
        a = sum(r["after"] == "drift" for r in g)
        vv = [r for r in g if vis[r["seed"]]["visible"] >= 1]
        print(
            f"  {m:g}x: {b}/{len(g)} -> {a}/{len(g)};  of those with >= 1 visible unit: {sum(r['before'] == 'drift' for r in vv)}/{len(vv)} -> {sum(r['after'] == 'drift' for r in vv)}/{len(vv)}"
        )
    for lo, hi in [(0, 0.5), (0.5, 1), (1, 2), (2, 4), (4, 1e9)]:
        g = [r for r in dr if lo <= vis[r["seed"]]["visible"] < hi]
        print(
            f"  visible {lo:g}-{hi:g} u: {sum(r['before'] == 'drift' for r in g)}/{len(g)} -> {sum(r['after'] == 'drift' for r in g)}/{len(g)}"
        )
    g = [r for r in dr if vis[r["seed"]]["visible"] >= 1]
    print(
        "  pooled >= 1 visible u, after:",
        cp(sum(r["after"] == "drift" for r in g), len(g)),
        " before:",
        cp(sum(r["before"] == "drift" for r in g), len(g)),
    )
    print(
        "  misses >= 1 u after:",
        [
            (
                r["seed"],
                r["size"],
                r["effect"].split(",")[0][16:],
                r["after"],
                round(vis[r["seed"]]["visible"], 2),
            )
            for r in g
            if r["after"] != "drift"
        ],
    )
    nl = [r for r in rows if r["cause"] == "none"]
    print(
        "  nulls: before",
        cp(sum(r["before"] != "none" for r in nl), len(nl)),
        " after",
        cp(sum(r["after"] != "none" for r in nl), len(nl)),
        "re-analysed",
        sum(r["rerun"] for r in nl),
        collections.Counter(r["after"] for r in nl if r["after"] != "none"),
    )
    oth = [r for r in rows if r["cause"] not in ("none", "drift")]
    ch = [(r["seed"], r["cause"], r["before"], r["after"]) for r in oth if r["before"] != r["after"]]
    print(
        f"  other causes: {len(oth)} cases ({sum(r['rerun'] for r in oth)} re-analysed), naming changed: {len(ch)} {ch}; named drift after: {sum(r['after'] == 'drift' for r in oth)} before: {sum(r['before'] == 'drift' for r in oth)}"
    )
