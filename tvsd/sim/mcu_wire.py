"""The virtual MCU's wire model: what the pty is not, and what the SIL does about it.

A real UART (or USB link) from the host has the host's bytes on the wire when they are written.
The SIL's pty hands them to the virtual MCU through the kernel's tty flip-buffer work, a
normal-priority kworker that CPU hogs hold off for tens to hundreds of ms (docs/measurements/soak-and-load.md,
"The SIL's MCU
link under CPU hogs: the pty's kernel worker"). A heartbeat the host sent in time could then reach
a core that, paced at real time, had already run past last heartbeat + watchdog and cut: the
pty's expiry, not the host's. So the firmware's watchdog cut waits at that edge (counted from the
last heartbeat's own send tick: one read while the cut waits goes into the core at the tick it
was sent, vmcu_rx_bytes_at) until either a heartbeat sent before the edge has come in (no cut), or one sent
at or after it has (the host's own gap crossed it: cut before that heartbeat is handled), or
:data:`WIRE_ALLOWANCE_S` of wall time has passed beyond the edge with neither (a dead host: cut,
that much late). Only the cut waits (a SIL-only core hook, CORE_SIL_HOOKS): the core's clock,
its state frames and the plant run on at real time. Holding the whole core (and the plant) at the
edge instead was tried first: each wait ended in a catch-up burst that kept the SIL process's
threads off the CPU, and the pty's delays grew with the allowance (docs/measurements/soak-and-load.md).

Not reproduced: a frame read while the cut waits is handled as if the watchdog were armed; if the
host's gap was real, the chip had refused it (ACK_NO_HEARTBEAT) and here it is taken, then cut.

G, the allowance: from the heartbeats' send -> pump-read delay measured on this 2-core machine
(``scripts/pty_wire_delay.py``, and the soak's SIL process: docs/measurements/soak-and-load.md, the pty's
kernel worker).
A wait starts only for a heartbeat read more than watchdog − period late (37.5 ms at the shipped
50 / 12.5 ms), and G covers the rest of the delay. Hogs alone: max 1.5 / 48.5 / 5.4 ms (0 / 1 /
2 hogs, 30 s each). The soak (2 hogs, 50 RPC clients, the daemon): 3-8 % of the heartbeats over
40 ms, max 236-445 ms in four 60 s runs; at G = 250 ms two were still cut (read 300-445 ms late),
at 500 ms none (the longest wait 374 ms). A dead host is cut within watchdog + G in the SIL.

Owns: the model's numbers (G, the environment overrides, :class:`WireStats` and their export) and
its logic inside the virtual MCU (:class:`WireModel`: reading the heartbeats' send times, holding
the cut). :class:`tvsd.sim.virtual_mcu.VirtualMcu` owns the core, the pty and the lock it calls
:class:`WireModel` under.
"""

from __future__ import annotations

import bisect
import contextlib
import ctypes
import json
import math
import os
import threading
import time
import zlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tvsd.hw.mcu.spec import FRAME_CRC, FRAME_HEADER, load_spec

WIRE_ALLOWANCE_S = 0.500
# For measuring, in the SIL devices' process (tvsd.sim.sil_process): another allowance (0: none,
# the pty's timing decides, as before this model), and a JSON file rewritten every second with
# the wire's WireStats (a soak's daemon and its SIL process inherit the environment).
ENV_ALLOWANCE = "TVSD_SIL_WIRE_ALLOWANCE_S"
ENV_STATS = "TVSD_SIL_WIRE_STATS"
# Bins of the heartbeats' send → read delay, ms (upper edges; the last bin is everything above).
DELAY_EDGES_MS = (
    0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 40.0, 50.0, 75.0, 100.0, 150.0, 200.0, 300.0, 500.0
)
_QUANTILES = (("p50", 0.5), ("p99", 0.99), ("p999", 0.999))
_LABELS = (*(f"<={e:g}" for e in DELAY_EDGES_MS), f">{DELAY_EDGES_MS[-1]:g}")
# The virtual MCU's host bytes not yet in the core: (core ticks, arrival, bytes, a heartbeat alone).
QueuedRx = Iterable[tuple[int, float, bytes, bool]]
HB_MAX_AGE_US = 1_000_000  # a heartbeat's host_us older than this at its read: not trusted
LATE_KEPT = 30  # the latest heartbeats kept with their times, to match against a kworker trace


