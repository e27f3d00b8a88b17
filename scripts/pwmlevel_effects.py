"""A fresh family of outsider effects on level-held voltage/duty commands behind a tach
(docs/measurements/pwmlevel.md): draws from seeds `first`…, open loop, kept when the command is
V or duty, a staircase or a PRBS staircase, and ω a tach (everything as drawn).

    .venv/bin/python scripts/pwmlevel_effects.py SET --first 16000 --per-cause 2 --size 20

Writes each case's CSV into SET (if missing) and prints `NAME CAUSE SIZE EXCITATION`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import outsider_bench as ob


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("set", type=Path)
    ap.add_argument("--first", type=int, default=16000)
    ap.add_argument("--per-cause", type=int, default=2)
    ap.add_argument("--size", type=float, default=20.0)
    a = ap.parse_args(argv)
    a.set.mkdir(parents=True, exist_ok=True)
    seed = a.first
    for cause in ob.CAUSES:
        n = 0
        while n < a.per_cause:
            s = ob.draw(seed, cause, a.size, closed=False)
            seed += 1
            if s.unit not in ("V", "duty") or s.excitation == "multisine" or s.sensor["omega"] != "tach":
                continue
            path = a.set / f"{s.name}.csv"
            if not path.exists():
                ob.write(path, s, ob.make(s))
            print(s.name, cause, a.size, s.excitation, flush=True)
            n += 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
