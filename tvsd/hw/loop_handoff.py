"""Items from a device thread to the asyncio loop's thread: no lock, one wake-up per burst.

The MCU link's I/O thread (its events) and the IMU reader (its batches) hand work to the event
loop this way. deque append/popleft are atomic, so the device thread never waits on the loop; a
``call_soon_threadsafe`` is a write to the loop's self-pipe and a turn of the loop, so there is
one per burst, not one per item. Each turn hands over the items queued when it began: later ones
have their own wake-up, and the loop's other callbacks keep their turn.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from collections.abc import Callable
from typing import Generic, TypeVar

log = logging.getLogger(__name__)
T = TypeVar("T")


class LoopHandoff(Generic[T]):
    """`put` on the device thread; `deliver(item)` runs on the loop's thread, in order."""

    def __init__(self, deliver: Callable[[T], None], what: str) -> None:
        self._deliver = deliver
        self._what = what  # for the log line of a failing handler
        self._items: deque[T] = deque()
        self._wake_pending = False
        self.loop: asyncio.AbstractEventLoop | None = None  # set before the device thread starts

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        self._items.clear()

    def put(self, item: T) -> None:
        """On the device thread; never raises, never waits."""
        self._items.append(item)
        loop = self.loop
        if not self._wake_pending and loop is not None:
            self._wake_pending = True
            with contextlib.suppress(RuntimeError):  # the loop closed under a stopping thread
                loop.call_soon_threadsafe(self._run)

    def _run(self) -> None:
        self._wake_pending = False  # first: an item queued from here on wakes the loop again
        items = self._items
        for _ in range(len(items)):
            item = items.popleft()
            try:
                self._deliver(item)
            except Exception:  # a consumer's bug must not stop the others
                log.exception("%s: handler failed for %r", self._what, item)
