"""The merged integ3 (four branches) on the lead's seed-91 closed nulls, against the lead's verdicts
(integ3 at e938591) and each branch's own rows: how many nulls name a cause, and which answers moved.

    nice -n 19 .venv/bin/python scripts/review5_nulls_summary.py
"""

from __future__ import annotations

import json
from pathlib import Path

from tvsd.analysis.matrix import clopper_pearson

ROOT = Path(__file__).resolve().parents[1]
M = ROOT / "docs/measurements"
LEAD = Path("/work/wt/nulls91/out")


def rows(paths: list[Path]) -> list[dict]:
    return [json.loads(x) for p in paths for x in p.read_text().splitlines() if x.strip()]


def rate(k: int, n: int) -> str:
    lo, hi = clopper_pearson(k, n)
    return f"{k}/{n} = {100 * k / max(n, 1):.2f} % (95 % CI {100 * lo:.2f}–{100 * hi:.2f} %)"


def main() -> None:
    lead = {r["seed"]: r["found"] for r in rows(sorted(LEAD.glob("closed91.w*.jsonl")))}
    after = {r["seed"]: r["on"]["causes"] for r in rows(sorted((M / "review5").glob("nulls91.w*.jsonl")))}
    colour = {r["seed"]: r["on"]["causes"] for r in rows([M / "closedcolour2/nulls91.jsonl"])}
    drift = {r["seed"]: r["lsdp"]["found"] for r in rows(sorted((M / "closeddrift2").glob("n91.w*.jsonl")))}
    seeds = sorted(s for s in after if s in lead)
    n = len(seeds)
    print("merged integ3 (rule defaults):", rate(sum(bool(after[s]) for s in seeds), n))
    print("lead, integ3 at e938591:       ", rate(sum(lead[s] != "none" for s in seeds), n))
    named: dict[str, int] = {}
    for s in seeds:
        for c in after[s]:
            named[c] = named.get(c, 0) + 1
    print("causes named after:", named)
    for s in seeds:
        now = after[s][0] if after[s] else "none"
        if now != lead[s]:
            c = colour.get(s)
            branch = "-" if c is None else (c[0] if c else "none")
            print(
                f"  {s}: lead {lead[s]} -> merged {now} {after[s]}; closedcolour2 branch {branch}, "
                f"closeddrift2 branch {drift.get(s, '-')}"
            )


if __name__ == "__main__":
    main()
