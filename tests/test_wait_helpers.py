"""The shared wait helpers (conftest): they return what they waited for, and a timeout names what
was awaited and the last value seen, so a failing daemon test says where it stood."""

from __future__ import annotations

import asyncio
import itertools

import pytest
from conftest import until, wait_for


def test_wait_for_returns_the_value_that_met_the_condition() -> None:
    counter = itertools.count()
    assert wait_for(lambda: next(counter), 5.0, "3", ok=lambda n: n >= 3, interval=0) == 3


def test_a_timeout_names_what_and_the_last_value_seen() -> None:
    with pytest.raises(AssertionError, match=r"after 0.05 s waiting for the moon \(last seen: 42\)"):
        wait_for(lambda: 42, 0.05, "the moon", ok=lambda v: v > 100)


def test_without_a_name_the_waiting_line_is_quoted() -> None:
    with pytest.raises(AssertionError, match="lambda: 0"):
        wait_for(lambda: 0, 0.02)


def test_abort_fails_at_once_with_its_reason() -> None:
    with pytest.raises(AssertionError, match=r"gave up waiting for spin: safe state \(last seen: 'fault'\)"):
        wait_for(lambda: "fault", 60.0, "spin", ok=lambda s: s == "idle", abort=lambda s: "safe state")


def test_until_polls_on_the_event_loop() -> None:
    async def main() -> None:
        flag: list[int] = []
        asyncio.get_running_loop().call_later(0.01, flag.append, 1)
        assert await until(lambda: flag, 5.0, "the callback") >= 0.0
        with pytest.raises(AssertionError, match=r"waiting for never \(last seen: \[\]\)"):
            await until(lambda: [], 0.02, "never")

    asyncio.run(main())
