"""SIL bridge: the drive model turns the virtual MCU's inputs, the MCU's PWM turns the model.

The plant (tvsd.model.plant.advance, open loop) is stepped in chunks (1 ms by default) on the
virtual MCU's manual clock. Each chunk applies the MCU's PWM duty × drive voltage (the host sets
the PWM through ``McuLink.send_pwm``): paced, each PWM frame from the moment it arrived, to the
control step (0.1 ms), as the motor integrates every one of a 2 kHz (ATmega) stream; stepped as fast as
possible (:meth:`run_until`), the duty of the chunk's start, held. Then it feeds the MCU what
the sensors would see during the chunk, with the shaft angle interpolated linearly in time:

- the encoder count (``counts_per_rev`` from ``sil.measurement.encoder_counts_per_rev``) at the
  chunk's end and at each optical crossing, and in between linear at every firmware control tick
  (0.1 ms, when the firmware samples it: ``VirtualMcu.set_shaft`` on the manual clock);
- the zero pulse at each crossing of 2πk (``VirtualMcu.set_shaft``);
- the optical pulse at each crossing of 2πk + β, β being the SA angle of the configured target
  (φ, γ, range) by tvsd.scan.geometry;
both latched at the interpolated time rounded to the MCU timer (62.5 ns).

Pacing: :meth:`McuPlant.start` runs a thread that keeps the manual clock at ``speed`` × the
monotonic clock (so a host link, whose heartbeats and timeouts run on wall time, sees a steady
clock, ``speed`` times faster than real time); :meth:`run_until` steps as fast as it can.

Benchmark: tvsd.sim.clock_sync_bench (``tvsctl bench --only mcu_sil``) runs 60 s of SIL at 10 ×
real time with the link's heartbeats going and reports how far the link's ClockSync maps MCU
ticks from the truth (the pacing line).

The plant's state (tvsd.model.plant.state_array) carries its time and delay ring from chunk to
chunk, so resonance phase and transport delay run on; a `drift` effect runs over each chunk. The
encoder holds its count between feeds.

History: every chunk also goes into a bounded ring (``history_s``, 10 s of 1 ms chunks: 0.3 MB)
of (end time, mean disturbance acceleration over the chunk, ω and φ at its end), written by
:meth:`McuPlant.step` and read from any thread (:meth:`McuPlant.history`, :meth:`McuPlant.at_host`):
what the SIL IMU twins feel (tvsd.sim.imu_motion.PlantMotion). The disturbance is the kernel's
O_DIST_MEAN, the mean over the chunk of the acceleration about the SA axis that the IMU measures
(the vibration Δv with its sign in J·ω̇ = … − J·Δv, plus the effect torques / J): unlike the state's
S_NOISE (the OU model's current value, 0 under the literal SDE), it exists for every vibration
model, and a chunk mean is the box-car a 1 kHz sensor would see.
"""

from __future__ import annotations

import bisect
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

import numpy as np
from numpy.typing import ArrayLike

from tvsd.causes import parse_effects
from tvsd.config import Config, VibrationConfig
from tvsd.control.setup import Setup
from tvsd.model import plant as K
from tvsd.scan.geometry import aim, doe_b_target
from tvsd.scan.settings import ScanSettings
from tvsd.sim import runs
from tvsd.sim.mcu_wire import WIRE_ALLOWANCE_S
from tvsd.sim.record import substeps_for
from tvsd.sim.virtual_mcu import PULSE_OPTICAL, VirtualMcu


@dataclass(frozen=True)
class Target:
    """Where the positioning laser points: the DoE B convention (PL angles and range)."""

    phi_deg: float = 30.0
    gamma_deg: float = 0.0
    range_m: float = 2.0


def target_beta(cfg: Config, target: Target) -> float:
    """β (rad) of the laser spot on the target: the inverse of eqs. (1)–(3), stepper-quantised."""
    settings = ScanSettings(baseline_m=cfg.geometry.baseline_m)
    xyz = doe_b_target(target.phi_deg, target.gamma_deg, target.range_m, settings.baseline_m)
    return aim(*xyz, settings).beta


def crossings(a0: float, a1: float, offset: float) -> list[float]:
    """Fractions f in (0, 1] where a0 + f·(a1 − a0) crosses 2πk + offset, in time order."""
    if a1 == a0:
        return []
    lo, hi = sorted((a0, a1))
    first = math.floor((lo - offset) / math.tau) + 1
    last = math.floor((hi - offset) / math.tau)
    fr = [(k * math.tau + offset - a0) / (a1 - a0) for k in range(first, last + 1)]
    return sorted(f for f in fr if 0.0 < f <= 1.0)


