"""Which recordings the doctor would read through the encoder instead of their speed column.

    .venv/bin/python scripts/speed_source_scan.py FILE.csv ...

Prints, per file, `encoder` (tvsd.analysis.speed_source.choose replaces the speed) or `kept`,
with the residual ratio (nan: no encoder grid to compare with): only the `encoder` files can
change their verdict.
"""

from __future__ import annotations

import sys
from pathlib import Path

from tvsd.analysis import speed_source
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band
from tvsd.config import load_config


def main(argv: list[str] | None = None) -> int:
    cfg = load_config()
    for name in argv if argv is not None else sys.argv[1:]:
        data = load(Path(name), cfg)
        found = speed_source.compared(data, Band())
        ratio = float("nan") if found is None else found[1]
        switched = found is not None and ratio * speed_source.MARGIN < 1.0
        print(name, "encoder" if switched else "kept", f"{ratio:.3g}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
