"""The daemon's side of the exchange, for the tests that drive an emulated board through McuLink
(tests/test_mcu_stm32.py, tests/test_mcu_avr.py): `from mcu_exchange import Exchange`."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any, TypeVar

import pytest

from tvsd.errors import DeviceError
from tvsd.hw.mcu.link import McuLink, StateSample
from tvsd.sim import emulator

B = TypeVar("B", bound=emulator.EmulatedBoard)


class Exchange:
    """Keeps every state frame and answers the next `answers` of them with a pwm_set of `duty`
    each (the daemon answers every one; a test bounds how many, so a backlog cannot build up).
    With `min_gap_s`, a state that arrives sooner than that after the last answered one (host
    time: states read in one batch) is not answered, so a late event loop sends no burst."""

    def __init__(self, duty: float, min_gap_s: float = 0.0) -> None:
        self.duty = duty
        self.min_gap_s = min_gap_s
        self.states: list[StateSample] = []
        self.answers = 0
        self.link: McuLink | None = None  # set once the link exists: McuLink(..., on_state=exchange)
        self._last = -math.inf

    def __call__(self, s: StateSample) -> None:
        self.states.append(s)
        if self.answers > 0 and self.link is not None and s.host_time - self._last >= self.min_gap_s:
            self.answers -= 1
            self._last = s.host_time
            self.link.send_pwm(self.duty)


async def drained(link: McuLink, timeout_s: float, board: Callable[[], object]) -> None:
    """A round trip: what was sent before it has been handled. On timeout the link's stats and
    `board()` (what the emulator says) go into the failure."""
    try:
        await link.ping(timeout_s=timeout_s)
    except DeviceError as exc:
        raise AssertionError(f"{exc}; link {link.stats()}, board {board()}") from exc


def run_on(board: B, test: Callable[[B], Coroutine[Any, Any, None]]) -> None:
    """Start the emulated board, run `test(board)` on an event loop, stop the board, and check it
    left no process behind."""
    board.start()
    pid = board.pid
    assert pid is not None
    try:
        asyncio.run(test(board))
    finally:
        board.close()
    assert not emulator.pid_alive(pid), f"{type(board).__name__} outlived the test"


def built_image(missing: list[str], what: str, build: Callable[[], Path]) -> Path:
    """The image `build()` makes; the test is skipped, naming the packages, when its toolchain or
    emulator is missing (make test installs them: make system-deps)."""
    if missing:
        pytest.skip(f"{what} missing: {' '.join(missing)}; fix: make system-deps")
    return build()
