"""Values as an operator reads them: clock times as local ISO time with ms, point flags as words.

The JSON forms keep the raw numbers (`t_unix` seconds, `flags` bits): scripts compute with those.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping
from typing import Any

# tvsd.scan.points.FLAG_NAMES, repeated so that a table needs no numpy import (a test checks they agree).
FLAG_WORDS: dict[int, str] = {1: "vibration", 2: "compensated", 4: "no_imu", 8: "encoder"}


def local_time(t_unix: float) -> str:
    """2026-11-26T08:01:02.345+01:00: this machine's zone, ms, the offset shown."""
    return dt.datetime.fromtimestamp(t_unix).astimezone().isoformat(timespec="milliseconds")


def flag_words(flags: int) -> str:
    """2 → 'compensated', 6 → 'compensated+no_imu', 0 → 'none'; unknown bits as 'bit16'."""
    words = [FLAG_WORDS.get(1 << b, f"bit{1 << b}") for b in range(flags.bit_length()) if flags >> b & 1]
    return "+".join(words) or "none"


def humanize(item: Mapping[str, Any]) -> dict[str, Any]:
    """A copy with clock times and flags for reading (keys named t_unix / *_unix, flags)."""
    out: dict[str, Any] = {}
    for key, value in item.items():
        if (key == "t_unix" or key.endswith("_unix")) and isinstance(value, (int, float)):
            out["time" if key == "t_unix" else key.removesuffix("_unix")] = local_time(float(value))
        elif key == "flags" and isinstance(value, int):
            out[key] = flag_words(value)
        elif isinstance(value, Mapping):
            out[key] = humanize(value)
        elif isinstance(value, list):
            out[key] = [humanize(v) if isinstance(v, Mapping) else v for v in value]
        else:
            out[key] = value
    return out
