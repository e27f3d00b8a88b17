"""The drive as the daemon sees it: the MCU link, on hardware or on the SIL plant.

Both backends speak the same bytes through the same McuLink (tvsd/hw/mcu/link.py): `hardware`
opens the configured serial port; `sil` opens the pty of the virtual MCU that the SIL devices'
process runs (tvsd/sim/sil_process.py: the drive model, tvsd/sim/mcu_plant.py, paced at real
time, started by the daemon, tvsd.daemon.app). The daemon cannot tell them apart but for `inject`
(SIL fault injection) and where the SIL scene puts the laser spot, both told to that process.

Every state frame (cfg.mcu.exchange_hz) hands the control thread the encoder angle, a speed over
the last SPEED_WINDOW_S of frames, the frame's arrival time and its sampling instant on the host's
clock (the law carries the angle forward from there). 2 ms: one frame apart, the 8192-count
encoder would quantise 25 rev/s to 1.2 % (2 ms: 0.24 %, for 1 ms of delay, nothing against the
drive's 2.4 s time constant). All of it on the link's I/O thread (tvsd/hw/mcu/io_thread.py), never
the event loop: after each batch of states read together it sends the control thread's latest
command as the PWM duty, and keeps what it sent (`sent_volts`: the command the motor really got,
held between frames, for the point stream's drive model). So the exchange with the MCU runs at
the state rate (2 kHz on the ATmega328P, 10 kHz on the STM32F405: cfg.mcu.board), one control
tick (0.1 ms) behind at most, and the 10 kHz kernel never waits for it.

Safety, in three layers: the control thread holds PWM 0 once the newest state frame is older than
cfg.mcu.link_timeout_ms (40 ms); it latches that (LoopFault.STALE) if no frame reaches the present
within cfg.mcu.link_lost_ms (500 ms), when the link reports the loss too (on_link(False)), or at
once if the frames that come show a gap (LoopFault.GAP); complete but late frames resume control
(tvsd.control.hold, tvsd.daemon.frame_chain); the firmware cuts PWM and laser watchdog_ms after the last
heartbeat. Heartbeats go every watchdog_ms / 4 from the control
kernel itself (Runner.attach_link, tvsd.control.link_tx: no GIL needed, so no Python code holding
it can starve them), and PWM 0 behind each while the loop holds its safe state: a dead control
loop means no heartbeat, and the firmware cuts. (Before the handshake, and where no runner is
given, the link's I/O thread sends them while the kernel's tick count moves: `liveness`.)
Under --realtime that thread runs SCHED_FIFO IO_THREAD_PRIORITY: below the control thread (80),
above the event loop (40, tvsd.daemon.main).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tvsd.config import Config
from tvsd.control.runner import Runner
from tvsd.daemon.frame_chain import FrameChain
from tvsd.errors import ConfigError, DeviceError, UsageError
from tvsd.hw.mcu.events import FaultEvent, PulseEvent
from tvsd.hw.mcu.io_thread import IO_THREAD_PRIORITY
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.messages import McuStats
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.spec import CONTROL_TICK_HZ
from tvsd.hw.mcu.steppers import Steppers

if TYPE_CHECKING:
    from tvsd.sim.sil_devices import SilDevices

SPEED_WINDOW_S = 2e-3
MEAN_MAX_TICKS = 40  # a frame averages at most 4 ms of ticks (the longest exchange period)
SENT_HISTORY_S = 0.8  # PWM frames kept, in s of exchanges (the point stream looks back < 0.5 s)
SENT_SLACK = 64  # of them not read back: the I/O thread may be overwriting them meanwhile
SIL_TARGET_RANGE_M = 2.0  # the SIL scene: a surface 2 m from the PL (tvsd/sim/scene.py)
SIL_FAULTS = ("link_loss", "link_restore")
FIRMWARE_STATS_PERIOD_S = 1.0  # how often the status's firmware counters are asked for (27 B back)
FIRMWARE_COUNTERS = ("rx_overflows", "ticks_dropped", "watchdog_expiries")


def spot_beta(cfg: Config, phi: float, gamma: float) -> float:
    """β of the laser spot at φ, γ (rad) on the SIL scene's surface: the McuPlant's own target."""
    from tvsd.sim.mcu_plant import Target, target_beta

    return target_beta(cfg, Target(math.degrees(phi), math.degrees(gamma), SIL_TARGET_RANGE_M))


class DriveLink:
    """Encoder in, PWM out, pulses and MCU faults up. Start with `await start()`."""

    def __init__(
        self,
        cfg: Config,
        runner: Runner,
        backend: str,
        *,
        on_pulse: Callable[[PulseEvent], None],
        on_link: Callable[[bool], None],
        on_fault: Callable[[FaultEvent], None],
        state_dir: Path | None = None,
    ) -> None:
        if backend not in ("hardware", "sil"):
            raise ConfigError(f"devices.mcu: {backend!r} is not a backend; use hardware or sil")
        self.cfg, self.runner, self.backend = cfg, runner, backend
        self.on_pulse, self.on_link, self.on_fault = on_pulse, on_link, on_fault
        self.state_dir = state_dir  # runtime state (the socket's dir): the tty workers' record
        m = cfg.mcu
        if backend == "sil":
            sil_counts = cfg.sil_or_default.measurement.encoder_counts_per_rev
            if sil_counts != m.encoder_counts_per_rev:
                raise ConfigError(
                    f"mcu.encoder_counts_per_rev is {m.encoder_counts_per_rev} but the SIL profile's "
                    f"encoder has {sil_counts}: make them equal"
                )
        self.rad_per_count = 2.0 * math.pi / m.encoder_counts_per_rev
        self.state_div = max(1, min(40, round(CONTROL_TICK_HZ / m.exchange_hz)))
        self.duty_per_volt = 1.0 / cfg.drive.u_max_v
        n = max(2, round(SPEED_WINDOW_S * CONTROL_TICK_HZ / self.state_div) + 1)
        self._ticks = np.zeros(n, dtype=np.int64)  # ring of the last frames: MCU ticks, angle
        self._phi = np.zeros(n)
        self._frames = 0
        self.chain = FrameChain()  # the state frames' due times, for the late-input hold
        self._sent_n = math.ceil(SENT_HISTORY_S * CONTROL_TICK_HZ / self.state_div)  # 8000 at 10 kHz
        self._sent_host = np.zeros(self._sent_n)  # ring of the PWM frames sent: host time, volts
        self._sent_volts = np.zeros(self._sent_n)
        self._sent = 0
        # ring of the state frames received, for the recording's `states` channel: MCU ticks,
        # encoder count, the sampling instant on the host's clock (NaN before the clock sync)
        self._st_ticks = np.zeros(self._sent_n, dtype=np.int64)
        self._st_enc = np.zeros(self._sent_n, dtype=np.int64)
        self._st_host = np.zeros(self._sent_n)
        self._states = 0
        self._frame_tick = 0  # the runner's tick count when the last PWM frame was made
        self._pwm_due = False  # a state came in the batch being handled: answer it with a PWM frame
        # True from the handshake's heartbeat round trip (which arms the firmware) until closing
        # (PWM 0 is then the last duty sent). The state frames stream from the MCU's boot: a PWM
        # frame answering them before the first heartbeat was refused (no_heartbeat) at every start
        self._answering = False
        self._pwm_lock = threading.Lock()
        self.clock_hz = 16_000_000
        self.sil: SilDevices | None = None  # SIL: the devices' process, running the virtual MCU
        self.link: McuLink | None = None
        self.steppers: Steppers | None = None
        self.last_state_host = math.nan
        self._firmware: tuple[float, McuStats] | None = None  # (when, the MCU's stats reply)
        self._stats_task: asyncio.Task[None] | None = None

    # --- life cycle -----------------------------------------------------------------------------
    async def start(self, sil: SilDevices | None = None) -> None:
        """Open the link (SIL: to the virtual MCU of `sil`, the running devices' process, whose
        scene aims where the daemon starts), identify, configure, home the axes."""
        m = self.cfg.mcu
        port = m.port
        if self.backend == "sil":
            if sil is None or not sil.port:
                raise DeviceError("devices.mcu is sil but the SIL devices' process runs no MCU")
            self.sil = sil
            port = sil.port
        link = McuLink(
            replace(m, port=port),
            on_state=self._on_state,
            on_batch=self._send_pwm,
            on_pulse=self.on_pulse,
            on_fault=self.on_fault,
            on_link=self.on_link,
            on_stepper=self._on_stepper,
            on_refused=self._on_refused,
            liveness=lambda: self.runner.ticks,
            # (getattr: a board check in the tests runs without a runner)
            io_priority=IO_THREAD_PRIORITY if getattr(self.runner, "realtime", False) else None,
            shared_tx=getattr(self.runner, "tx", None),  # the kernel writes the heartbeats
            state_dir=self.state_dir,
        )
        self.link = link  # state frames may come during the handshake
        try:
            await link.__aenter__()
        except BaseException:
            self.link = None
            raise
        with self._pwm_lock:  # the ping's answer came: the firmware is armed, PWM is taken
            self._answering = True
        assert link.identity is not None
        reported = link.spec.boards.get(link.identity.board, f"unknown ({link.identity.board})")
        problem = m.board_problem(reported, sil=self.backend == "sil")
        if problem is not None:
            self.link = None
            await link.close()
            raise DeviceError(problem)
        self.clock_hz = link.identity.clock_hz
        if hasattr(self.runner, "attach_link"):  # heartbeats from the nogil kernel from now on
            hb_id, pwm_id = link.message_id("heartbeat"), link.message_id("pwm_set")
            self.runner.attach_link(m.heartbeat_period_s, link.spec.sync, hb_id, pwm_id)
            link.kernel_heartbeats(True)
        link.send_config(watchdog_ms=m.watchdog_ms, state_div=self.state_div, max_on_ms=0)
        self.runner.stale_after(m.link_timeout_ms * 1e-3, m.link_lost_ms * 1e-3 if m.late_input_hold else 0.0)
        await self._await_first_state(link)
        self.steppers = Steppers(link)
        for axis in ("phi", "gamma"):
            self.steppers.home(axis)
        self._stats_task = asyncio.create_task(self._poll_firmware_stats(link), name="mcu-stats")

    async def _await_first_state(self, link: McuLink) -> None:
        """Return once a state frame has reached the control thread. A command given before any
        measurement latches STALE at once (tvsd.control.hold: there is no last frame to hold
        from), and on a loaded machine the first frame can reach the host after the handshake's
        answers do (CI of 0efd0f5: test_late_input's first command latched STALE). The daemon
        accepts commands only after start, so start waits: at most mcu.link_lost_ms, the bound
        within which no frame at all means the link is lost."""
        bound_ms = self.cfg.mcu.link_lost_ms
        deadline = time.monotonic() + bound_ms * 1e-3
        while math.isnan(self.last_state_host):  # set after the frame is handed to the runner
            if time.monotonic() > deadline:
                await self.close()  # the kernel's heartbeats detached too, PWM 0 and laser off
                raise DeviceError(
                    f"the MCU on {link.settings.port} answered the handshake but sent no state frame "
                    f"within {bound_ms:g} ms (mcu.link_lost_ms): its firmware does not stream the "
                    "encoder (another build?) or the port's input is lost: flash the image built from this "
                    "checkout (make -C firmware; hil/README.md), or raise mcu.link_lost_ms on a slow link"
                )
            await asyncio.sleep(0.002)

    async def _poll_firmware_stats(self, link: McuLink) -> None:
        """The firmware's own counters for the status (its watchdog expiries among them: a fault
        frame can be lost on the way, the count cannot)."""
        while True:
            # no answer this time (link lost, or closing): the status shows the age
            with contextlib.suppress(DeviceError):
                self._firmware = (time.monotonic(), await link.request_stats())
            await asyncio.sleep(FIRMWARE_STATS_PERIOD_S)

    async def close(self) -> None:
        """PWM 0 and laser off on the wire (the firmware's watchdog would do it too), then close."""
        if self._stats_task is not None:
            self._stats_task.cancel()
            self._stats_task = None
        if self.link is not None:
            if hasattr(self.runner, "detach_link"):
                self.runner.detach_link()
            with self._pwm_lock:  # the I/O thread sends no duty after this 0
                self._answering = False
                self.link.send_pwm(0.0)
            self.link.send_laser(False)
            self.link.flush()
            await self.link.close()
            self.link = None
        self.sil = None  # its owner (tvsd.daemon.app) ends the process

    # --- the exchange (the link's I/O thread: the measurement's one writer) ------------------------
    def _on_state(self, s: StateSample) -> None:
        i = self._frames % len(self._ticks)
        phi = s.encoder * self.rad_per_count
        self._ticks[i], self._phi[i] = s.mcu_ticks, phi
        self._frames += 1
        j = (self._frames - min(self._frames, len(self._ticks))) % len(self._ticks)  # oldest kept
        dt = (s.mcu_ticks - int(self._ticks[j])) / self.clock_hz
        omega = (phi - float(self._phi[j])) / dt if dt > 0 else self.runner.omega
        # When the MCU sampled it, on the host's clock: the law carries the angle forward from
        # there. Unknown before the clock sync, and for a frame placed by the fit alone.
        sampled = self.to_host(s.mcu_ticks) if s.exact else math.nan
        sample_ns = round(sampled * 1e9) if math.isfinite(sampled) else None
        k = self._states % self._sent_n
        self._st_ticks[k], self._st_enc[k], self._st_host[k] = s.mcu_ticks, s.encoder, sampled
        self._states += 1
        arrival = round(s.host_time * 1e9)
        due = self.chain.due(s, arrival, self.clock_hz, self.state_div)
        self.runner.measured(phi, omega, arrival, sample_ns, due_ns=due, chain_ns=self.chain.chain_ns)
        self.last_state_host = s.host_time
        self._pwm_due = True

    def _send_pwm(self) -> None:
        """After a batch of states (on_batch): one PWM frame for all of them. A late thread reads
        several states at once, and answering each would burst frames into the MCU's receive
        buffer (the ATmega's holds ~5: heartbeats were lost, and its watchdog cut, in simavr
        under load, tests/test_mcu_avr.py's finding)."""
        link = self.link
        if not self._pwm_due or link is None:
            return
        self._pwm_due = False
        duty = max(-1.0, min(1.0, self._exchange_mean() * self.duty_per_volt))
        with self._pwm_lock:
            if not self._answering or not link.send_pwm(duty):
                return
        i = self._sent % self._sent_n
        self._sent_host[i], self._sent_volts[i] = time.monotonic(), duty / self.duty_per_volt
        self._sent += 1

    def _exchange_mean(self) -> float:
        """The law's command averaged over the ticks since the last PWM frame (at most
        MEAN_MAX_TICKS), the interval the previous frame's duty was held.

        The law ticks at 10 kHz, the frames go at the exchange rate (2 kHz on the ATmega) or once
        per batch of states (the SIL pty hands them over each millisecond): the last tick alone
        aliased the command's tick-to-tick swing (each new speed estimate moves Gd·tanh(ε̇)) into
        the applied voltage, which the recording's u (the 1 ms mean of the ticks) does not show.
        On the SIL daemon's identify runs the two differed by 2.1 V rms below 20 Hz (the mean of
        the last 5 ticks only: 0.5 V), and the doctor named a clip, a resonance, coloured noise or
        negative damping for it; with this mean 0.10 V at a steady 2 ms lag
        (docs/measurements/doctor-method.md, model doctor
        step 8). A command of exactly 0 is the loop's safe state (fault, idle): sent as 0 at
        once, not averaged with the ticks before it."""
        end = self.runner.ticks
        n = min(end - self._frame_tick, MEAN_MAX_TICKS)  # < 1: a new runner, or no tick since
        self._frame_tick = end
        if self.runner.command == 0.0:
            return 0.0
        if n < 1:
            return float(self.runner.command)
        return float(self.runner.recent_ticks(n)["u"].mean())

    def sent_since(self, seq: int) -> tuple[np.ndarray, np.ndarray, int]:
        """The PWM frames sent from number `seq` on, oldest first: host times (time.monotonic),
        volts, and the number to ask from next time. Frames the ring overwrote before the call
        (more than 0.8 s of them, less the slack the I/O thread may be writing) are skipped."""
        end = self._sent  # one read: rows below it are written
        first = min(max(seq, end - (self._sent_n - SENT_SLACK)), end)
        idx = np.arange(first, end) % self._sent_n
        return self._sent_host[idx], self._sent_volts[idx], end

    def states_since(self, seq: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """The state frames received from number `seq` on, oldest first (as `sent_since`): MCU
        ticks, encoder counts, sampling instants on the host's clock (time.monotonic; NaN before
        the clock sync), and the number to ask from next time."""
        end = self._states
        first = min(max(seq, end - (self._sent_n - SENT_SLACK)), end)
        idx = np.arange(first, end) % self._sent_n
        return self._st_ticks[idx], self._st_enc[idx], self._st_host[idx], end

    def sent_volts(self, t_mcu: np.ndarray) -> np.ndarray:
        """The motor voltage commanded at MCU times: each PWM frame's from when it was sent (its
        ~0.1 ms on the line and in the MCU's parser not counted) until the next; 0 before the
        first kept, and before the clock sync."""
        # the I/O thread writes on: leave it the oldest rows (a row is written before the count)
        n = min(self._sent, self._sent_n - SENT_SLACK)
        out = np.zeros(len(t_mcu))
        if n == 0:
            return out
        idx = np.arange(self._sent - n, self._sent) % self._sent_n
        host, volts = self._sent_host[idx], self._sent_volts[idx]
        m0, m1 = self.to_mcu_s(float(host[0])), self.to_mcu_s(float(host[-1]))
        if not (math.isfinite(m0) and math.isfinite(m1)):
            return out
        # the clock map is affine: two points place every send (drift included)
        span = float(host[-1] - host[0])
        mcu = m0 + (host - host[0]) * ((m1 - m0) / span if span > 0 else 1.0)
        k = np.searchsorted(mcu, t_mcu, side="right") - 1
        out[k >= 0] = volts[k[k >= 0]]
        return out

    def _on_stepper(self, st: Any) -> None:
        if self.steppers is not None:
            self.steppers.update(st)

    def _on_refused(self, r: Any) -> None:
        if self.steppers is not None:
            self.steppers.refused(r.name, r.values, r.reason)

    # --- commands -----------------------------------------------------------------------------
    def laser(self, on: bool) -> None:
        if self.link is None or not self.link.send_laser(on):
            raise DeviceError("cannot switch the laser: the MCU link is closed or its output is full")

    def aim(self, phi: float, gamma: float) -> None:
        """Move the PL axes (φ, γ in rad); the SIL scene puts the spot where they point."""
        if self.steppers is None:
            raise DeviceError("the MCU link is not up: no stepper can move")
        targets = {"phi": math.degrees(phi), "gamma": math.degrees(gamma)}
        # Check both axes before moving either: a γ refused after φ had started left φ moved.
        for axis, deg in targets.items():
            st = self.steppers.status(axis)
            a = self.steppers.axes[axis]
            if not st.homed:
                raise UsageError(f"{st.name} is not homed yet (homing runs after start): retry in a few s")
            if not a.min_deg <= deg <= a.max_deg:
                raise UsageError(
                    f"{a.name} = {deg:.2f}° is outside the axis limits [{a.min_deg:g}, {a.max_deg:g}]°: "
                    "nothing moved; choose a target inside them"
                )
            if st.moving:
                raise UsageError(f"{a.name} is still moving: nothing moved; retry when it stops")
        self.steppers.move_to("phi", math.degrees(phi))
        self.steppers.move_to("gamma", math.degrees(gamma))
        if self.sil is not None:
            self.sil.set_beta(spot_beta(self.cfg, phi, gamma))

    def inject(self, fault: str) -> dict[str, Any]:
        """SIL fault injection: `link_loss` cuts the cable both ways, `link_restore` mends it."""
        if self.sil is None:
            raise UsageError("fault injection needs the SIL MCU (devices.mcu: sil, or tvsd --sil)")
        if fault not in SIL_FAULTS:
            raise UsageError(f"unknown MCU fault {fault!r}: use one of {', '.join(SIL_FAULTS)}")
        self.sil.cable_cut(fault == "link_loss")  # DeviceError if the process is gone
        return {"fault": fault, "t_mono": time.monotonic(), "last_state_mono": self.last_state_host}

    # --- status ---------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        if self.link is None:
            return {"source": self.backend, "state": "down"}
        st = self.link.stats()
        axes = {}
        if self.steppers is not None:
            for axis in ("phi", "gamma"):
                a = self.steppers.status(axis)
                axes[axis] = {"deg": a.position_deg, "homed": a.homed, "moving": a.moving}
        return {
            "source": self.backend,
            "state": "ok" if st.link_up else "lost",
            "port": self.link.settings.port,
            "board": self.cfg.mcu.board,
            "exchange_hz": CONTROL_TICK_HZ / self.state_div,  # state + PWM frames per second
            "state_rate_hz": CONTROL_TICK_HZ / self.state_div,  # (its older name)
            "frames_rx": st.frames_rx,
            "lost_frames": st.lost_frames,
            "crc_errors": st.crc_errors,
            "link_losses": st.link_losses,
            "rtt_p50_us": None if math.isnan(st.rtt_p50_s) else round(st.rtt_p50_s * 1e6, 1),
            "clock_drift_ppm": None if math.isnan(st.clock_drift_ppm) else round(st.clock_drift_ppm, 2),
            # the I/O thread's heartbeats: the firmware cuts after mcu.watchdog_ms without one
            "heartbeat_gap_max_ms": round(st.heartbeat_gap_max_s * 1e3, 2),
            "heartbeat_late_max_ms": round(st.heartbeat_late_max_s * 1e3, 2),
            "heartbeats_withheld": st.heartbeats_withheld,  # the control loop had not ticked
            **self._kernel_heartbeats(),
            **self._late_input(),
            "firmware": self._firmware_counters(),
            "events_dropped": st.events_dropped,
            "io_thread_fifo": self.link.io_realtime,
            "tty_workers": self.link.tty_workers,  # the kernel's, which hand over the MCU's bytes
            **({"sil_pid": self.sil.pid} if self.sil is not None else {}),
            "steppers": axes,
        }

    def _firmware_counters(self) -> dict[str, Any] | None:
        """The MCU's counters from its latest stats reply (None before the first), and its age."""
        if self._firmware is None:
            return None
        t, st = self._firmware
        return {**{k: getattr(st, k) for k in FIRMWARE_COUNTERS}, "age_s": round(time.monotonic() - t, 2)}

    def _late_input(self) -> dict[str, Any]:
        """The control thread's late-input holds (tvsd.control.hold): PWM 0 held, not latched,
        while the state frames were late; each counted here ended in a resume."""
        if not hasattr(self.runner, "holds"):
            return {}
        h = self.runner.holds()
        return {
            "input_held": h.held_s > 0,
            "input_held_ms": round(h.held_s * 1e3, 2),
            "late_input_holds": h.resumed,
            "late_input_hold_ms_total": round(h.total_s * 1e3, 2),
            "late_input_hold_ms_max": round(h.longest_s * 1e3, 2),
            "input_late_max_ms": round(self.chain.late_max_ns / 1e6, 2),
            "frame_chain_breaks": self.chain.breaks,
        }

    def _kernel_heartbeats(self) -> dict[str, Any]:
        """The heartbeats the control kernel writes itself (tvsd.control.link_tx)."""
        if not hasattr(self.runner, "heartbeat_stats"):
            return {}
        hb = self.runner.heartbeat_stats()
        return {
            "kernel_heartbeats": hb.sent,
            "kernel_heartbeat_gap_max_ms": round(hb.gap_max_s * 1e3, 2),
            "kernel_tx_errors": hb.errors,
            "kernel_port_busy": hb.busy,  # ticks it found the port taken (tried again next tick)
            "kernel_pwm0_frames": hb.cuts,
        }

    def to_mcu_s(self, host_s: float) -> float:
        """MCU time (s) of a host time (time.monotonic), by the link's clock sync; NaN before it."""
        clock = self.link.clock if self.link is not None else None
        if clock is None or not clock.ready:
            return math.nan
        return clock.to_ticks(host_s) / self.clock_hz

    def to_host(self, mcu_ticks: int) -> float:
        """Host time (time.monotonic) of an MCU tick count, by the link's clock sync."""
        clock = self.link.clock if self.link is not None else None
        if clock is None or not clock.ready:
            return math.nan
        return float(clock.to_host(mcu_ticks))
