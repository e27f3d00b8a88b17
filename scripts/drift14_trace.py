"""Trace the open-loop drift decision on recordings (branch drift14): the drift block's z and the
gate, the windows' trend test (before: at 5 %/3; after: in open loop also t at the decision's
1 %/3, drift.accepted), and the held-out folds' gain of the drift block. An answer can change
only where the drift is above the gate and its trend agrees before but not after.

    nice -n 19 .venv/bin/python scripts/drift14_trace.py [--shard=W/N] FILE.csv [...] > OUT.jsonl
"""

import json
import sys

import numpy as np

from tvsd.analysis import absorber, crossval, drift, speed_source
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, prepare
from tvsd.config import load_config


def trace(path: str) -> dict[str, object]:
    data = load(path, load_config())
    band = Band()
    data = speed_source.choose(data, band)
    prep = prepare(data, band)
    design = absorber.absorb(D.build(prep, data.offset_term, data.units.axis == "rotary"))
    design.back_emf = data.b_omega > 0 or data.u_unit == "V"
    out = C.test_all(design)
    row: dict[str, object] = {"file": path, "threshold": round(out.threshold, 3)}
    for t in out.tested:
        if t.cause != "drift":
            continue
        par = str(t.option.effect["parameter"])
        tr = drift.agrees(design, out, par, float(t.coef[0]))
        X_cv = np.column_stack([design.X, t.option.block])
        row.update(
            z=round(t.z, 3),
            parameter=par,
            coef=float(t.coef[0]),
            trend=tr.as_dict(),
            above=bool(t.z > out.threshold),
            before_ok=bool(tr.agrees),
            after_ok=drift.accepted(tr, alone=True),
            est=[round(float(e), 6) for e in tr.est],
            se=[round(float(s), 6) for s in tr.se],
            heldout=round(crossval.heldout_gain(design, out, X_cv), 2),
        )
    return row


if __name__ == "__main__":
    args = sys.argv[1:]
    shard = args.pop(0)[len("--shard=") :] if args and args[0].startswith("--shard=") else "0/1"
    w, nw = map(int, shard.split("/"))
    for k, p in enumerate(args):
        if k % nw == w:
            print(json.dumps(trace(p)), flush=True)
