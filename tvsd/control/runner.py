"""The 10 kHz control thread: one numba nogil kernel that paces itself on absolute deadlines.

The kernel (`control_loop`) never returns to Python while it runs: it sleeps with
`clock_nanosleep(TIMER_ABSTIME)` (tvsd.control.latency.wait_tick), evaluates the robust law and
writes the command, and exchanges everything with the I/O side through preallocated numpy arrays:

- `ints` (int64): the timing words of tvsd.control.latency, then K_FAULT (0, or why the loop holds
  its safe state: FAULT_OVERRUN, FAULT_STALE), K_STREAK_LIMIT, K_BUSY_NS, K_MEAS_NS (CLOCK_MONOTONIC
  of the latest measurement the I/O side wrote), K_STALE_NS (0: no check), K_FAULT_NS and
  K_FAULT_MEAS_NS (when the fault latched, and the measurement time it judged), K_SAMPLE_NS (when
  the MCU sampled that measurement; 0: unknown, the angle is used as it is) and K_MEAS_SEQ (the
  seqlock around φ, ω and that time).
- `vals` (float64): the law's words (tvsd.control.layout), the measurement V_PHI, V_OMEGA (written
  by the I/O side), outputs V_U … V_DT.
- `exc` (float64, rows × tvsd.control.layout.N_EXC): the excitation table `tvsctl identify` plays
  (Runner.set_excitation): row k from K_EXC_T0_NS + k·K_EXC_STEP_NS on, K_EXC_N rows (0: off).
  Scanning mode only; a fault or any other mode clears K_EXC_N, so the excitation stops that tick.
- `hist`: the lateness histogram; `rec`: a ring of the last ticks (what the law saw and did),
  indexed by tick number, which the asyncio side reads in batches (`recent_ticks`, TICK_DTYPE).

These arrays and their word numbers are this package's own: everything outside tvsd/control
steers the loop through the `Runner` methods (a test greps for it).

Each input word is read once per tick; a multi-word update (the four gains) can straddle one
tick (100 µs), which is harmless for gain sets that each satisfy the conditions.

The law uses the measured time step: references advance by the real elapsed time, so a late tick
degrades gracefully. `streak_limit` consecutive ticks that wake more than a period late latch the
safe state (K_FAULT = FAULT_OVERRUN, command 0) until the I/O side clears K_FAULT. The default
is the daemon's (control.overrun_streak_ms 100): a shorter latch trips on a loaded machine's
ordinary stalls (50 ticks did, in CI, and stopped a test's plant).

Hardware mode (and the daemon's SIL, where the plant sits behind the MCU link): the I/O side writes
each encoder measurement with its arrival time and, once the clock sync places it, the MCU's
sampling instant, from which the law carries the angle forward at the measured speed. A
measurement older than K_STALE_NS while the drive is commanded latches FAULT_STALE: the command is
0 from the first tick past the limit, whatever the event loop is doing (the MCU link's own loss
report comes later, from asyncio).

SIL: the plant kernel (tvsd.model.plant.advance, open loop) is stepped inside the same loop by the
real elapsed time with the command held since the previous tick, so the simulated scanner runs in
real time. Its state (tvsd.model.plant.state_array) carries the plant's time and delay ring across
ticks, so fixed-frequency effects and the delay stay continuous and a tick allocates nothing; a
`drift` effect runs over each call, not over the session.
"""

from __future__ import annotations

import ctypes
import enum
import math
import os
import threading
import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from tvsd.config import Gains
from tvsd.control import latency as L
from tvsd.control import layout as W
from tvsd.control.law import robust_law
from tvsd.control.scanning import ramp_toward, track
from tvsd.control.setup import Setup
from tvsd.model import params as P
from tvsd.model import plant as K

