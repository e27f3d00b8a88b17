"""The 10 kHz control kernel: one numba nogil function that paces itself on absolute deadlines.

`control_loop` never returns to Python while it runs: it sleeps with
`clock_nanosleep(TIMER_ABSTIME)` (tvsd.control.latency.wait_tick), evaluates the robust law,
writes the command, and sends its own MCU frames (tvsd.control.link_tx); everything else goes
through the preallocated arrays of tvsd.control.words, which tvsd.control.runner owns.

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
measurement older than K_STALE_NS while the drive is commanded holds the safe state: the command
is 0 from the first tick past the limit, whatever the event loop is doing, and the kernel puts
PWM 0 on the wire itself (tvsd.control.link_tx). Whether that hold latches (FAULT_STALE, FAULT_GAP)
or resumes — late input from an MCU that sent every frame on time — is tvsd.control.hold's.

SIL: the plant kernel (tvsd.model.plant.advance, open loop) is stepped inside the same loop by the
real elapsed time with the command held since the previous tick, so the simulated scanner runs in
real time. Its state (tvsd.model.plant.state_array) carries the plant's time and delay ring across
ticks, so fixed-frequency effects and the delay stay continuous and a tick allocates nothing; a
`drift` effect runs over each call, not over the session.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tvsd.control import latency as L
from tvsd.control import layout as W
from tvsd.control.hold import check_input
from tvsd.control.law import robust_law
from tvsd.control.link_tx import link_stop, link_tick
from tvsd.control.scanning import ramp_toward, track
from tvsd.control.words import (
    FAULT_NONE,
    FAULT_OVERRUN,
    K_BUSY_NS,
    K_CHAIN_NS,
    K_DUE_NS,
    K_EXC_N,
    K_EXC_STEP_NS,
    K_EXC_T0_NS,
    K_FAULT,
    K_FAULT_NS,
    K_HB_NEXT_NS,
    K_HELD,
    K_MEAS_SEQ,
    K_SAMPLE_NS,
    K_STALE_NS,
    K_STREAK_LIMIT,
    MODE_IDLE,
    MODE_POSITION,
    MODE_SCAN,
    R_DT,
    R_LATE_US,
    R_OMEGA,
    R_OMEGA_REF,
    R_PHI,
    R_PHI_REF,
    R_T,
    R_U,
    R_UFF,
    V_ACCEL,
    V_DT,
    V_FF,
    V_G0,
    V_GD,
    V_GP,
    V_GR,
    V_MAXLAG,
    V_MODE,
    V_OMEGA,
    V_OMEGA_REF,
    V_PHI,
    V_PHI_REF,
    V_REF,
    V_U,
    V_UMAX,
)
from tvsd.model import params as P
from tvsd.model import plant as K

# The measured angle is carried forward at the measured speed from its sampling instant to each
# tick, at most this far, or up to the stale limit (K_STALE_NS) if that is longer: input younger
# than it is the law's to act on (tvsd.control.hold), so its angle must move on. Held at 10 ms
# while the law ran on to 40 ms (or a config's longer limit), the angle reference integrated on,
# slipped at +max_lag, and the late frames' true angle then put the shaft a turn-fraction ahead:
# a -max_lag slip the law paid back by slowing the drive (the spin scan's 18.9 rev/s for 20).
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
    ints: np.ndarray, vals: np.ndarray, ts: np.ndarray, held: tuple[float, float, int, int, int]
) -> tuple[float, float, int, int, int]:
    """(φ, ω, sample time, due time, chain start) as one consistent set, or `held` (the last
    one) if the I/O side is writing right now: it writes them between two increments of
    K_MEAS_SEQ. Never a retry loop: the writer may be preempted mid-write by this very thread
    (SCHED_FIFO on its CPU), and a spinning reader would then wait for the scheduler to move it
    (measured: 30–45 ms stalls).
    The clock call between the reads is opaque to the compiler, so it re-loads the sequence
    word rather than assuming nobody else writes it."""
    seq = ints[K_MEAS_SEQ]
    phi, omega, sample_ns = vals[V_PHI], vals[V_OMEGA], ints[K_SAMPLE_NS]
    due_ns, chain_ns = ints[K_DUE_NS], ints[K_CHAIN_NS]
    L.now_ns(ts)
    if seq % 2 == 0 and ints[K_MEAS_SEQ] == seq:
        return phi, omega, sample_ns, due_ns, chain_ns
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
    tx: np.ndarray,
    mutex: np.ndarray,
    txbuf: np.ndarray,
) -> None:
    """Run ticks until ints[K_STOP] (or K_MAX_TICKS); all state lives in the arrays (`tx`,
    `mutex`, `txbuf`: the MCU port's shared write side and the kernel's frame buffer, for
    tvsd.control.link_tx)."""
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
    measurement = (vals[V_PHI], vals[V_OMEGA], ints[K_SAMPLE_NS], ints[K_DUE_NS], ints[K_CHAIN_NS])
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
        phi, omega, sample_ns, due_ns, chain_ns = measurement
        if sample_ns > 0:
            # The encoder was read at sample_ns, up to a frame period (+ the link) ago: the law
            # sees the angle now. Held, ε would grow by ω·period between frames (0.063 rad at
            # 2.5 kHz and 25 rev/s: G0·ε runs over tanh's whole range) and the command would saw.
            age = min(max(wake - sample_ns, 0), max(EXTRAPOLATE_MAX_NS, ints[K_STALE_NS]))
            phi += omega * (age / 1e9)
        mode = int(vals[V_MODE])
        umax = vals[V_UMAX]
        u_ff = 0.0
        if ints[K_FAULT] == FAULT_NONE:
            if ints[L.K_STREAK] >= ints[K_STREAK_LIMIT]:
                ints[K_FAULT] = FAULT_OVERRUN
                ints[K_FAULT_NS] = wake
                ints[K_HELD] = 0
                ints[K_HB_NEXT_NS] = wake  # the next heartbeat, with PWM 0 behind it, goes now
            elif check_input(ints, wake, mode != MODE_IDLE, due_ns, chain_ns):
                # late input, the MCU alive throughout: resume from where the shaft is now, at
                # its speed (the references tracked the stale measurement during the hold)
                phi_ref = phi
                omega_ref = omega if mode == MODE_SCAN else 0.0
        if ints[K_FAULT] != 0 or mode != MODE_SCAN:
            ints[K_EXC_N] = 0  # the excitation is for scanning only, and ends with any fault
        d_rps, d_u = _excitation(ints, exc, wake) if ints[K_EXC_N] > 0 else (0.0, 0.0)
        if ints[K_FAULT] != 0 or ints[K_HELD] != 0 or mode == MODE_IDLE:
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
        link_tick(ints, tx, mutex, txbuf, ts, wake)
        work = L.now_ns(ts) - wake
        ints[L.K_WORK_NS] += work
        if work > ints[L.K_WORK_MAX_NS]:
            ints[L.K_WORK_MAX_NS] = work
        if ints[L.K_MAX_TICKS] > 0 and ints[L.K_TICKS] >= ints[L.K_MAX_TICKS]:
            break
        deadline += period
    vals[V_U] = 0.0  # a stopped loop commands nothing
    link_stop(ints, tx, mutex)
    ints[L.K_CPU_NS] += L.thread_cpu_ns(ts) - cpu0
    ints[L.K_RUNNING] = 0
