"""Branch splits3's closed-loop before/after: the closed-loop plan's case 710138 (seed 71, a clip
at 8.4 V, 30×) through matrix_closed's `lsm` and `ls` variants, the path that builds the maps'
blocks as E[f(u) | instruments] (instrument_maps.expected_maps), which no bench-dev file reaches.
Writes matrix_closed's JSONL row to OUT; prints to stderr which tvsd ran and how often
expected_maps did (counted by wrapping instrument.expected_maps here, in this script only).
docs/measurements/splits3.md.

    nice -n 19 .venv/bin/python scripts/splits3_closed_case.py /tmp/after.jsonl
    PYTHONPATH=/tmp/splits3_before nice -n 19 .venv/bin/python \
        scripts/splits3_closed_case.py /tmp/before.jsonl
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import tvsd
from tvsd.analysis import instrument
from tvsd.analysis import matrix_closed as MC
from tvsd.analysis.closed_plan import plan_cells

calls = [0]
inner = instrument.expected_maps


def counted(*a: Any, **k: Any) -> None:
    calls[0] += 1
    inner(*a, **k)


def main() -> None:
    instrument.expected_maps = counted  # the name instrumented() calls, in both trees
    print(tvsd.__file__, file=sys.stderr)
    case = next(c for c in plan_cells(8, (3.0, 10.0, 30.0), 71, 4) if c.seed == 710138)
    MC.run(Path(sys.argv[1]), [case], ("lsm", "ls"), gain=False)
    print(f"expected_maps calls: {calls[0]}", file=sys.stderr)


if __name__ == "__main__":
    main()