# Runner words after the timing words of tvsd.control.latency.
(K_FAULT, K_STREAK_LIMIT, K_BUSY_NS, K_MEAS_NS, K_STALE_NS, K_FAULT_NS, K_FAULT_MEAS_NS) = range(
    L.N_TIMING, L.N_TIMING + 7
)
K_SAMPLE_NS, K_MEAS_SEQ = L.N_TIMING + 7, L.N_TIMING + 8
K_EXC_T0_NS, K_EXC_STEP_NS, K_EXC_N = L.N_TIMING + 9, L.N_TIMING + 10, L.N_TIMING + 11
N_INTS = L.N_TIMING + 12
EXC_LEAD_NS = 2_000_000  # an excitation starts this long after it is set: whole rows, from row 0


class LoopFault(enum.IntEnum):
    """Why the loop holds its safe state (command 0) until `clear_fault`."""

    NONE = 0
    OVERRUN = 1  # `streak_limit` late ticks in a row
    STALE = 2  # the newest measurement is older than `stale_after`


FAULT_NONE, FAULT_OVERRUN, FAULT_STALE = LoopFault.NONE.value, LoopFault.OVERRUN.value, LoopFault.STALE.value

# vals: the law's words (inputs the I/O side writes), the measurement, then outputs (kernel writes).
V_MODE, V_REF, V_GP, V_GD, V_GR, V_G0, V_UMAX = W.MODE, W.REF, W.GP, W.GD, W.GR, W.G0, W.UMAX
V_ACCEL, V_MAXLAG, V_FF = W.ACCEL, W.MAXLAG, W.FF
V_PHI, V_OMEGA = W.N_LAW, W.N_LAW + 1
(V_U, V_PHI_REF, V_OMEGA_REF, V_DT) = range(W.N_LAW + 2, W.N_LAW + 6)
N_VALS = W.N_LAW + 6
MODE_IDLE, MODE_POSITION, MODE_SCAN = W.MODE_OFF, W.MODE_POSITION, W.MODE_SCAN

# rec columns: one row per tick, row = tick % len(rec); `recent_ticks` names them (TICK_DTYPE).
TICK_FIELDS = ("t", "dt", "phi", "omega", "phi_ref", "omega_ref", "u_ff", "u", "late_us")
R_T, R_DT, R_PHI, R_OMEGA, R_PHI_REF, R_OMEGA_REF, R_UFF, R_U, R_LATE_US = range(len(TICK_FIELDS))
N_REC = len(TICK_FIELDS)
# One tick as the law saw it: t (s since the loop started), dt (the measured step, s), φ and ω
# measured (carried to the tick), φr and ωr, the feedforward u_ff and the command u (V), and how
# late the tick woke (µs).
TICK_DTYPE = np.dtype([(name, "<f8") for name in TICK_FIELDS])

# The measured angle is carried forward at the measured speed from its sampling instant to each
# tick, at most this far: beyond it the link is failing (the stale limit latches at 40 ms) and the
# angle is held.
EXTRAPOLATE_MAX_NS = 10_000_000
MAX_DT_S = 0.05  # a longer stall (suspend, debugger) advances the references by this much only
MAX_PLANT_STEPS = 1000  # SIL catch-up cap per tick (0.1 s at 10 kHz); beyond it sim time lags


@njit(cache=True, nogil=True)
def _busy(ts: np.ndarray, ns: int) -> None:
    """Test hook: burn `ns` of wall time inside the tick (artificial overrun)."""
    end = L.now_ns(ts) + ns
    while L.now_ns(ts) < end:
        pass


@njit(cache=True, nogil=True)
def _read_measurement(
    ints: np.ndarray, vals: np.ndarray, ts: np.ndarray, held: tuple[float, float, int]
) -> tuple[float, float, int]:
    """(φ, ω, sample time) as one consistent set, or `held` (the last one) if the I/O side is
    writing right now: it writes them between two increments of K_MEAS_SEQ. Never a retry loop:
    the writer may be preempted mid-write by this very thread (SCHED_FIFO on its CPU), and a
    spinning reader would then wait for the scheduler to move it (measured: 30–45 ms stalls).
    The clock call between the reads is opaque to the compiler, so it re-loads the sequence
    word rather than assuming nobody else writes it."""
    seq = ints[K_MEAS_SEQ]
    phi, omega, sample_ns = vals[V_PHI], vals[V_OMEGA], ints[K_SAMPLE_NS]
    L.now_ns(ts)
    if seq % 2 == 0 and ints[K_MEAS_SEQ] == seq:
        return phi, omega, sample_ns
    return held


