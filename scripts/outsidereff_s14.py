"""Seed 14 (fresh, open loop, 6×/20×) before → after for branch outsidereff.

    .venv/bin/python scripts/outsidereff_s14.py

After = this branch's rows (`outsidereff/s14.after.jsonl`, run before the PWM rule), with the
files the final rule keeps (`outsidereff/s14-scan.txt`: `kept`) read from integ3's rows
(`s14.before.w*.jsonl`, every file the first rule switched): a kept file takes integ3's path.
"""

from __future__ import annotations

import glob
import json
from collections import defaultdict

from scipy.stats import beta


def cp(k: int, n: int) -> str:
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return f"{k}/{n} ({100 * lo:.1f}–{100 * hi:.1f} %)"


D = "docs/measurements/outsidereff/"
after = {r["name"]: r for r in map(json.loads, open(D + "s14.after.jsonl"))}
before = {r["name"]: r for f in glob.glob(D + "s14.before.w*.jsonl") for r in map(json.loads, open(f))}
switched = {line.split()[0].split("/")[-1][:-4] for line in open(D + "s14-scan.txt") if " encoder " in line}
b_ans = {k: before.get(k, r)["cause"] for k, r in after.items()}  # not re-run before: unchanged
f_ans = {k: (r["cause"] if k in switched else b_ans[k]) for k, r in after.items()}
nulls = [k for k, r in after.items() if r["spec"]["cause"] == "none"]
print("open nulls: before", cp(sum(b_ans[k] != "none" for k in nulls), len(nulls)),
      " after", cp(sum(f_ans[k] != "none" for k in nulls), len(nulls)),
      " switched", len(switched & set(nulls)))  # fmt: skip
tab: dict[tuple[str, float], list[int]] = defaultdict(lambda: [0, 0, 0])
for k, r in after.items():
    s = r["spec"]
    if s["cause"] == "none":
        continue
    t = tab[(s["cause"], s["size"])]
    t[0] += 1
    t[1] += b_ans[k] == s["cause"]
    t[2] += f_ans[k] == s["cause"]
    if b_ans[k] != f_ans[k]:
        print(k, s["cause"], s["size"], s["unit"], s["excitation"], b_ans[k], "->", f_ans[k])
tot = [sum(v[i] for v in tab.values()) for i in range(3)]
print("open effects named", f"{tot[1]}/{tot[0]} -> {tot[2]}/{tot[0]}")
for key in sorted(tab):
    print(key, f"{tab[key][1]}/{tab[key][0]} -> {tab[key][2]}/{tab[key][0]}")
for k in nulls:
    if f_ans[k] != "none" or b_ans[k] != "none":
        print("null", k, b_ans[k], "->", f_ans[k], "switched" if k in switched else "kept")
