import json, glob, sys
rows = {json.loads(l)["file"]: json.loads(l) for f in sorted(glob.glob(sys.argv[1])) for l in open(f)}
rows = list(rows.values())
def closed(p):
    with open(p) as fh:
        for line in fh:
            if not line.startswith("#"):
                return "omega_ref" in line
for g, pre in {"outsider": "o", "tvsd97": "/tmp/fn"}.items():
    rs = [r for r in rows if (r["file"].split("/")[-1].startswith("o") if g == "outsider" else r["file"].startswith(pre))]
    for kind in ("null", "effect"):
        ks = [r for r in rs if g != "outsider" or ((int(r["file"].split("/")[-1][3:6]) < 80) == (kind == "null"))]
        if g != "outsider" and kind == "effect": continue
        op = [r for r in ks if not closed(r["file"])]
        ab = [r for r in op if r.get("above")]
        print(g, kind, "traced", len(ks), "open loop", len(op), "drift above gate", len(ab),
              "trend passes before", sum(r["before_ok"] for r in ab), "after", sum(r["after_ok"] for r in ab),
              "changed:", [r["file"].split("/")[-1] for r in ab if r["before_ok"] != r["after_ok"]])