@njit(cache=True, nogil=True)
def _excitation(ints: np.ndarray, exc: np.ndarray, wake: int) -> tuple[float, float]:
    """The excitation row due at `wake` (speed offset rev/s, voltage offset V); past the last row
    the table switches itself off."""
    k = (wake - ints[K_EXC_T0_NS]) // ints[K_EXC_STEP_NS]
    if k < 0:
        return 0.0, 0.0
    if k >= ints[K_EXC_N]:
        ints[K_EXC_N] = 0
        return 0.0, 0.0
    return exc[k, W.EXC_RPS], exc[k, W.EXC_VOLTS]


@njit(cache=True, nogil=True)
def control_loop(
    ints: np.ndarray,
    vals: np.ndarray,
    hist: np.ndarray,
    edges: np.ndarray,
    rec: np.ndarray,
    ts: np.ndarray,
    sil: bool,
    state: np.ndarray,
    plant: np.ndarray,
    eff: np.ndarray,
    vib: np.ndarray,
    u_hold: np.ndarray,
    plant_dt: float,
    exc: np.ndarray,
) -> None:
    """Run ticks until ints[K_STOP] (or K_MAX_TICKS); all state lives in the arrays."""
    ints[L.K_RUNNING] = 1
    cpu0 = L.thread_cpu_ns(ts)
    start = L.now_ns(ts)
    ints[L.K_START_NS] = start
    period = ints[L.K_PERIOD_NS]
    deadline = start + period
    prev = start
    phi_ref = vals[V_PHI]
    omega_ref = 0.0
    sim_debt = 0.0
    n_rec = rec.shape[0]
    J, kv, kM, kb = plant[P.P_J], plant[P.P_KV] + plant[P.P_S2], plant[P.P_KM], plant[P.P_KB]
    R, ku, tc, tsv, v0 = plant[P.P_R], plant[P.P_KU], plant[P.P_TC], plant[P.P_TS], plant[P.P_V0]
    u = 0.0
    measurement = (vals[V_PHI], vals[V_OMEGA], ints[K_SAMPLE_NS])
    while ints[L.K_STOP] == 0:
        wake, deadline = L.wait_tick(ints, hist, edges, ts, deadline)
        dt = min((wake - prev) / 1e9, MAX_DT_S)
        prev = wake
        if ints[K_BUSY_NS] > 0:
            _busy(ts, ints[K_BUSY_NS])
        if sil:
            # The command held over the elapsed interval drives the plant (zero-order hold).
            sim_debt += dt
            n = min(int(sim_debt / plant_dt), MAX_PLANT_STEPS)
            sim_debt = 0.0 if n == MAX_PLANT_STEPS else sim_debt - n * plant_dt
            u_hold[0] = u
            K.advance(state, plant, eff, vib, plant_dt, n, u_hold, 1 << 30, -1)
            vals[V_PHI] = state[K.S_PHI]
            vals[V_OMEGA] = state[K.S_OMEGA]
        measurement = _read_measurement(ints, vals, ts, measurement)
        phi, omega, sample_ns = measurement
        if sample_ns > 0:
            # The encoder was read at sample_ns, up to a frame period (+ the link) ago: the law
            # sees the angle now. Held, ε would grow by ω·period between frames (0.063 rad at
            # 2.5 kHz and 25 rev/s: G0·ε runs over tanh's whole range) and the command would saw.
            age = min(max(wake - sample_ns, 0), EXTRAPOLATE_MAX_NS)
            phi += omega * (age / 1e9)
        mode = int(vals[V_MODE])
        umax = vals[V_UMAX]
        u_ff = 0.0
        if ints[K_FAULT] == FAULT_NONE:
            if ints[L.K_STREAK] >= ints[K_STREAK_LIMIT]:
                ints[K_FAULT] = FAULT_OVERRUN
                ints[K_FAULT_NS] = wake
            elif mode != MODE_IDLE and ints[K_STALE_NS] > 0 and wake - ints[K_MEAS_NS] > ints[K_STALE_NS]:
                ints[K_FAULT] = FAULT_STALE
                ints[K_FAULT_NS] = wake
                ints[K_FAULT_MEAS_NS] = ints[K_MEAS_NS]
        if ints[K_FAULT] != 0 or mode != MODE_SCAN:
            ints[K_EXC_N] = 0  # the excitation is for scanning only, and ends with any fault
        d_rps, d_u = _excitation(ints, exc, wake) if ints[K_EXC_N] > 0 else (0.0, 0.0)
        if ints[K_FAULT] != 0 or mode == MODE_IDLE:
            u = 0.0
            phi_ref = phi  # a restart begins where the shaft is, not where it was
            omega_ref = omega if mode == MODE_SCAN else 0.0
        elif mode == MODE_POSITION:
            phi_ref = vals[V_REF]
            omega_ref = 0.0
            u = robust_law(phi_ref - phi, -omega, vals[V_GP], vals[V_GD], vals[V_GR], vals[V_G0], umax)
        else:
            # Scanning: the speed reference ramps, the angle reference integrates it over the
            # measured step, and slips beyond the allowed lag (anti-windup), as in the offline simulation.
            omega_prev = omega_ref
            omega_ref = ramp_toward(
                omega_ref, 2.0 * math.pi * (vals[V_REF] + d_rps), 2.0 * math.pi * vals[V_ACCEL] * dt
            )
            phi_ref += omega_ref * dt
            alpha = (omega_ref - omega_prev) / dt if dt > 0.0 else 0.0
            u, u_ff, phi_ref, _ = track(
                phi, omega, phi_ref, omega_ref, alpha, vals[V_MAXLAG], vals[V_FF] != 0.0 and dt > 0.0,
                J, kv, kM, kb, R, ku, tc, tsv, v0, vals[V_GP], vals[V_GD], vals[V_GR], vals[V_G0], umax,
            )  # fmt: skip
            u = min(max(u + d_u, -umax), umax)  # the PRBS rides on the law's output, within the drive
        vals[V_U] = u
        vals[V_PHI_REF] = phi_ref
        vals[V_OMEGA_REF] = omega_ref
        vals[V_DT] = dt
        row = ints[L.K_TICKS] % n_rec
        rec[row, R_T] = (wake - start) / 1e9
        rec[row, R_DT] = dt
        rec[row, R_PHI] = phi
        rec[row, R_OMEGA] = omega
        rec[row, R_PHI_REF] = phi_ref
        rec[row, R_OMEGA_REF] = omega_ref
        rec[row, R_UFF] = u_ff
        rec[row, R_U] = u
        rec[row, R_LATE_US] = (wake - deadline) / 1e3
        ints[L.K_TICKS] += 1  # published after the row is written: readers read rows < ticks
        work = L.now_ns(ts) - wake
        ints[L.K_WORK_NS] += work
        if work > ints[L.K_WORK_MAX_NS]:
            ints[L.K_WORK_MAX_NS] = work
        if ints[L.K_MAX_TICKS] > 0 and ints[L.K_TICKS] >= ints[L.K_MAX_TICKS]:
            break
        deadline += period
    vals[V_U] = 0.0  # a stopped loop commands nothing
    ints[L.K_CPU_NS] += L.thread_cpu_ns(ts) - cpu0
    ints[L.K_RUNNING] = 0


