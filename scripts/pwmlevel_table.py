"""Before → after of branch pwmlevel (docs/measurements/pwmlevel.md) from its stored rows.

    .venv/bin/python scripts/pwmlevel_table.py

cases.txt: every outsider case of seeds 12–14 the branch can reach (open loop, V or duty held on
levels, a tach beside an encoder: `scripts/pwmlevel_cases.py`); switched.*.jsonl: those the
encoder now reads, on integ3 (before: the tach), through the encoder without the levels in the
null (outsidereff's measured state) and after; family.*.txt: fresh nulls (seeds 15000+: 24
without the levels, 64 after).
"""

from __future__ import annotations

import json
from pathlib import Path

from scipy.stats import beta

D = Path(__file__).resolve().parent.parent / "docs" / "measurements" / "pwmlevel"


def cp(k: int, n: int) -> str:
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return f"{k}/{n} ({100 * lo:.1f}–{100 * hi:.1f} %)"


def rows(name: str) -> dict[str, dict]:
    return {
        (r := json.loads(line))["name"]: r for line in (D / name).read_text().splitlines() if line.strip()
    }


def main() -> None:
    truth = {
        n: (c, float(m))
        for n, c, m, _ in (line.split() for line in (D / "cases.txt").read_text().splitlines())
    }
    before, nolev, after = (
        rows("switched.before.jsonl"),
        rows("switched.nolevels.jsonl"),
        rows("switched.after.jsonl"),
    )
    nulls = [n for n, (c, _) in truth.items() if c == "none"]
    sw = [n for n in nulls if n in after]
    print(f"level-held V/duty tach nulls, seeds 12-14: {len(nulls)}, read through the encoder now: {len(sw)}")
    for label, got in (("before (integ3: tach)", before), ("encoder, no levels", nolev), ("after", after)):
        k = sum(got[n]["cause"] != "none" for n in sw)
        named = [f"{n} {got[n]['cause']}" for n in sw if got[n]["cause"] != "none"]
        print(f"  {label}: switched nulls named {cp(k, len(sw))}; all {cp(k, len(nulls))}  {named}")
    print("effects read through the encoder now (truth: before | no levels | after):")
    hit = [0, 0, 0]
    eff = [n for n, (c, _) in truth.items() if c != "none" and n in after]
    for n in eff:
        c, m = truth[n]
        got = [before[n]["cause"], nolev[n]["cause"], after[n]["cause"]]
        hit = [h + (g == c) for h, g in zip(hit, got, strict=True)]
        print(f"  {n} {c} {m:g}x: {' | '.join(got)}")
    print(f"  named: before {hit[0]}/{len(eff)}, no levels {hit[1]}/{len(eff)}, after {hit[2]}/{len(eff)}")
    fam = {}
    for label in ("nolevels", "after"):
        # NAME UNIT EXCITATION CAUSE encoder|kept TOP: only the encoder's can change
        lines = [x.split() for x in (D / f"family.{label}.txt").read_text().splitlines()]
        enc = [x for x in lines if x[4] == "encoder"]
        fam[label] = (sum(x[3] != "none" for x in enc), len(enc))
    print(
        "fresh family (seeds 15000+, 8-bit, 8192 counts, tach, 20 s), read through the encoder: "
        f"no levels {cp(*fam['nolevels'])}, after {cp(*fam['after'])}"
    )
    enc = {
        x.split()[0] for x in (D / "family.after.txt").read_text().splitlines() if x.split()[4] == "encoder"
    }
    fb = [r for r in rows("family.before.jsonl").values() if r["name"] in enc]
    named = [f"{r['name']} {r['cause']}" for r in fb if r["cause"] not in ("none", "ERROR")]
    refused = [r["name"] for r in fb if r["cause"] == "ERROR"]
    print(
        f"  the same {len(fb)} on integ3 (tach): named {cp(len(named), len(fb))} {named}, refused {refused}"
    )
    k_sw = sum(after[n]["cause"] != "none" for n in sw) + fam["after"][0]
    k_nl = sum(nolev[n]["cause"] != "none" for n in sw) + fam["nolevels"][0]
    print(
        "pooled, nulls read through the encoder: "
        f"no levels {cp(k_nl, len(sw) + fam['nolevels'][1])}, after {cp(k_sw, len(sw) + fam['after'][1])}"
    )


if __name__ == "__main__":
    main()
