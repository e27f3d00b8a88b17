"""Output of tvsctl commands: one JSON object with --json, an aligned table otherwise."""

from __future__ import annotations

import json
import math
import numbers
import sys
from collections.abc import Mapping, Sequence
from typing import Any


def _clean(obj: Any) -> Any:
    """JSON has no NaN/inf: write null, as scripts expect."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if hasattr(obj, "item"):  # numpy scalars
        return _clean(obj.item())
    return obj


def print_json(obj: Mapping[str, Any]) -> None:
    """The one way a command prints its --json answer: one object on one line (the JSON rule of
    tvsd.cli.daemon_cmds: never a bare list or value, never wrapped)."""
    if not isinstance(obj, Mapping):
        raise TypeError(f"--json prints one object, got {type(obj).__name__}: name the list by its command")
    print(json.dumps(_clean(obj), indent=None, sort_keys=False))


def _is_number(value: Any) -> bool:
    """A real number, Python's or numpy's (numpy registers its scalars with `numbers`); a bool,
    either kind, is not one (np.bool_ is not registered, bool is an int)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def fmt(value: Any) -> str:
    if _is_number(value) and not isinstance(value, numbers.Integral):  # float, np.float32, …
        value = float(value)
        if not math.isfinite(value):
            return "—"
        return f"{value:.4g}"
    return str(value)


def print_table(rows: Sequence[Sequence[Any]], headers: Sequence[str] | None = None) -> None:
    # Numbers right-aligned (digits line up), text left-aligned and the line's end not padded:
    # a long text cell (a fault's message) must not push spaces into every other row.
    numeric = [
        bool(rows) and all(_is_number(r[j]) for r in rows)
        for j in range(len(rows[0]) if rows else len(headers or ()))
    ]
    cells = [[fmt(v) for v in r] for r in rows]
    if headers:
        cells.insert(0, list(headers))
    if not cells:
        return
    widths = [max(len(r[j]) for r in cells) for j in range(len(cells[0]))]
    for n, r in enumerate(cells):
        line = "  ".join(
            c.rjust(w) if numeric[j] else c.ljust(w) for j, (c, w) in enumerate(zip(r, widths, strict=True))
        )
        print(line.rstrip())
        if headers and n == 0:
            print("  ".join("-" * w for w in widths))


def print_pairs(pairs: Mapping[str, Any]) -> None:
    """Key, value lines; a list (e.g. of faults) as one indented line per item."""
    width = max((len(k) for k in pairs), default=0)
    for key, value in pairs.items():
        if isinstance(value, list) and value:
            print(key)
            for item in value:
                text = (
                    "  ".join(f"{k}={fmt(v)}" for k, v in item.items())
                    if isinstance(item, Mapping)
                    else fmt(item)
                )
                print(f"  {text}")
        else:
            print(f"{key.ljust(width)}  {fmt(value)}")


def warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)
