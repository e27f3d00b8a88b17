"""The control thread: the kernel's shared arrays, its thread, and the I/O side's one interface.

The kernel (tvsd.control.kernel.control_loop) runs on its own thread and never returns to Python
while it runs; this module owns its arrays (the words: tvsd.control.words) and is everything
outside tvsd/control may use to steer it (a test greps for it). The MCU frames the kernel sends
itself (heartbeat, PWM 0 in the safe state) are tvsd.control.link_tx's; the real-time request is
tvsd.control.realtime's.
"""

from __future__ import annotations

import math
import threading
import time
from typing import NamedTuple

import numpy as np

from tvsd.config import Gains
from tvsd.control import latency as L
from tvsd.control import layout as W
from tvsd.control.kernel import EXTRAPOLATE_MAX_NS, control_loop
from tvsd.control.link_tx import TX_BUF_BYTES
from tvsd.control.realtime import Realtime, request_realtime
from tvsd.control.setup import Setup
from tvsd.control.words import (
    EXC_LEAD_NS,
    FAULT_NONE,
    K_BUSY_NS,
    K_CHAIN_NS,
    K_CUTS_SENT,
    K_DUE_NS,
    K_EXC_N,
    K_EXC_STEP_NS,
    K_EXC_T0_NS,
    K_FAULT,
    K_FAULT_MEAS_NS,
    K_FAULT_NS,
    K_HB_GAP_MAX_NS,
    K_HB_LAST_NS,
    K_HB_LATE_MAX_NS,
    K_HB_NEXT_NS,
    K_HB_PERIOD_NS,
    K_HB_SENT,
    K_HELD,
    K_HOLD_LONGEST_NS,
    K_HOLD_MAX_NS,
    K_HOLD_START_NS,
    K_HOLD_TOTAL_NS,
    K_HOLDS,
    K_LATCH_NS,
    K_MEAS_NS,
    K_MEAS_SEQ,
    K_SAMPLE_NS,
    K_STALE_NS,
    K_STREAK_LIMIT,
    K_TX_ERRORS,
    K_TX_HB_ID,
    K_TX_PWM_ID,
    K_TX_SYNC,
    MODE_IDLE,
    MODE_POSITION,
    MODE_SCAN,
    N_INTS,
    N_REC,
    N_VALS,
    TICK_DTYPE,
    V_MODE,
    V_OMEGA,
    V_PHI,
    V_REF,
    V_U,
    LoopFault,
)
from tvsd.hw.mcu.shared_tx import SharedTx
from tvsd.model import plant as K

__all__ = [
    "EXTRAPOLATE_MAX_NS",
    "TICK_DTYPE",
    "Holds",
    "KernelHeartbeats",
    "LoopFault",
    "Realtime",
    "Runner",
    "TickBatch",
    "request_realtime",
]


class TickBatch(NamedTuple):
    """`Runner.ticks_since`: rows of ticks first .. next-1, and how many before `first` were lost."""

    rows: np.ndarray
    first: int
    next: int
    lost: int


class Holds(NamedTuple):
    """`Runner.holds`: command 0 held for late input, then control resumed (tvsd.control.hold)."""

    resumed: int  # holds that ended in a resume
    total_s: float  # their time in all
    longest_s: float
    held_s: float  # the hold now: how long so far (0: none)


class KernelHeartbeats(NamedTuple):
    """`Runner.heartbeat_stats`: the heartbeats the kernel wrote (times: CLOCK_MONOTONIC s)."""

    on: bool
    sent: int
    last_s: float
    gap_max_s: float  # longest time between two heartbeats written whole
    late_max_s: float  # how late after its due time a heartbeat was built, at most
    errors: int  # writes that failed (the port gone or closed): frames dropped
    busy: int  # ticks the port was the I/O thread's (mutex or its torn frame): tried next tick
    cuts: int  # PWM-0 frames sent behind a heartbeat while the loop's fault held the safe state


