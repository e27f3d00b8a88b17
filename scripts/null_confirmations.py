"""Nulls re-analysed with both confirmation rules logged: every call of the out-of-sample check
(crossval.heldout_gain) and of the drift's windows (drift.window_refits_agree) under the rule
before branch heldout and after; the verdict follows the rule after.

    python scripts/null_confirmations.py ALPHA 'ROWS*.jsonl' RECORDINGS_DIR OUT.jsonl I/N

ROWS: scripts/doctor_nulls.py output rows (plant, profile, σv of each null); ALPHA the decision's
gate (0.01 is the doctor's; larger lets more nulls reach the confirmations). One JSON line per
null: what was named, and `calls` [extra columns, gain before, gain after], `drift`
[parameter, before, after] (the per-window refits are asked only under rules.drift_trend_test off).

The rule before is the design's rules with the switch off (tvsd.analysis.rules), on a copy of the
design: no module flag is set, so nothing is left switched if a call raises.
"""

import dataclasses
import functools
import glob
import json
import math
import sys
from pathlib import Path

from tvsd.analysis import calibrate as C
from tvsd.analysis import crossval as CV
from tvsd.analysis import drift as DF
from tvsd.analysis import matrix as M
from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.matrix_open import _no_gain
from tvsd.config import load_config

_no_gain()
ALPHA = float(sys.argv[1])
src = sys.argv[2]
folder = Path(sys.argv[3])
out = sys.argv[4]
shard, nshard = map(int, sys.argv[5].split("/"))
orig_test = C.test_all
C.test_all = functools.partial(orig_test, alpha=ALPHA)
orig_hg = CV.heldout_gain
calls = []


def switched(design, **off):
    """The design with its rules' switches `off` (a shallow copy: the arrays are shared)."""
    return dataclasses.replace(design, rules=dataclasses.replace(design.rules, **off))


def hg(design, o, X_ext, folds=CV.CV_FOLDS):
    old = orig_hg(switched(design, skip_unpinned_folds=False), o, X_ext, folds)
    new = orig_hg(design, o, X_ext, folds)
    calls.append([X_ext.shape[1] - design.X.shape[1], round(old, 2), round(new, 2)])
    return new


CV.heldout_gain = hg  # verdict and selection call it through the module
orig_da = DF.window_refits_agree
dcalls = []


def da(design, o, parameter, sign):
    old = orig_da(switched(design, drift_pinned_windows=False), o, parameter, sign)
    new = orig_da(design, o, parameter, sign)
    dcalls.append([parameter, old, new])
    return new


DF.window_refits_agree = da
done = set()
if Path(out).exists():
    done = {json.loads(x)["seed"] for x in Path(out).read_text().splitlines()}
rows = [json.loads(x) for f in sorted(glob.glob(src)) for x in Path(f).read_text().splitlines()]
rows = [r for r in rows if r["cause"] == "none"]
cfg0 = load_config()
with open(out, "a") as fo:
    for i, r in enumerate(sorted(rows, key=lambda r: r["seed"])):
        if i % nshard != shard or r["seed"] in done:
            continue
        case = M.Case(
            r["seed"], "none", 0.0, math.nan, None, r["profile"], r["sigma_v"], r["plant"], r.get("rps", 0.0)
        )
        cfg = M.case_config(cfg0, case)
        path = folder / f"{r['profile']}-{r['seed']}.csv"
        if not path.exists():
            cands = list(folder.glob(f"*-{r['seed']}.csv"))
            if not cands:
                continue
            path = cands[0]
        calls.clear()
        dcalls.clear()
        try:
            dg = diagnose(load(path, cfg), cfg.plant.v0)
            found = dg.cause
            top = [[t.cause, round(float(t.z), 2)] for t in dg.outcome.tested[:3]]
            th = round(float(dg.outcome.threshold), 2)
        except Exception as exc:
            found, top, th = f"error: {exc}"[:100], [], None
        fo.write(
            json.dumps(
                {
                    "seed": r["seed"],
                    "profile": r["profile"],
                    "found": found,
                    "top": top,
                    "threshold": th,
                    "calls": list(calls),
                    "drift": list(dcalls),
                }
            )
            + "\n"
        )
        fo.flush()
