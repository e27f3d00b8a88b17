"""exposure()'s drift measures (units, visible) of the stored matrices' drift cases, from their cached
recordings (/tmp/ol/cache*, /tmp/closedlim/cache71) into docs/measurements/drift/visible.json."""

import glob
import json
from pathlib import Path

import numpy as np

from tvsd.analysis import matrix as M
from tvsd.analysis.dataset import load
from tvsd.analysis.exposure import exposure
from tvsd.config import load_config

FIELDS = ("seed", "cause", "size", "noise_units", "effect", "profile", "sigma_v", "plant", "rps")
out = {}
caches = {31: "/tmp/ol/cache", 33: "/tmp/ol/cache33", 34: "/tmp/ol/cache34"}
for pat in [
    "docs/measurements/open-matrix/heldout-seed3[134].w*.jsonl",
    "docs/measurements/closed-matrix/seed71.w*.jsonl",
]:
    for f in sorted(glob.glob(pat)):
        for l in open(f):
            r = json.loads(l)
            if r["cause"] != "drift":
                continue
            case = M.Case(**{k: r[k] for k in FIELDS})
            if case.profile == "identify":
                from tvsd.analysis.closed_plan import case_config

                cfg = case_config(case)
                p = f"/tmp/closedlim/cache71/case{case.seed}.csv"
            else:
                cfg = M.case_config(load_config(), case)
                p = f"{caches[case.seed // 10000]}/{case.profile}-{case.seed}.csv"
            d = load(Path(p), cfg)
            w = d.speed if d.speed is not None else np.gradient(d.position, d.t)
            out[case.seed] = exposure(case.effect, d.u, w, cfg.plant, case.sigma_v, 1.0 / d.sample_rate_hz)
json.dump(out, open("docs/measurements/drift/visible.json", "w"))
print(len(out))
