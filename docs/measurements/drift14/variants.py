import copy, json, sys
from pathlib import Path
import numpy as np
sys.path.insert(0, "/work/wt/drift14/tests"); sys.path.insert(0, "/work/wt/drift14/scripts")
import outsider_bench as ob
from drift14_trace import trace

base = ob.draw(14042, "none", 0.0)
print(json.dumps({k: getattr(base, k) for k in ("unit", "fs", "seconds", "excitation")}), base.plant, base.sensor, base.noise, base.drive)
orig_torques = ob._torques
def run(tag, spec, noise_seed=None):
    if noise_seed is not None:
        ob._torques = lambda s, g, k, n: orig_torques(s, np.random.default_rng([noise_seed, 7]), k, n)
    cols = ob.make(spec)
    ob._torques = orig_torques
    p = Path(f"/tmp/d14/var_{tag}.csv")
    ob.write(p, spec, cols)
    r = trace(str(p))
    print(tag, json.dumps({k: r.get(k) for k in ("z", "threshold", "parameter", "heldout")}), json.dumps(r.get("trend")), flush=True)

def var(**kw):
    v = copy.deepcopy(base)
    for k, val in kw.items():
        for d in (v.sensor, v.drive, v.noise, v.plant):
            if k in d:
                d[k] = val; break
        else:
            setattr(v, k, val)
    return v

which = sys.argv[1:]
if "same" in which: run("same", base)
for s in range(1, 5):
    if "noise" in which: run(f"noise{s}", base, noise_seed=s)
if "cpr" in which: run("cpr", var(cpr=4194304))
if "pwm" in which: run("pwm0", var(pwm_bits=0))
if "L" in which: run("L", var(L=base.plant["L"] * 1e-3))
if "lugre" in which: run("stiff", var(sigma0=base.plant["sigma0"] * 100))
if "all" in which: run("all", var(cpr=4194304, pwm_bits=0, L=base.plant["L"] * 1e-3))
