"""Whether a tty's kernel side still holds input for us, asked without blocking the asker.

A poll of a tty that finds no input waits for the kernel's tty flip-buffer work (``n_tty_poll`` ->
``tty_buffer_flush_work``), a normal-priority kworker, and that work is queued only when bytes
were pushed into the flip buffer. So a zero-timeout ``select`` that blocks means bytes are on their
way (the link is alive; the CPU load keeps the worker off), one that returns at once with nothing
means none are: the link is silent. The MCU link's I/O thread must not make that wait itself when
it owns the heartbeat (the wait is unbounded: 100-215 ms measured under CPU load), so this thread
makes it and wakes the I/O thread with the answer (tvsd.hw.mcu.io_thread, the loss check).
"""

from __future__ import annotations

import math
import select
import threading
import time
from collections.abc import Callable


class TtyProbe:
    """One probe at a time on its own thread; ``wake()`` is called when an answer is ready."""

    def __init__(self, wake: Callable[[], None]) -> None:
        self._wake = wake
        self._fd: int | None = None
        self._request = threading.Event()
        self._stop = False
        self._busy = False
        self._answer: bool | None = None
        self._asked_at = -math.inf
        self._thread: threading.Thread | None = None

    def start(self, fd: int) -> None:
        self._fd, self._stop = fd, False
        self._thread = threading.Thread(target=self._run, name="tvsd-mcu-tty-probe", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Ask the thread to end (not joined: it may be waiting in the kernel for the worker)."""
        self._stop = True
        self._request.set()

    @property
    def busy(self) -> bool:
        """A probe waits in the kernel: the tty's worker holds bytes for us."""
        return self._busy

    def ask(self) -> None:
        if not self._busy:
            self._answer, self._busy, self._asked_at = None, True, time.monotonic()
            self._request.set()

    def answer(self, since: float) -> bool | None:
        """Readable or not, by the last probe asked after `since` (taken once); None: none."""
        answer, self._answer = self._answer, None
        return answer if self._asked_at > since else None

    def _run(self) -> None:
        while True:
            self._request.wait()
            self._request.clear()
            fd = self._fd
            if self._stop or fd is None:
                return
            try:  # blocks while the flip-buffer work holds bytes (the docstring)
                ready = bool(select.select([fd], [], [], 0)[0])
            except (OSError, ValueError):  # closed under us
                ready = False
            self._answer, self._busy = ready, False
            self._wake()