class Runner:
    """The control thread and its shared arrays; SIL when built with `sil=True`.

    The I/O side's whole interface to the loop: the mode (`position`, `scan`, `idle`), the gains
    (`set_gains`, `gains`), the measurement (`measured`, `stale_after`, `held`, `holds`), the safe
    state (`fault`, `fault_code`, `clear_fault`, `inject_overrun`), and what the loop did (`recent_ticks`,
    `stats`, `ticks`, `command`). Every call is a few word writes or a copy: safe from any thread,
    and never a wait on the loop.
    """

    def __init__(
        self,
        setup: Setup,
        *,
        sil: bool = True,
        period_s: float | None = None,
        streak_limit: int = 1000,  # the daemon's default: 100 ms of late ticks at 10 kHz
        record: int = 65536,
        realtime: bool = False,
        excitation_rows: int = 0,
        lock_memory: bool = True,  # with `realtime`: mlockall (a test process may not want it)
    ) -> None:
        self._setup = setup  # the plant's arrays; the gains live in `vals` from here on
        self.sil = sil
        self.realtime = realtime
        self.lock_memory = lock_memory
        self.realtime_report: Realtime | None = None
        self.ints = np.zeros(N_INTS, dtype=np.int64)
        self.ints[L.K_PERIOD_NS] = round((setup.dt if period_s is None else period_s) * L.NS)
        self.ints[K_STREAK_LIMIT] = streak_limit
        self.vals = np.zeros(N_VALS)
        W.pack_law(self.vals, setup)
        self.hist = np.zeros(L.N_BINS, dtype=np.int64)
        self.rec = np.zeros((record, N_REC))
        self.exc = np.zeros((max(excitation_rows, 1), W.N_EXC))  # preallocated: identify allocates nothing
        self._exc_rows = excitation_rows
        self.ts = np.zeros(2, dtype=np.int64)
        self.tx = SharedTx()  # the MCU port's write side, shared with the link (`attach_link`)
        self.txbuf = np.zeros(TX_BUF_BYTES, dtype=np.uint8)
        self.plant_dt = setup.dt / setup.substeps
        self.state = K.state_array(self.plant_dt)  # room for the delay ring: no allocation per tick
        self.u_hold = np.zeros(1)  # the command held over each tick's plant steps
        self.cpu_s = 0.0
        self._thread: threading.Thread | None = None
        if sil:  # seed the plant's vibration once; per-tick calls pass seed -1
            K.advance(
                self.state,
                setup.plant,
                setup.effects,
                setup.vibration,
                self.plant_dt,
                0,
                self.u_hold,
                1,
                setup.seed,
            )

    # --- the law ----------------------------------------------------------------------------------
    def position(self, ref_rad: float) -> None:
        """Position mode: hold the shaft at `ref_rad`."""
        self.vals[V_REF] = ref_rad
        self.vals[V_MODE] = MODE_POSITION

    def scan(self, rps: float) -> None:
        """Scanning mode: the speed reference ramps to `rps` and the angle reference follows it."""
        self.vals[V_REF] = rps
        self.vals[V_MODE] = MODE_SCAN

    def idle(self) -> None:
        """No law: command 0."""
        self.vals[V_MODE] = MODE_IDLE

    def set_gains(self, gains: Gains) -> None:
        """The law's gains from the next tick on (the four words may straddle one tick: harmless
        between gain sets that each satisfy the conditions)."""
        W.write_gains(self.vals, gains)

    def gains(self) -> Gains:
        """The gains the loop runs with now: the one source of truth once the loop is built."""
        return W.read_gains(self.vals)

    # --- the excitation (tvsctl identify) -----------------------------------------------------------
    def set_excitation(
        self, d_rps: np.ndarray, d_volts: np.ndarray, period_s: float, start_ns: int | None = None
    ) -> int:
        """Play an excitation in scanning mode: row k adds d_rps[k] (rev/s) to the speed reference
        and d_volts[k] (V) to the command, from start_ns + k·period_s (CLOCK_MONOTONIC; default
        EXC_LEAD_NS from now). The table is copied into the preallocated one here, off the loop.
        Returns the start time. Any fault or mode change ends it (`excitation_active`)."""
        n = len(d_rps)
        if len(d_volts) != n or not 0 < n <= self._exc_rows:
            raise ValueError(f"excitation of {n} rows: the runner holds 1 .. {self._exc_rows}")
        if not period_s > 0:
            raise ValueError(f"excitation period {period_s!r} s: must be positive")
        ints = self.ints
        ints[K_EXC_N] = 0  # off while the table is rewritten
        self.exc[:n, W.EXC_RPS] = d_rps
        self.exc[:n, W.EXC_VOLTS] = d_volts
        ints[K_EXC_STEP_NS] = round(period_s * L.NS)
        t0 = time.monotonic_ns() + EXC_LEAD_NS if start_ns is None else start_ns
        ints[K_EXC_T0_NS] = t0
        ints[K_EXC_N] = n  # published last: the loop reads the count first
        return t0

    def clear_excitation(self) -> None:
        """End the excitation from the next tick on."""
        self.ints[K_EXC_N] = 0

    @property
    def excitation_active(self) -> bool:
        """An excitation is set and not yet over (the loop clears it at its end, on a fault, or when
        the mode leaves scanning)."""
        return bool(self.ints[K_EXC_N] > 0)

    @property
    def excitation_capacity_rows(self) -> int:
        return self._exc_rows

    # --- the measurement (hardware mode) ------------------------------------------------------------
    def measured(
        self,
        phi: float,
        omega: float,
        t_ns: int | None = None,
        sample_ns: int | None = None,
        *,
        due_ns: int | None = None,
        chain_ns: int | None = None,
    ) -> None:
        """Hardware mode: the I/O side writes the latest encoder angle and speed, when it
        arrived (CLOCK_MONOTONIC ns, default now; judged by the stale check) and, if known, when
        the MCU sampled it (the same clock; the law carries the angle forward from there at the
        measured speed). For the late-input hold (`stale_after`'s `hold_s`, tvsd.control.hold):
        when the frame was due by the MCU's own stamps (`due_ns` ≤ the arrival) and when the
        unbroken chain of frames it belongs to began (`chain_ns`, an arrival time). Not given:
        the frame is a chain of its own, due on arrival, so a hold it ends latches. The arrival
        time is written last."""
        ints = self.ints
        t = time.monotonic_ns() if t_ns is None else t_ns
        ints[K_MEAS_SEQ] += 1  # odd: an update is being written (a seqlock; one writer)
        self.vals[V_PHI] = phi
        self.vals[V_OMEGA] = omega
        ints[K_SAMPLE_NS] = 0 if sample_ns is None else sample_ns
        ints[K_DUE_NS] = t if due_ns is None else due_ns
        ints[K_CHAIN_NS] = t if chain_ns is None else chain_ns
        ints[K_MEAS_SEQ] += 1
        ints[K_MEAS_NS] = t

    @property
    def omega(self) -> float:
        """The latest measured speed, rad/s (SIL: the plant's)."""
        return float(self.vals[V_OMEGA])

    @property
    def measurement_age_s(self) -> float | None:
        """How old the newest measurement is (None before the first): the status's staleness."""
        t_ns = int(self.ints[K_MEAS_NS])
        return None if t_ns == 0 else (time.monotonic_ns() - t_ns) / L.NS

    def stale_after(self, seconds: float, hold_s: float = 0.0) -> None:
        """Command 0 when the newest measurement is older than `seconds` (0: never). With
        `hold_s` 0 that latches the fault STALE at once; above 0 it holds, unlatched, until the
        frames that come show late input (resume, counted: `holds`) or a stopped MCU (GAP),
        or until `hold_s` after the last frame passes without them (STALE): tvsd.control.hold."""
        if not (seconds >= 0 and hold_s >= 0) or (hold_s and hold_s < seconds):
            raise ValueError(f"stale after {seconds!r} s, hold {hold_s!r} s: need 0 <= stale <= hold")
        self.ints[K_HOLD_MAX_NS] = round(hold_s * L.NS)
        self.ints[K_STALE_NS] = round(seconds * L.NS)

    @property
    def held(self) -> bool:
        """The loop holds command 0 for late input, not latched (tvsd.control.hold)."""
        return bool(self.ints[K_HELD])

    def holds(self) -> Holds:
        """The late-input holds so far (each ended in a resume) and the one now, if any."""
        i = self.ints
        now = int(i[K_HELD]) and time.monotonic_ns() - int(i[K_HOLD_START_NS])
        return Holds(
            resumed=int(i[K_HOLDS]),
            total_s=int(i[K_HOLD_TOTAL_NS]) / L.NS,
            longest_s=int(i[K_HOLD_LONGEST_NS]) / L.NS,
            held_s=max(now, 0) / L.NS,
        )

    # --- the safe state ----------------------------------------------------------------------------
    @property
    def fault(self) -> bool:
        return bool(self.ints[K_FAULT])

    @property
    def fault_code(self) -> LoopFault:
        return LoopFault(int(self.ints[K_FAULT]))

    @property
    def fault_after_measurement_s(self) -> float:
        """How long after the newest measurement the safe state began (the stale check's
        latency; for a fault latched from a late-input hold: when the hold began)."""
        return (int(self.ints[K_FAULT_NS]) - int(self.ints[K_FAULT_MEAS_NS])) / L.NS

    @property
    def latched_after_measurement_s(self) -> float:
        """How long after the newest measurement the stale check latched (with a late-input hold:
        its bound, or sooner on a gap; without: the same as `fault_after_measurement_s`)."""
        return (int(self.ints[K_LATCH_NS]) - int(self.ints[K_FAULT_MEAS_NS])) / L.NS

    def clear_fault(self) -> None:
        self.ints[L.K_STREAK] = 0
        self.ints[K_HELD] = 0
        self.ints[K_FAULT] = FAULT_NONE

    def inject_overrun(self, periods: float) -> None:
        """Fault injection: every tick burns `periods` loop periods of wall time inside the
        kernel (0: stop), so ticks wake late and the overrun streak latches for certain."""
        self.ints[K_BUSY_NS] = round(periods * self.ints[L.K_PERIOD_NS])

    # --- what the loop did ---------------------------------------------------------------------------
    @property
    def command(self) -> float:
        return float(self.vals[V_U])

    @property
    def period_s(self) -> float:
        return int(self.ints[L.K_PERIOD_NS]) / L.NS

    @property
    def alive(self) -> bool:
        """The thread exists (it may still be loading the kernel: see `is_running`)."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def is_running(self) -> bool:
        """The kernel is in its loop (loaded, ticking, not yet stopped)."""
        return bool(self.ints[L.K_RUNNING])

    @property
    def ticks(self) -> int:
        return int(self.ints[L.K_TICKS])

    @property
    def start_ns(self) -> int:
        """CLOCK_MONOTONIC when the loop started: a tick's wake time is start_ns + t·1e9."""
        return int(self.ints[L.K_START_NS])

    @property
    def ring_size(self) -> int:
        """How many ticks `recent_ticks` can give at most (6.5 s at 10 kHz by default)."""
        return int(self.rec.shape[0])

    def stats(self) -> L.Jitter:
        return L.jitter(self.ints, self.hist)

    def lateness_histogram(self) -> np.ndarray:
        """Ticks per lateness bin (lower edges: tvsd.control.latency.EDGES_NS), a copy."""
        return self.hist.copy()

    def recent_ticks(self, n: int | None = None) -> np.ndarray:
        """The last n recorded ticks, oldest first: a copy, a structured array of TICK_DTYPE. The
        loop ticks on between calls: to move every tick once, read by number (`ticks_since`)."""
        ticks, size = self.ticks, self.rec.shape[0]
        n = min(ticks, size) if n is None else min(n, ticks, size)
        idx = np.arange(ticks - n, ticks) % size
        return self.rec[idx].view(TICK_DTYPE).reshape(n)

    def ticks_since(self, seq: int) -> TickBatch:
        """The ticks numbered `seq` on, oldest first (a copy): read in turn with `next`, no tick
        comes twice and none is skipped unnoticed — ticks the ring overwrote before they were
        read (before the call, or during the copy) are counted in `lost`, not returned."""
        end, size = self.ticks, self.rec.shape[0]  # one read of the count: rows < end are written
        first = min(max(seq, end - size), end)
        rows = self.rec[np.arange(first, end) % size].view(TICK_DTYPE).reshape(end - first)
        # The thread kept writing during the copy: tick k's row is reused by tick k + size, and
        # tick `ticks` may be being written now, so rows of ticks <= ticks - size are suspect.
        torn = min(max(0, self.ticks - size + 1 - first), end - first)
        return TickBatch(rows[torn:], first + torn, end, first + torn - seq)

    # --- the kernel's own MCU frames (tvsd.control.link_tx) -------------------------------------
    def attach_link(self, heartbeat_period_s: float, sync: int, heartbeat_id: int, pwm_id: int) -> None:
        """The kernel sends the heartbeat every `heartbeat_period_s` (the first now) to the port
        of `self.tx` (the link opens it: McuLink(shared_tx=runner.tx)), and PWM 0 behind each
        while its fault holds the safe state. Only while the kernel runs: a stopped kernel sends
        nothing, and the firmware's watchdog cuts."""
        if not heartbeat_period_s > 0:
            raise ValueError(f"heartbeat period {heartbeat_period_s!r} s: must be positive")
        ints = self.ints
        ints[K_HB_PERIOD_NS] = 0  # off while the words change
        ints[K_TX_SYNC], ints[K_TX_HB_ID], ints[K_TX_PWM_ID] = sync, heartbeat_id, pwm_id
        ints[K_HB_NEXT_NS] = time.monotonic_ns()
        ints[K_HB_PERIOD_NS] = round(heartbeat_period_s * L.NS)

    def detach_link(self) -> None:
        """No more heartbeats from the kernel (from its next tick on)."""
        self.ints[K_HB_PERIOD_NS] = 0

    def heartbeat_stats(self) -> KernelHeartbeats:
        i = self.ints
        last = int(i[K_HB_LAST_NS])
        return KernelHeartbeats(
            on=bool(i[K_HB_PERIOD_NS] > 0),
            sent=int(i[K_HB_SENT]),
            last_s=last / L.NS if last else math.nan,
            gap_max_s=int(i[K_HB_GAP_MAX_NS]) / L.NS,
            late_max_s=int(i[K_HB_LATE_MAX_NS]) / L.NS,
            errors=int(i[K_TX_ERRORS]),
            busy=self.tx.counters()["kernel_busy"],
            cuts=int(i[K_CUTS_SENT]),
        )

    def reset_heartbeat_peaks(self) -> None:
        """Zero the worst gap and lateness: they then cover what follows."""
        self.ints[K_HB_GAP_MAX_NS] = self.ints[K_HB_LATE_MAX_NS] = 0

    # --- lifecycle --------------------------------------------------------------------------------
    def start(self, max_ticks: int = 0) -> None:
        """Start the thread; with max_ticks > 0 the loop stops by itself after that many more ticks."""
        if self._thread is not None and self._thread.is_alive():
            raise RuntimeError("control loop already running")
        self.ints[L.K_STOP] = 0
        self.ints[L.K_MAX_TICKS] = self.ticks + max_ticks if max_ticks > 0 else 0
        self._thread = threading.Thread(target=self._main, name="tvsd-control", daemon=True)
        self._thread.start()

    def _main(self) -> None:
        if self.realtime:
            self.realtime_report = request_realtime(lock=self.lock_memory)
        cpu0 = time.thread_time()
        s = self._setup
        control_loop(
            self.ints,
            self.vals,
            self.hist,
            L.EDGES_NS,
            self.rec,
            self.ts,
            self.sil,
            self.state,
            s.plant,
            s.effects,
            s.vibration,
            self.u_hold,
            self.plant_dt,
            self.exc,
            self.tx.words,
            self.tx.mutex,
            self.txbuf,
        )
        self.cpu_s = time.thread_time() - cpu0

    def stop(self, timeout: float = 1.0) -> None:
        self.ints[L.K_STOP] = 1
        self.join(timeout)

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                raise TimeoutError(f"control loop did not stop within {timeout} s")