@dataclass
class WireStats:
    """What the wire model saw: heartbeats read and how late, holds at the watchdog's edge."""

    heartbeats: int = 0
    delay_max_ms: float = 0.0
    delay_hist: list[int] = field(default_factory=lambda: [0] * (len(DELAY_EDGES_MS) + 1))
    holds: int = 0  # times the cut waited at the watchdog's edge for the wire
    hold_max_ms: float = 0.0  # wall time of the longest wait
    released_by_heartbeat: int = 0  # a heartbeat sent before the edge came: no cut
    cut_at_allowance: int = 0  # none came within the allowance: crossed, and the watchdog cut
    # the LATE_KEPT latest reads: (delay ms, sent, read; CLOCK_MONOTONIC s), smallest first
    latest: list[tuple[float, float, float]] = field(default_factory=list)

    def heartbeat(self, delay_s: float, read_at: float = math.nan) -> None:
        ms = delay_s * 1e3
        self.heartbeats += 1
        self.delay_max_ms = max(self.delay_max_ms, ms)
        self.delay_hist[bisect.bisect_left(DELAY_EDGES_MS, ms)] += 1
        if len(self.latest) < LATE_KEPT or ms > self.latest[0][0]:
            bisect.insort(self.latest, (ms, read_at - delay_s, read_at))
            del self.latest[: max(len(self.latest) - LATE_KEPT, 0)]

    def quantile_ms(self, q: float) -> float:
        """Upper edge of the bin holding quantile q (inf: above the last edge)."""
        need, seen = q * self.heartbeats, 0
        for k, n in enumerate(self.delay_hist):
            seen += n
            if n and seen >= need:
                return DELAY_EDGES_MS[k] if k < len(DELAY_EDGES_MS) else float("inf")
        return 0.0

    def as_dict(self) -> dict[str, Any]:
        return {
            "heartbeats": self.heartbeats,
            "delay_max_ms": round(self.delay_max_ms, 3),
            # upper edges of the bins holding these quantiles
            **{f"delay_{name}_ms_le": self.quantile_ms(q) for name, q in _QUANTILES},
            "delay_hist_ms": {label: n for label, n in zip(_LABELS, self.delay_hist, strict=True) if n},
            "holds": self.holds,
            "hold_max_ms": round(self.hold_max_ms, 3),
            "released_by_heartbeat": self.released_by_heartbeat,
            "cut_at_allowance": self.cut_at_allowance,
            "latest": [
                {"delay_ms": round(d, 3), "sent": round(s, 6), "read": round(r, 6)}
                for d, s, r in reversed(self.latest)
            ],
        }


def allowance_from_env(default: float = WIRE_ALLOWANCE_S) -> float:
    """The allowance the SIL process uses: $TVSD_SIL_WIRE_ALLOWANCE_S if set (seconds), else G."""
    raw = os.environ.get(ENV_ALLOWANCE, "").strip()
    if not raw:
        return default
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not 0.0 <= value < 10.0:
        raise ValueError(f"{ENV_ALLOWANCE}={raw!r}: seconds in [0, 10) expected. Fix: unset it, or e.g. 0.05")
    return value


