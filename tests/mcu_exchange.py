"""The daemon's side of the exchange, for the tests that drive an emulated board through McuLink
(tests/test_mcu_stm32.py, tests/test_mcu_avr.py): the exchange, the identity and watchdog checks
both boards pass."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Awaitable, Callable, Coroutine
from dataclasses import replace
from pathlib import Path
from typing import Any, TypeVar

import pytest
from conftest import until

from tvsd.errors import DeviceError
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import ProtocolSpec
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
        self.link: McuLink | None = None  # open_link
        self._last = -math.inf

    def open_link(self, settings: McuSettings) -> McuLink:
        """The link to the board (not started) whose state frames come here."""
        self.link = McuLink(settings, on_state=self)
        return self.link

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


def check_identity(
    link: McuLink, spec: ProtocolSpec, settings: McuSettings, board: str, clock_hz: int, other: str
) -> None:
    """The board identified itself as `board` at `clock_hz` speaking this tvsd's protocol, and the
    host's settings accept it for `board` and name the fix when they say `other`."""
    ident = link.identity
    assert ident is not None
    board_id = {v: k for k, v in spec.boards.items()}[board]
    assert (ident.board, ident.clock_hz, ident.proto_version) == (board_id, clock_hz, spec.version)
    reported = spec.boards[ident.board]
    assert replace(settings, board=board).board_problem(reported) is None
    assert f"set mcu.board: {board}" in str(replace(settings, board=other).board_problem(reported))


async def check_watchdog_cut(
    link: McuLink,
    settings: McuSettings,
    duty: float,
    *,
    state_div: int,
    timeout_s: float,
    drained: Callable[[], Awaitable[None]],
    outputs_cut: Callable[[], Awaitable[None]],
    pwm_on: Callable[[], Awaitable[None]],
) -> None:
    """Heartbeats stop: the board's watchdog cuts PWM and laser (`outputs_cut` checks the pins)
    and says so, refuses PWM until a heartbeat arms it again, then drives `duty` again (`pwm_on`)."""
    link.send_config(watchdog_ms=settings.watchdog_ms, state_div=state_div, max_on_ms=0)
    await drained()
    await link.stop_heartbeat()
    await until(
        lambda: list(link.faults),
        timeout_s,
        "watchdog_expired",
        ok=lambda f: f and f[-1].name == "watchdog_expired",
    )
    assert link.faults[-1].detail == settings.watchdog_ms
    await outputs_cut()
    # and refuses PWM until a heartbeat arms it again
    link.send_pwm(duty)
    await until(
        lambda: list(link.refusals),
        timeout_s,
        "a refused pwm_set",
        ok=lambda r: r and r[-1].name == "pwm_set",
    )
    assert "heartbeat" in link.refusals[-1].reason
    await outputs_cut()
    await drained()  # arms it
    link.start_heartbeat()
    link.send_pwm(duty)
    link.send_config(watchdog_ms=settings.watchdog_ms, state_div=0, max_on_ms=0)
    await drained()
    await pwm_on()
