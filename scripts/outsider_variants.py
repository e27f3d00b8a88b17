"""One outsider case drawn again with one thing changed, each through `tvsctl analyze --json`.

    nice -n 19 .venv/bin/python scripts/outsider_variants.py o12067 [--out DIR] \
        [--set cpr=4194304 --set omega=tach --set pwm_bits=0 --set declare_cpr=0 ...]

Each `--set KEY=VALUE` is one variant (the case itself is always run first): KEY is a field of
the spec's sensor, drive, noise or plant dict (or `cause`/`fs`/`seconds`), VALUE a number or a
word; `a=1,b=2` changes two things in one variant. Prints the answer, the colour's p and τ, the
top candidates, the quantisation floor's crossing and the band the colour test saw.
"""

from __future__ import annotations

import argparse
import copy
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import outsider_bench as ob

TVSCTL = str(Path(sys.executable).parent / "tvsctl")


def _value(v: str) -> Any:
    for t in (int, float):
        try:
            return t(v)
        except ValueError:
            pass
    return v


def variant(s: ob.Spec, change: str) -> ob.Spec:
    v = copy.deepcopy(s)
    for kv in filter(None, change.split(",")):
        k, val = kv.split("=", 1)
        for d in (v.sensor, v.drive, v.noise, v.plant):
            if k in d:
                d[k] = _value(val)
                break
        else:
            setattr(v, k, _value(val))
    return v


def analyze(path: Path) -> dict[str, Any]:
    p = subprocess.run([TVSCTL, "analyze", str(path), "--json"], capture_output=True, text=True)
    try:
        return json.loads(p.stdout)
    except json.JSONDecodeError:
        return {"cause": f"exit{p.returncode}", "error": (p.stderr or p.stdout).strip()[-200:]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("case", help="oSSSKK: the case seed (seed·1000 + index) after the 'o'")
    ap.add_argument("--cause", default=None, help="the case's cause and size, e.g. delay:20 (default none)")
    ap.add_argument("--set", dest="changes", action="append", default=[])
    ap.add_argument("--out", type=Path, default=Path("/tmp/outsider_variants"))
    a = ap.parse_args(argv)
    cause, size = (a.cause.split(":")[0], float(a.cause.split(":")[1])) if a.cause else ("none", 0.0)
    s = ob.draw(int(a.case.lstrip("o")), cause, size)
    a.out.mkdir(parents=True, exist_ok=True)
    for change in ["", *a.changes]:
        v = variant(s, change)
        path = a.out / f"{s.name}{'-' + change.replace('=', '').replace(',', '-') if change else ''}.csv"
        ob.write(path, v, ob.make(v))
        r = analyze(path)
        nz = r.get("noise") or {}
        top = [(c["cause"], round(c["score"], 2)) for c in r.get("candidates", [])[:3]]
        row = {"variant": change or "as drawn", "cause": r.get("cause"), "effect": r.get("effect"),
               "colour_p": nz.get("colour_p"), "floor_hz": nz.get("quantisation_floor_hz"),
               "band": nz.get("band_tested_hz"), "top": top}  # fmt: skip
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
