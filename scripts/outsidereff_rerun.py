"""Re-run outsider cases through tvsd.analysis.speed_source (branch outsidereff).

    nice -n 19 .venv/bin/python scripts/outsidereff_rerun.py LIST TMPDIR OUT.jsonl

LIST: lines "NAME CAUSE SIZE EXCITATION BEFORE" (outsider2's rows). Each case is drawn again
(outsider_bench.draw), written, run through speed_source.choose, and `tvsctl analyze --json` only
where it switched (a kept file takes integ3's path: BEFORE stands). 2 workers.
"""
import json, sys, os
from multiprocessing import Pool
from pathlib import Path
sys.path.insert(0, 'tests'); sys.path.insert(0, 'scripts')
import outsider_bench as ob
from outsider_variants import analyze
from tvsd.analysis import speed_source
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band
from tvsd.config import load_config
OUT = Path(sys.argv[2]); OUT.mkdir(parents=True, exist_ok=True)

def one(line):
    name, cause, size, exc, before = line.split()
    s = ob.draw(int(name.lstrip('o')), cause, float(size))
    path = OUT / f"{name}.csv"
    ob.write(path, s, ob.make(s))
    data = load(path, load_config())
    ch = speed_source.choose(data, Band())
    row = {"name": name, "truth": cause, "size": float(size), "excitation": exc, "before": before,
           "switched": ch is not data, "note": ch.meta.get(speed_source.KEY)}
    if ch is not data:
        r = analyze(path)
        row["after"] = r.get("cause")
        row["top"] = [(c["cause"], round(c["score"], 2)) for c in r.get("candidates", [])[:3]]
    else:
        row["after"] = before
    path.unlink()
    return row

if __name__ == "__main__":
    lines = [l for l in open(sys.argv[1]).read().splitlines() if l.strip()]
    with Pool(2) as p, open(sys.argv[3], "w") as fh:
        for row in p.imap_unordered(one, lines):
            fh.write(json.dumps(row) + "\n"); fh.flush()
