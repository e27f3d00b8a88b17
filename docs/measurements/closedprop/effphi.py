import sys, time
from pathlib import Path
from tvsd.analysis import matrix
from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.matrix_open import heldout_gain_skipped
from tvsd.causes import parse_effect
from tvsd.config import load_config
from tvsd.recording.csvfile import read, write
from tvsd.sim.record import record
from tvsd.analysis.closed_plan import sized
out = Path("/tmp/cp/eff")
pool = matrix.cases(n_null=0, reps=1, seed=0, causes=tuple(sys.argv[1].split(",")), profiles=matrix.CLOSED_PROFILES)
for c in pool:
    if c.size != float(sys.argv[2]):
        continue
    cfg = matrix.case_config(load_config(), c)
    c = sized(c, cfg, out, 30.0)
    p = out / f"{c.cause}-{c.seed}.csv"
    if not p.exists():
        record(cfg, p, c.profile, 30.0, (parse_effect(c.effect),), c.seed, rps=c.rps)
    rec = read(p)
    q = out / f"phi-{p.name}"
    write(q, rec.t, rec.u, rec.omega, rec.phi, rec.sample_rate_hz,
          {k: v for k, v in rec.meta.items() if k not in ("tvs-recording", "sample_rate_hz")},
          {k: v for k, v in rec.extra.items() if k != "omega_ref"})
    for f in (p, q):
        t0 = time.time()
        with heldout_gain_skipped():
            dg = diagnose(load(f, cfg), cfg.plant.v0)
        print(f.name, c.effect, dg.cause, [(s.cause, round(s.z, 1)) for s in dg.ranked[:3]], round(time.time() - t0, 1), flush=True)