@dataclass
class Pacing:
    """How closely the paced thread kept the manual clock on speed × wall time."""

    wall0: float = math.nan  # time.monotonic() when pacing started
    sim0: float = 0.0  # sim time then
    lag_sum_s: float = 0.0  # sum over feeds of (line − sim time reached), sim seconds
    lag_max_s: float = 0.0
    feeds: int = 0

    def truth_host(self, sim_s: float, speed: float) -> float:
        """Host time at which the pacing line reaches sim_s."""
        return self.wall0 + (sim_s - self.sim0) / speed


@dataclass(frozen=True)
class PlantHistory:
    """Chunks of the plant in time order: chunk k covers (t[k] − chunk_s, t[k]]."""

    t: np.ndarray  # sim s, end of each chunk
    disturbance: np.ndarray  # rad/s², mean acceleration about the SA axis over the chunk
    omega: np.ndarray  # rad/s at t
    phi: np.ndarray  # rad at t (unwrapped)

    def at(self, t_sim: ArrayLike) -> PlantHistory:
        """Values at sim times: the disturbance of the chunk holding each time, ω and φ linear
        between chunk ends. Times before the first chunk or after the last hold the nearest."""
        s = np.asarray(t_sim, dtype=np.float64)
        if self.t.size == 0:
            zero = np.zeros_like(s)
            return PlantHistory(s, zero, zero, zero)
        i = np.clip(np.searchsorted(self.t, s, side="left"), 0, self.t.size - 1)
        return PlantHistory(
            s, self.disturbance[i], np.interp(s, self.t, self.omega), np.interp(s, self.t, self.phi)
        )