def export_stats(stats: WireStats, stop: threading.Event, period_s: float = 1.0) -> threading.Thread | None:
    """If $TVSD_SIL_WIRE_STATS names a file, a thread rewrites it with `stats` every period_s
    until `stop` (and once more then): the figures survive the process being killed."""
    path = os.environ.get(ENV_STATS, "").strip()
    if not path:
        return None
    target = Path(path)

    def run() -> None:
        while True:
            done = stop.wait(period_s)
            tmp = target.with_name(target.name + ".tmp")
            with contextlib.suppress(OSError):
                tmp.write_text(json.dumps(stats.as_dict()))
                tmp.replace(target)
            if done:
                return

    thread = threading.Thread(target=run, name="sil-wire-stats", daemon=True)
    thread.start()
    return thread


class WireModel:
    """The wire model inside one virtual MCU: the heartbeats' send times read from the host's
    bytes, and the watchdog cut held at its edge while the wire may still bring one.

    Owned by :class:`tvsd.sim.virtual_mcu.VirtualMcu`, which calls every method with its lock
    held and passes in what it owns: the core's queue of host bytes not yet handed in (``(core
    ticks, arrival, bytes, a heartbeat frame alone)``, in arrival order) and its core-seconds ->
    host-time line. `lib` is the loaded core (tvsd.sim.vmcu_library.load_library); the counts go
    to `stats`."""

    def __init__(self, lib: ctypes.CDLL, clock_hz: int, allowance_s: float, stats: WireStats) -> None:
        self._lib = lib
        self.clock_hz = clock_hz
        self.allowance_s = allowance_s
        self.stats = stats
        self._wd_edge, self._wd_ticks = ctypes.c_uint64(), ctypes.c_uint64()
        self._released_edge = -1  # an edge the allowance ran out at: crossed
        self.deferring, self._held_since = False, 0.0  # the cut waits for the wire, since (monotonic)
        spec = load_spec()
        hb = spec.by_name("heartbeat")
        self.hb_head = (spec.sync, hb.size, hb.id)  # a heartbeat frame's SYNC, LEN, ID
        self._rx_tail = b""  # the last bytes read: a heartbeat split across two reads

    @property
    def heartbeat_frame_len(self) -> int:
        return FRAME_HEADER + self.hb_head[1] + FRAME_CRC

    def reaches_edge(self, ticks: int) -> bool:
        """Whether an advance to `ticks` must consult the model (once per advance, not per slice):
        it is on and the cut waits, or the advance reaches the watchdog's edge."""
        return self.allowance_s > 0 and (
            self.deferring
            or bool(self._lib.vmcu_watchdog(self._wd_edge, self._wd_ticks) and ticks >= self._wd_edge.value)
        )

    def heartbeat_in(self, when: int) -> bool:
        """A heartbeat frame alone, sent at core tick `when`, goes into the core now. If the cut
        waits and it was sent at or after the edge (the host's own gap), the cut happens first,
        as the tick at the edge made it. True: hand it in at `when` (vmcu_rx_bytes_at: read while
        the cut waits for it, the next edge counts from its send tick); False: at the read's
        time, as before (the ack's mcu_ticks stays the read's, for the host's clock sync)."""
        if (
            self.deferring
            and self._lib.vmcu_watchdog(self._wd_edge, self._wd_ticks)
            and when >= self._wd_edge.value  # sent at or after the edge: the host's own gap
        ):
            self._end_deferral(released=False)
            self._lib.vmcu_watchdog_check()  # the cut, as the tick at the edge made it: before it
        return self.deferring and when >= 0

    def _edge(self, rx_queue: QueuedRx, to_host: Callable[[float], float]) -> int | None:
        """The tick from which the watchdog's cut waits for the wire, or None: its edge (the last
        heartbeat's send tick + watchdog, moved on by the heartbeats queued before it) while the
        wire may still bring a heartbeat sent before it. None once one sent at or after it is
        queued (the host's own gap crossed the edge: the firmware cuts), once the allowance of
        wall time past the edge is spent (a dead host: cut, that much late), or unarmed."""
        if not self._lib.vmcu_watchdog(ctypes.byref(self._wd_edge), ctypes.byref(self._wd_ticks)):
            return None
        edge, wd = int(self._wd_edge.value), int(self._wd_ticks.value)
        for when, _, _, heartbeat in rx_queue:
            if heartbeat:
                if when >= edge:
                    return None
                edge = when + wd
        if edge == self._released_edge:
            return None
        if time.monotonic() >= to_host(edge / self.clock_hz) + self.allowance_s:
            self._released_edge = edge
            self.stats.cut_at_allowance += 1
            return None
        return edge

    def defer(self, upto: int, rx_queue: QueuedRx, to_host: Callable[[float], float] | None) -> None:
        """Whether the watchdog's cut waits while the core runs to `upto`: while it is at or past
        the edge that the wire may still answer (_edge). The core's time, its frames and the plant
        run on; only the cut waits. Counts the waits. `to_host` None: no line to count the
        allowance on (a manual clock driven by hand): never waits."""
        edge = None if self.allowance_s <= 0 or to_host is None else self._edge(rx_queue, to_host)
        waiting = edge is not None and upto >= edge
        if waiting == self.deferring:
            return
        if waiting:
            self._lib.vmcu_watchdog_defer(1)
            self.deferring, self._held_since = True, time.monotonic()
            self.stats.holds += 1
        else:  # moved on by a heartbeat sent in time; else crossed (the allowance spent: cut)
            self._end_deferral(released=edge is not None)

    def _end_deferral(self, released: bool) -> None:
        self._lib.vmcu_watchdog_defer(0)
        self.deferring = False
        self.stats.hold_max_ms = max(self.stats.hold_max_ms, (time.monotonic() - self._held_since) * 1e3)
        if released:
            self.stats.released_by_heartbeat += 1

    def sent_times(self, data: bytes, arrival: float) -> list[tuple[float, bytes]]:
        """`data` cut after each heartbeat frame in it, each part with the time its last byte was
        on the wire at the latest: a heartbeat's own `host_us` (CLOCK_MONOTONIC µs when the host
        built it, mod 2**32), the rest `arrival`. Why: host bytes reach this pty through the
        kernel's tty flip-buffer work, a normal-priority kworker, which CPU hogs delay by tens of
        ms, so heartbeats the host wrote 12.5 ms apart were read, and went into the core, more
        than the 50 ms watchdog apart (firmware expiries while the host's own gaps stayed
        13-17 ms). A real UART or USB link puts the host's bytes on the wire when it writes
        them; so does this, for the frames that say when."""
        sync, size, hb_id = self.hb_head
        frame = FRAME_HEADER + size + FRAME_CRC
        buf = self._rx_tail + data
        skip = len(self._rx_tail)
        self._rx_tail = buf[-(frame - 1) :]
        parts: list[tuple[float, bytes]] = []
        start, last = 0, -math.inf
        arrival_us = int(arrival * 1e6)
        i = buf.find(sync)
        while 0 <= i <= len(buf) - frame:
            end = i + frame
            if buf[i + 1] == size and buf[i + 4] == hb_id and end > skip:
                body = buf[i : i + FRAME_HEADER + size]
                if zlib.crc32(body) == int.from_bytes(buf[i + FRAME_HEADER + size : end], "little"):
                    host_us = int.from_bytes(buf[i + FRAME_HEADER : i + FRAME_HEADER + size], "little")
                    age_us = (arrival_us - host_us) % 2**32
                    if age_us <= HB_MAX_AGE_US:
                        # (else not a time we can trust: the read's)
                        self.stats.heartbeat(age_us * 1e-6, arrival)
                        sent = max(last, arrival - age_us * 1e-6)
                        parts.append((sent, data[start : end - skip]))
                        start, last = end - skip, sent
                    i = end - 1
            i = buf.find(sync, i + 1)
        if start < len(data):
            parts.append((arrival, data[start:]))
        return parts
