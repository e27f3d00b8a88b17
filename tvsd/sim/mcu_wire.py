"""The virtual MCU's wire model: what the pty is not, and what the SIL does about it.

A real UART (or USB link) from the host has the host's bytes on the wire when they are written.
The SIL's pty hands them to the virtual MCU through the kernel's tty flip-buffer work, a
normal-priority kworker that CPU hogs hold off for tens to hundreds of ms (README, "The SIL's MCU
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
threads off the CPU, and the pty's delays grew with the allowance (README).

Not reproduced: a frame read while the cut waits is handled as if the watchdog were armed; if the
host's gap was real, the chip had refused it (ACK_NO_HEARTBEAT) and here it is taken, then cut.

G, the allowance: from the heartbeats' send -> pump-read delay measured on this 2-core machine
(``scripts/pty_wire_delay.py``, and the soak's SIL process: README, the pty's kernel worker).
A wait starts only for a heartbeat read more than watchdog − period late (37.5 ms at the shipped
50 / 12.5 ms), and G covers the rest of the delay. Hogs alone: max 1.5 / 48.5 / 5.4 ms (0 / 1 /
2 hogs, 30 s each). The soak (2 hogs, 50 RPC clients, the daemon): 3-8 % of the heartbeats over
40 ms, max 236-445 ms in four 60 s runs; at G = 250 ms two were still cut (read 300-445 ms late),
at 500 ms none (the longest wait 374 ms). A dead host is cut within watchdog + G in the SIL.
"""

from __future__ import annotations

import bisect
import contextlib
import json
import math
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

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

    def heartbeat(self, delay_s: float) -> None:
        ms = delay_s * 1e3
        self.heartbeats += 1
        self.delay_max_ms = max(self.delay_max_ms, ms)
        self.delay_hist[bisect.bisect_left(DELAY_EDGES_MS, ms)] += 1

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
