"""Control ticks into a recording by tick number: no row twice, none skipped (issue 13 item 4).

The old drain read `runner.ticks`, then `recent_ticks(n)`, which read the count again while the
thread kept writing: the rows ended at a later tick than the count it kept, so the next drain
gave some ticks a second time (duplicated 1 kHz bins in 2 of 9 daemon recordings).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tvsd.control.runner import Runner
from tvsd.control.setup import Setup
from tvsd.daemon.session_recording import SessionRecording


class Capture(SessionRecording):
    """A daemon recording that also keeps every tick row handed to the 1 kHz binning."""

    def __init__(self, path: Path) -> None:
        super().__init__(path, "", from_tick=0)
        self.rows: list[np.ndarray] = []

    def loop_ticks(self, rows: np.ndarray) -> None:
        self.rows.append(rows.copy())
        super().loop_ticks(rows)


def test_draining_a_running_loop_moves_each_tick_exactly_once(setup: Setup, tmp_path: Path) -> None:
    """Drains as fast as the event loop could (back to back) race the 10 kHz thread on every call:
    each tick's row must arrive once, in order. Tick times strictly increase (a tick twice would
    repeat its t), and rows + lost = ticks run (lost: overwritten before a drain, none here: the
    ring holds 0.4 s and a drain comes every few ms)."""
    r = Runner(setup, record=4096)
    rec = Capture(tmp_path / "rec")
    r.start()
    try:
        deadline = time.monotonic() + 0.5
        drains = 0
        while time.monotonic() < deadline or r.ticks < 2000:
            rec.drain(r)
            drains += 1
            time.sleep(0)
    finally:
        r.stop(5.0)
    rec.drain(r)
    rec.close()
    rows = np.concatenate(rec.rows)
    t = rows["t"]
    assert drains > 50
    dup = int(np.sum(np.diff(t) <= 0))
    assert dup == 0, f"{dup} tick rows came twice or out of order over {drains} drains"
    assert getattr(rec, "lost_ticks", 0) == 0
    assert len(rows) == r.ticks, f"{len(rows)} rows for {r.ticks} ticks"


def test_ticks_the_ring_overwrote_are_counted_not_returned(setup: Setup) -> None:
    r = Runner(setup, record=256)
    r.start(max_ticks=1000)
    r.join(30.0)
    batch = r.ticks_since(0)
    # The ring holds 256 rows, and the oldest one is the row the next tick would write: 255 kept.
    assert (batch.first, batch.next, batch.lost, len(batch.rows)) == (745, 1000, 745, 255)
    assert np.all(np.diff(batch.rows["t"]) > 0)
    again = r.ticks_since(batch.next)
    assert (again.first, again.next, again.lost, len(again.rows)) == (1000, 1000, 0, 0)
    part = r.ticks_since(900)
    assert (part.first, part.lost, len(part.rows)) == (900, 0, 100)
    np.testing.assert_array_equal(part.rows["t"], batch.rows["t"][-100:])