@dataclass(frozen=True)
class Realtime:
    """What the thread asked the OS for and what it got, in plain words."""

    sched_fifo: str
    affinity: str
    mlockall: str


def request_realtime(priority: int = 80, cpu: int | None = None, lock: bool = True) -> Realtime:
    """Call from the thread to be made real-time; each request that fails says why."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        fifo = f"granted (priority {priority})"
    except (PermissionError, OSError) as exc:
        fifo = f"refused: {exc.strerror or exc} (needs root or CAP_SYS_NICE / rtprio limit)"
    allowed = sorted(os.sched_getaffinity(0))
    target = allowed[-1] if cpu is None else cpu
    try:
        os.sched_setaffinity(0, {target})  # pid 0 = this thread on Linux
        aff = f"granted (CPU {target} of {allowed})"
    except OSError as exc:
        aff = f"refused: {exc.strerror or exc} (CPU {target} not in {allowed})"
    if not lock:
        mem = "not requested"
    else:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.mlockall(1 | 2) == 0:  # MCL_CURRENT | MCL_FUTURE: no page faults in the loop
            mem = "granted (current and future pages)"
        else:
            err = ctypes.get_errno()
            mem = f"refused: {os.strerror(err)} (needs CAP_IPC_LOCK or a larger `ulimit -l`)"
    return Realtime(fifo, aff, mem)


class TickBatch(NamedTuple):
    """`Runner.ticks_since`: rows of ticks first .. next-1, and how many before `first` were lost."""

    rows: np.ndarray
    first: int
    next: int
    lost: int


class Runner:
    """The control thread and its shared arrays; SIL when built with `sil=True`.

    The I/O side's whole interface to the loop: the mode (`position`, `scan`, `idle`), the gains
    (`set_gains`, `gains`), the measurement (`measured`, `stale_after`), the safe state (`fault`,
    `fault_code`, `clear_fault`, `inject_overrun`), and what the loop did (`recent_ticks`,
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
    ) -> None:
        self._setup = setup  # the plant's arrays; the gains live in `vals` from here on
        self.sil = sil
        self.realtime = realtime
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
        self, phi: float, omega: float, t_ns: int | None = None, sample_ns: int | None = None
    ) -> None:
        """Hardware mode: the I/O side writes the latest encoder angle and speed, when it
        arrived (CLOCK_MONOTONIC ns, default now; judged by the stale check) and, if known, when
        the MCU sampled it (the same clock; the law carries the angle forward from there at the
        measured speed). The arrival time is written last."""
        ints = self.ints
        ints[K_MEAS_SEQ] += 1  # odd: an update is being written (a seqlock; one writer)
        self.vals[V_PHI] = phi
        self.vals[V_OMEGA] = omega
        ints[K_SAMPLE_NS] = 0 if sample_ns is None else sample_ns
        ints[K_MEAS_SEQ] += 1
        ints[K_MEAS_NS] = time.monotonic_ns() if t_ns is None else t_ns

    @property
    def omega(self) -> float:
        """The latest measured speed, rad/s (SIL: the plant's)."""
        return float(self.vals[V_OMEGA])

    @property
    def measurement_age_s(self) -> float | None:
        """How old the newest measurement is (None before the first): the status's staleness."""
        t_ns = int(self.ints[K_MEAS_NS])
        return None if t_ns == 0 else (time.monotonic_ns() - t_ns) / L.NS

    def stale_after(self, seconds: float) -> None:
        """Hold the safe state when the newest measurement is older than this (0: never)."""
        self.ints[K_STALE_NS] = round(seconds * L.NS)

    # --- the safe state ----------------------------------------------------------------------------
    @property
    def fault(self) -> bool:
        return bool(self.ints[K_FAULT])

    @property
    def fault_code(self) -> LoopFault:
        return LoopFault(int(self.ints[K_FAULT]))

    @property
    def fault_after_measurement_s(self) -> float:
        """How long after the newest measurement the fault latched (the stale check's latency)."""
        return (int(self.ints[K_FAULT_NS]) - int(self.ints[K_FAULT_MEAS_NS])) / L.NS

    def clear_fault(self) -> None:
        self.ints[L.K_STREAK] = 0
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
            self.realtime_report = request_realtime()
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
