"""argparse types for numbers the commands pass on to numpy, numba and the simulator.

Why: `int`/`float` alone let through what those cannot take — a negative seed (numpy's
SeedSequence: "expected non-negative integer", exit 70 "internal error"), a seed past int64 (a numba
TypingError), NaN or 1e308 (a NaN table with exit 0, an OverflowError). These refuse them at the
command line: the usage and one line naming the option's range, exit 2 (EXIT_USAGE).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

SEED_MAX = 2**53  # the daemon's bound for an integer parameter (README "Daemon API limits")


def seed(text: str) -> int:
    """A random seed: a whole number 0..2**53."""
    try:
        n = int(text)
    except ValueError:
        n = -1
    if not 0 <= n <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"expected a seed 0..2**53 (a whole number), got {text!r}")
    return n


def number(low: float, high: float, unit: str = "", *, low_open: bool = False) -> Callable[[str], float]:
    """A finite number in [low, high] (or (low, high] with `low_open`), else one line with the range."""
    bracket = "(" if low_open else "["
    span = f"{bracket}{low:g}, {high:g}]" + (f" {unit}" if unit else "")

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            x = math.nan
        inside = (low < x if low_open else low <= x) and x <= high
        if not (math.isfinite(x) and inside):
            raise argparse.ArgumentTypeError(f"expected a number in {span}, got {text!r}")
        return x

    return parse


def seconds(text: str) -> float:
    """A time in seconds on a recording's t column: any finite number (t may start anywhere)."""
    try:
        x = float(text)
    except ValueError:
        x = math.nan
    if not math.isfinite(x):
        raise argparse.ArgumentTypeError(
            f"expected seconds of the recording's t column (a finite number, e.g. 5 or 2.5), got {text!r}"
        )
    return x


def count(low: int, high: int, what: str) -> Callable[[str], int]:
    """A whole number in [low, high]."""

    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            n = low - 1
        if not low <= n <= high:
            raise argparse.ArgumentTypeError(f"expected {what} {low}..{high}, got {text!r}")
        return n

    return parse
