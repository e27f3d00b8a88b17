"""Shared-queue runner (2 workers): the same row as scripts/outsider_run.py run, a different order:
outsider nulls (cheapest first), then bench-dev, then the effects (encoder-difference files main
answered none/colored_noise/resonance first). A claim file per item keeps the workers apart."""
import json, os, resource, subprocess, sys, time
from pathlib import Path
sys.path.insert(0, "/work/wt/remeasure/tests")
import outsider_bench as ob
R = Path("/work/wt/remeasure"); D = R / "docs/measurements/remeasure"
TVSCTL = str(R / ".venv/bin/tvsctl")
w = int(sys.argv[1]); claims = Path("/tmp/remeasure/claims"); claims.mkdir(exist_ok=True)
main = {json.loads(x)["name"]: json.loads(x) for f in ("run.w0.jsonl", "run.w1.jsonl") for x in open(f"/work/wt/outsider-main/{f}")}
specs = {ob.draw(*c).name: c for c in ob.plan(7, 2, 30)}
def cost(n): s = main[n]["spec"]; return s["seconds"] * s["fs"]
nulls = sorted((n for n in specs if main[n]["spec"]["cause"] == "none"), key=cost)
eff = [n for n in specs if main[n]["spec"]["cause"] != "none"]
def prio(n):
    s = main[n]["spec"]; enc = s["sensor"]["omega"] != "tach"
    return (0 if enc and main[n]["cause"] in ("none", "colored_noise", "resonance") else 1, cost(n))
queue = [("o", n) for n in nulls] + [("b", f"d{i:02d}") for i in range(13)] + [("o", n) for n in sorted(eff, key=prio)]
for kind, n in queue:
    if kind == "o":
        done = {json.loads(x)["name"] for f in D.glob("outsider.w*.jsonl") for x in f.read_text().splitlines() if x.strip()}
        if n in done: continue
    try: os.close(os.open(claims / f"{kind}{n}", os.O_CREAT | os.O_EXCL))
    except FileExistsError: continue
    path = f"/tmp/remeasure/set/{n}.csv" if kind == "o" else str(R / f"../shared/data/bench-dev/{n}.csv")
    t0, c0 = time.monotonic(), resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run([TVSCTL, "analyze", path, "--json"] + ([] if kind == "o" else ["--quiet"]), capture_output=True, text=True)
    wall, c1 = time.monotonic() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    try: ans = json.loads(p.stdout)
    except json.JSONDecodeError: ans = {"cause": f"exit{p.returncode}", "error": (p.stderr or p.stdout).strip()[-300:]}
    if kind == "o":
        row = {"name": n, "spec": main[n]["spec"], "cause": ans.get("cause"), "effect": ans.get("effect"),
               "causes": [c.get("cause") for c in ans.get("causes", [])],
               "candidates": [(c["cause"], round(c["score"], 2)) for c in ans.get("candidates", [])[:4]],
               "error": ans.get("error"), "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "rc": p.returncode}
        out = D / f"outsider.w{w}.jsonl"
    else:
        row = {"name": n, "rc": p.returncode, "answer": ans, "wall_s": round(wall, 2), "cpu_s": round(cpu, 2)}
        out = D / "bench-dev.jsonl"
    with out.open("a") as fh: fh.write(json.dumps(row) + "\n")
    print(kind, n, "->", row.get("cause") or ans.get("cause"), f"{wall:.1f}s", flush=True)
