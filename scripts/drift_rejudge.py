"""Re-judge stored matrix cases on the drift's trend test (after) and on the per-window refits
before it (rules.drift_trend_test False), from their cached recordings (branch drift).

    nice -n 5 .venv/bin/python scripts/drift_rejudge.py W/NW OUT.wW.jsonl LIST.json

LIST: [[rows_glob, seed, recording_path], ...] (the stored matrix rows give the case). Each row:
the case, `stored` (the stored answer), `ls`/`ls_why` (after), `before`/`before_why`, and
`drift_trace` (both rules' verdict on the drift candidate and the trend test's figures; empty when
the drift's z did not pass the gate, where the rule does not act). Diagnosed once; again with the
old rule only where the two rules disagree. A restart skips seeds already in OUT's sibling files.
"""

import dataclasses
import glob
import json
import sys
from pathlib import Path

from tvsd.analysis import drift as DF
from tvsd.analysis import matrix as M
from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.matrix_open import _no_gain
from tvsd.analysis.rules import DEFAULT
from tvsd.config import load_config

_no_gain()
FIELDS = ("seed", "cause", "size", "noise_units", "effect", "profile", "sigma_v", "plant", "rps")
w, nw = map(int, sys.argv[1].split("/"))
out = Path(sys.argv[2])
todo = json.load(open(sys.argv[3]))[w::nw]
done = {
    json.loads(x)["seed"]
    for f in out.parent.glob(out.name.split(".w")[0] + ".w*.jsonl")
    for x in f.read_text().splitlines()
}
done |= {json.loads(x)["seed"] for x in out.read_text().splitlines()} if out.exists() else set()
rows = {}
for src in {t[0] for t in todo}:
    for f in glob.glob(src):
        for l in open(f):
            r = json.loads(l)
            rows[r["seed"]] = r
trace = {}
orig = DF.confirmed


def both(design, o, parameter, sign, alone=False):
    new = DF.agrees(design, o, parameter, sign)
    old = DF.window_refits_agree(design, o, parameter, sign)
    trace.update(new=new.agrees, old=bool(old), trend=new.as_dict(), parameter=parameter)
    return new.agrees if design.rules.drift_trend_test else bool(old)


DF.confirmed = both


def run(data, cfg, rules=DEFAULT):
    trace.clear()
    dg = diagnose(data, cfg.plant.v0, rules=rules)
    why = {
        "z": {s.cause: round(float(s.z), 3) for s in dg.ranked},
        "threshold": round(float(dg.outcome.threshold), 3),
        "reason": dg.reason,
        "why_not": {s.cause: (s.why_not[0] if s.why_not else None) for s in dg.ranked},
    }
    return dg.cause, why, dict(trace)


for src, seed, path in todo:
    if seed in done:
        continue
    r = rows[seed]
    case = M.Case(**{k: r[k] for k in FIELDS})
    if case.profile == "identify":
        from tvsd.analysis.closed_plan import case_config

        cfg = case_config(case)
    else:
        cfg = M.case_config(load_config(), case)
    data = load(Path(path), cfg)
    row = {k: r[k] for k in FIELDS}
    row["seen"] = r.get("seen")
    row["stored"] = r["ls"]
    row["ls"], row["ls_why"], tr = run(data, cfg)
    row["drift_trace"] = tr
    if tr and tr["new"] != tr["old"]:
        before = dataclasses.replace(DEFAULT, drift_trend_test=False)
        row["before"], row["before_why"], _ = run(data, cfg, before)
    else:
        row["before"], row["before_why"] = row["ls"], row["ls_why"]
    with out.open("a") as f:
        f.write(json.dumps(row, default=float) + "\n")
    print(seed, r["cause"], r["size"], "before", row["before"], "after", row["ls"], flush=True)
