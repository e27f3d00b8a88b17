"""Compare matrix rows before/after, timings (keys ending in _s) left out: byte equality of the rest."""
import json, sys
def load(f):
    out = {}
    for l in open(f):
        r = json.loads(l)
        out[r["seed"]] = json.dumps({k: v for k, v in r.items() if not k.endswith("_s")})
    return out
a, b = load(sys.argv[1]), load(sys.argv[2])
for s in sorted(set(a) | set(b)):
    print(s, "identical" if a.get(s) == b.get(s) else "DIFFERS", json.loads(a[s])["ls"], json.loads(a[s])["ls0"])
