"""The rows of the measurement scripts' outputs: JSON lines, one object a line, from every file a
glob pattern matches (sorted), blank lines skipped."""

from __future__ import annotations

import glob
import json
from pathlib import Path
from typing import Any


def rows(pattern: str) -> list[dict[str, Any]]:
    return [
        json.loads(x)
        for f in sorted(glob.glob(pattern))
        for x in Path(f).read_text().splitlines()
        if x.strip()
    ]