@dataclass
class McuPlant:
    """The drive model wired to a virtual MCU (manual clock). Use as a context manager."""

    cfg: Config
    target: Target = field(default_factory=Target)
    speed: float = 1.0
    chunk_s: float = 1e-3
    vibration: VibrationConfig | None = None
    initial_state: np.ndarray | None = None
    record: bool = True  # keep the (t, angle) of every encoder update, for tests
    library: Path | None = None
    history_s: float = 10.0  # length of the history ring (sim seconds)
    # paced: how long past its watchdog's edge the firmware's cut waits for a heartbeat the pty
    # hands over late (tvsd.sim.mcu_wire)
    wire_allowance_s: float = WIRE_ALLOWANCE_S

    def __post_init__(self) -> None:
        if not self.speed > 0:
            raise ValueError(f"speed must be > 0, got {self.speed}")
        # substeps as the offline simulator takes them: a fast winding (plant.L 0.1 mH) would
        # diverge at one RK4 step per tick, and the SIL process never answer its start
        effects = parse_effects(self.cfg.sil_or_default.effects)
        self.setup = Setup.from_config(
            self.cfg, effects=effects, vibration=self.vibration, substeps=substeps_for(self.cfg, effects)
        )
        self.counts_per_rev = self.cfg.sil_or_default.measurement.encoder_counts_per_rev
        self.beta = target_beta(self.cfg, self.target)
        self._n = max(1, round(self.chunk_s / self.setup.dt))
        self.chunk_s = self._n * self.setup.dt
        self._state = K.state_array(self.setup.dt)
        if self.initial_state is not None:
            self._state[: len(self.initial_state)] = self.initial_state
        self._u = np.zeros(self._n)
        self._pwm_pending: deque[tuple[float, float]] | None = None  # paced: (sim time, duty) to apply
        self._duty = 0.0  # the duty in force at the end of the last chunk (paced)
        self._seed = self.setup.seed  # the kernel reseeds numpy when seed >= 0: only once
        self.t = 0.0  # sim time of the plant (= the MCU's manual clock after each chunk)
        self._chunks = 0  # t = chunks × chunk_s, not a running sum (no drift across the timer's ticks)
        self.mcu = VirtualMcu(
            counts_per_rev=self.counts_per_rev,
            drive_volts=self.cfg.drive.u_max_v,
            clock="manual",
            library=self.library,
            wire_allowance_s=self.wire_allowance_s,
        )
        self.shaft_t: list[float] = []
        self.shaft_angle: list[float] = []
        self.optical_times: list[float] = []  # exact crossing times, before the timer rounds them
        self.pacing = Pacing()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        # history ring: row 0 end time, 1 disturbance, 2 ω, 3 φ; entry j is chunk j (0: the start)
        self._hist = np.zeros((4, max(2, round(self.history_s / self.chunk_s))))
        self._hist_n = 0  # entries written so far
        self._hist_t = 0.0  # end time of the newest entry
        self._hist_lock = threading.Lock()
        self._remember(0.0)
        self._feed(0.0, self.angle)

    @property
    def angle(self) -> float:
        return float(self._state[K.S_PHI])

    @property
    def omega(self) -> float:
        return float(self._state[K.S_OMEGA])

    def angle_at(self, t_s: float) -> float:
        """The angle the encoder holds at sim time t_s (the last feed at or before it, as the
        MCU's timer sees times: to the nearest 62.5 ns tick)."""
        i = bisect.bisect_right(self.shaft_t, t_s + 0.5 / self.mcu.clock_hz) - 1
        return self.shaft_angle[max(i, 0)]

    # ---- stepping ------------------------------------------------------------------------
    def step(self) -> None:
        """One chunk: the MCU's motor voltage over it (paced: each PWM change from its arrival;
        else the present one held), then the sensors fed."""
        t0, a0 = self.t, self.angle
        if self._pwm_pending is None:
            self._u[:] = self.mcu.motor_volts
        else:
            self._chunk_volts(t0)
        sub = self.setup.substeps
        dist = K.advance(
            self._state,
            self.setup.plant,
            self.setup.effects,
            self.setup.vibration,
            self.setup.dt / sub,
            self._n * sub,
            self._u,
            sub,
            self._seed,
        )
        self._seed = -1
        self._chunks += 1
        t1, a1 = self._chunks * self.chunk_s, self.angle
        for f in crossings(a0, a1, self.beta):
            t_o = t0 + f * (t1 - t0)
            self._feed(t_o, a0 + f * (a1 - a0))  # zero pulses before t_o, in time order
            self.mcu.pulse(PULSE_OPTICAL, t_o)
            self.optical_times.append(t_o)
        self._feed(t1, a1)
        self.t = t1
        self._remember(dist)

    def _chunk_volts(self, t0: float) -> None:
        """Each control step of the chunk gets the duty in force at its start: the host's PWM
        frames apply from their arrival on the pacing line, so a 2 kHz PWM stream is not sampled
        once per chunk. Frames that came while earlier chunks were being stepped (late: the pty
        hands each millisecond's frames over at once, so their arrival times cannot space them)
        share this chunk's steps in their order: the motor integrates each duty's volt-seconds,
        and the last one alone lost the others' (on the SIL daemon every chunk found its frames
        late, two per chunk at the ATmega's 2 kHz: the applied voltage was the second frame's,
        0.3-0.5 V rms from the recording's u below 20 Hz). A change the firmware made itself (its
        watchdog's cut) shows in the duty now once no frame is pending, and applies from the
        chunk's start."""
        changes, duty_now = self.mcu.pwm_changes()
        pending = self._pwm_pending
        assert pending is not None
        if changes:
            sim = self.host_to_sim([t for t, _ in changes])
            pending.extend(zip(sim.tolist(), (d for _, d in changes), strict=True))
        elif not pending:
            self._duty = duty_now
        dt, n = self.setup.dt, self._n
        late: list[float] = []
        while pending and pending[0][0] <= t0 + 0.5 * dt:
            late.append(pending.popleft()[1])
        for k in range(n):
            if k > 0 and pending and pending[0][0] <= t0 + (k + 0.5) * dt:
                late = []  # a frame on time: the steps from here are its
                while pending and pending[0][0] <= t0 + (k + 0.5) * dt:
                    self._duty = pending.popleft()[1]
            elif late:
                self._duty = late[k * len(late) // n]
            self._u[k] = self._duty * self.mcu.drive_volts

    # ---- history ring ---------------------------------------------------------------------
    def _remember(self, disturbance: float) -> None:
        with self._hist_lock:
            j = self._hist_n % self._hist.shape[1]
            t = self._chunks * self.chunk_s
            self._hist[:, j] = (t, disturbance, self.omega, self.angle)
            self._hist_n += 1
            self._hist_t = t  # last: covered_host() never runs ahead of the ring

    def history(self, since_sim: float = -math.inf) -> PlantHistory:
        """The ring's chunks from the one holding sim time `since_sim` (or the oldest kept) to
        the newest; a copy, safe to call from any thread while the plant runs."""
        with self._hist_lock:
            size, n = self._hist.shape[1], self._hist_n
            first = max(n - size, 0)
            if math.isfinite(since_sim):  # entry j ends at j·chunk_s: the one holding since_sim
                first = min(max(first, math.ceil(since_sim / self.chunk_s - 1e-9)), n - 1)
            idx = np.arange(first, n) % size
            data = self._hist[:, idx]
        return PlantHistory(data[0], data[1], data[2], data[3])

    def host_to_sim(self, t_host: ArrayLike) -> np.ndarray:
        """Sim times of host (time.monotonic) times on the pacing line (inverse of
        Pacing.truth_host); before the pacing thread starts, the plant's current time."""
        t = np.asarray(t_host, dtype=np.float64)
        p = self.pacing
        wall0 = p.wall0
        if math.isnan(wall0):
            return np.full_like(t, self.t)
        return p.sim0 + (t - wall0) * self.speed

    def _host_to_sim_s(self, t_host: float) -> float:
        """host_to_sim for one time; NaN before the pacing starts."""
        p = self.pacing
        return p.sim0 + (t_host - p.wall0) * self.speed

    def covered_host(self) -> float:
        """Host time up to which the ring holds the plant (its newest chunk's end on the pacing
        line: up to a chunk and a wake-up behind the line's present); NaN before pacing starts."""
        p = self.pacing
        return p.wall0 + (self._hist_t - p.sim0) / self.speed

    def at_host(self, t_host: ArrayLike) -> PlantHistory:
        """The plant at host times (PlantHistory.at: held beyond the ring and past the plant)."""
        s = self.host_to_sim(t_host)
        return self.history(float(np.min(s)) if s.size else -math.inf).at(s)

    def _feed(self, t_s: float, angle: float) -> None:
        self.mcu.set_shaft(angle, t_s)
        if self.record:
            self.shaft_t.append(t_s)
            self.shaft_angle.append(angle)

    def run_until(self, t_s: float) -> None:
        """Step as fast as the machine allows until the plant reaches t_s (sim seconds)."""
        while self.t + 0.5 * self.chunk_s < t_s:
            self.step()

    # ---- pacing thread --------------------------------------------------------------------
    def start(self) -> None:
        """Run the plant in a thread at `speed` × real time until :meth:`stop`."""
        if self._thread is not None:
            return
        self._stop.clear()
        self.mcu.log_pwm()
        self._pwm_pending, self._duty = deque(), self.mcu.pwm_duty
        self.mcu.rx_timeline = self._host_to_sim_s  # host bytes enter the core at their arrival
        self.mcu.core_to_host = lambda sim_s: self.pacing.truth_host(sim_s, self.speed)
        self._thread = threading.Thread(target=self._paced, name="mcu-plant", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self.mcu.rx_timeline = None  # the clock holds now: host bytes go in as they come
        self.mcu.core_to_host = None
        self.mcu.flush_rx()
        if self._error is not None:
            raise RuntimeError("the paced plant thread failed") from self._error

    def _paced(self) -> None:
        p = self.pacing
        p.wall0, p.sim0 = time.monotonic(), self.t
        period = self.chunk_s / self.speed
        try:
            while not self._stop.is_set():
                line = p.sim0 + self.speed * (time.monotonic() - p.wall0)
                while self.t + self.chunk_s <= line:
                    self.step()
                    self.mcu.write_out()  # its state frames out now, not when the pump next runs
                lag = line - self.t
                p.lag_sum_s += lag
                p.lag_max_s = max(p.lag_max_s, lag)
                p.feeds += 1
                # pacing, not synchronisation: wake for the next chunk boundary
                self._stop.wait(max(0.0, (self.t + self.chunk_s - line) / self.speed) + 0.1 * period)
        except BaseException as exc:  # reported by stop()
            self._error = exc

    # ---- lifetime -------------------------------------------------------------------------
    def close(self) -> None:
        try:
            self.stop()
        finally:
            self.mcu.close()

    def __enter__(self) -> McuPlant:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def steady_state(
    cfg: Config, volts: float, seconds: float = 60.0, vibration: VibrationConfig | None = None
) -> np.ndarray:
    """The plant's state after `seconds` at a constant voltage (angle reset to 0): a start at
    constant speed, so a revolution's β is not skewed by acceleration."""
    effects = parse_effects(cfg.sil_or_default.effects)
    setup = Setup.from_config(cfg, effects=effects, vibration=vibration, substeps=substeps_for(cfg, effects))
    state = K.state_array(setup.dt)
    runs.open_loop(
        setup, np.full(round(seconds / setup.dt), volts), decim=round(seconds / setup.dt), state=state
    )
    state[K.S_PHI] = 0.0
    return state
