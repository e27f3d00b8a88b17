"""McuLink's receiving half: the frames' handlers on the link's I/O thread, the queue to the loop.

On the I/O thread (``io_thread.LinkIo`` calls ``on_frames``): tick placement, the clock sync's
round trips, and every state frame straight to ``on_state`` (in the daemon: the control
thread's measurement), then ``on_batch`` once per read that held states (the daemon answers the
batch with one PWM frame). What the event loop must see — pulses, MCU faults, stepper states,
refusals, link up/down, the replies to its requests — goes through a bounded
``collections.deque`` (append and popleft are atomic: the thread never waits for the loop), and
the loop is woken by at most one ``call_soon_threadsafe`` until it has drained the queue. A full
queue refuses the new event and counts it (``LinkStats.events_dropped``); link up/down always
goes in (at most one per ``link_lost_ms``).
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections import deque
from collections.abc import Callable
from typing import Any

from tvsd.hw.loop_handoff import LoopHandoff
from tvsd.hw.mcu.clock import ClockSync
from tvsd.hw.mcu.events import FaultEvent, LinkStats, PulseEvent, Refusal
from tvsd.hw.mcu.framing import Frame
from tvsd.hw.mcu.messages import (
    Ack,
    Fault,
    HeartbeatAck,
    Identify,
    McuStats,
    Pulse,
    State,
    StepperState,
    ack_meaning,
    check_against,
)
from tvsd.hw.mcu.placement import StateSample, TickPlacer
from tvsd.hw.mcu.spec import ProtocolSpec

log = logging.getLogger("tvsd.hw.mcu.link")  # the link's log, whichever part writes it

REFUSAL_LOG_INTERVAL_S = 1.0  # the same refusal is logged at most this often (with a count)
KERNEL_HB_FORGET_S = 2.0  # an ack this late is no round trip worth fitting (as sending.HB_FORGET_S)
EVENT_QUEUE = 4096  # events waiting for the event loop: pulses ~50/s, refusals up to the state rate


def _call(event: tuple[Callable[[Any], None], Any]) -> None:
    fn, arg = event
    fn(arg)


class Receiver:
    """Handles what the MCU sends. The ``on_*`` callbacks: ``on_state`` and ``on_batch`` run on
    the I/O thread, the others on the event loop's thread (``attach`` names the loop)."""

    def __init__(
        self,
        spec: ProtocolSpec,
        stats: LinkStats,
        sent: list[Any],
        rtt_history: int,
        *,
        on_pulse: Callable[[PulseEvent], None] | None = None,
        on_state: Callable[[StateSample], None] | None = None,
        on_batch: Callable[[], None] | None = None,
        on_fault: Callable[[FaultEvent], None] | None = None,
        on_stepper: Callable[[StepperState], None] | None = None,
        on_link: Callable[[bool], None] | None = None,
        on_refused: Callable[[Refusal], None] | None = None,
    ) -> None:
        self.spec, self.stats, self._sent = spec, stats, sent
        self.on_pulse, self.on_state, self.on_batch, self.on_fault = on_pulse, on_state, on_batch, on_fault
        self.on_stepper, self.on_link, self.on_refused = on_stepper, on_link, on_refused
        self.clock: ClockSync | None = None  # replaced whole (restart): readers take it once
        self.placer = TickPlacer(self._deliver_state)
        self.steppers: dict[int, StepperState] = {}
        self.faults: deque[FaultEvent] = deque(maxlen=64)
        self.refusals: deque[Refusal] = deque(maxlen=64)
        self._refusal_log: dict[tuple[str, int], tuple[float, int]] = {}  # → (logged at, repeats since)
        self.hb_sent: dict[int, float] = {}  # host_us -> send time, by whichever thread sent it
        # the control kernel sends heartbeats too (tvsd.control.link_tx): their host_us is the
        # send time itself (CLOCK_MONOTONIC µs, as time.monotonic), so no table is needed
        self.kernel_heartbeats = False
        self.hb_waiters: dict[int, asyncio.Future[float]] = {}
        self.identify_waiters: list[asyncio.Future[Identify]] = []
        self.stats_waiters: list[asyncio.Future[McuStats]] = []
        self.rtts: deque[float] = deque(maxlen=rtt_history)
        self._event_seq: int | None = None
        self._events: LoopHandoff[tuple[Callable[[Any], None], Any]] = LoopHandoff(_call, "MCU link event")
        classes = check_against(spec)
        handlers: dict[str, Callable[[Any, float], None]] = {
            "identify": self._on_identify,
            "heartbeat_ack": self._on_heartbeat_ack,
            "state": self._on_state,
            "pulse": self._on_pulse,
            "fault": self._on_fault,
            "stepper_state": self._on_stepper_state,
            "ack": self._on_ack,
            "stats": self._on_stats,
        }
        ids = {m.name: m for m in spec.messages}
        self._state_id = ids["state"].id
        self._dispatch: dict[int, tuple[type, Any, Callable[[Any, float], None]]] = {
            ids[name].id: (classes[ids[name].id], ids[name].codec, h) for name, h in handlers.items()
        }

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        self._events.loop = loop

    # --- the I/O thread -------------------------------------------------------------------------
    def on_frames(self, frames: list[Frame], now: float) -> None:
        states = False
        for f in frames:
            self.placer.note_lost(f.gap)  # losses up to this frame, not the whole read's
            # the decoder only passes ids of m2h messages with their exact payload size
            cls, codec, handler = self._dispatch[f.msg_id]
            states = states or f.msg_id == self._state_id
            try:
                handler(cls(*codec.unpack(f.payload)), now)
            except Exception:  # a consumer's bug must not stop the link
                log.exception("MCU link: handler for %s failed", cls.__name__)
        if states and self.on_batch is not None:
            try:
                self.on_batch()
            except Exception:
                log.exception("MCU link: on_batch failed")

    def on_link_change(self, up: bool) -> None:
        if not up:
            self.placer.note_lost(1)  # the stamps cannot be chained across an outage
        self._post(self._link_on_loop, up, always=True)

    def on_gone(self, why: str) -> None:
        self._post(self._gone_on_loop, why, always=True)

    def _post(self, fn: Callable[[Any], None], arg: Any, always: bool = False) -> None:
        """Hand fn(arg) to the event loop's thread; never waits."""
        if len(self._events) >= EVENT_QUEUE and not always:
            self.stats.events_dropped += 1
            return
        self._events.put((fn, arg))

    def _on_identify(self, msg: Identify, now: float) -> None:
        self._post(self._identify_on_loop, msg, always=True)

    def _on_heartbeat_ack(self, msg: HeartbeatAck, now: float) -> None:
        sent = self.hb_sent.pop(msg.host_us, None)
        ticks = self.placer.on_heartbeat_ack(msg.mcu_ticks, now)
        if sent is None and self.kernel_heartbeats:
            age = ((int(now * 1e6) - msg.host_us) & 0xFFFF_FFFF) / 1e6  # host_us wraps every 71 min
            if age < KERNEL_HB_FORGET_S:
                sent = now - age
        if sent is None:
            return  # an answer to a heartbeat we gave up on
        rtt = now - sent
        self.rtts.append(rtt)
        st = self.stats
        st.rtt_last_s = rtt
        st.rtt_samples += 1
        st.rtt_max_s = rtt if math.isnan(st.rtt_max_s) else max(st.rtt_max_s, rtt)
        clock = self.clock
        if clock is not None:
            clock.add(sent, now, ticks)
        if msg.host_us in self.hb_waiters:
            self._post(self._ping_on_loop, (msg.host_us, rtt), always=True)

    def _deliver_state(self, sample: StateSample) -> None:
        if self.on_state is not None:
            self.on_state(sample)

    def _on_state(self, msg: State, now: float) -> None:
        self.placer.on_state(msg.ticks, msg.encoder16, now, self.clock)

    def _on_pulse(self, msg: Pulse, now: float) -> None:
        # event_seq counts pulse events of all channels together (see the protocol notes)
        if self._event_seq is not None:
            gap = (msg.event_seq - self._event_seq - 1) & 0xFFFF
            if gap >= 0x8000:  # behind the last one: a repeat, not 65 000 losses
                return
            self.stats.lost_events += gap
        self._event_seq = msg.event_seq
        ticks = self.placer.unwrap32(msg.mcu_ticks)
        clock = self.clock
        host = clock.to_host(ticks) if clock is not None else math.nan
        name = self.spec.pulse_channels.get(msg.channel, f"channel{msg.channel}")
        if self.on_pulse is not None:
            self._post(self.on_pulse, PulseEvent(msg.channel, name, msg.event_seq, ticks, host))

    def _on_fault(self, msg: Fault, now: float) -> None:
        name = self.spec.fault_codes.get(msg.code, f"fault{msg.code}")
        self.stats.faults += 1
        self._post(self._fault_on_loop, FaultEvent(msg.code, name, msg.detail, now), always=True)

    def _on_stepper_state(self, msg: StepperState, now: float) -> None:
        self._post(self._stepper_on_loop, msg)

    def _on_ack(self, msg: Ack, now: float) -> None:
        if msg.status == 0:
            return
        name, values = self._sent[msg.seq] or ("", ())
        ref = Refusal(name or "?", values, msg.status, ack_meaning(msg.status), now)
        self._post(self._refused_on_loop, ref)

    def _on_stats(self, msg: McuStats, now: float) -> None:
        self._post(self._stats_on_loop, msg, always=True)

    # --- the event loop's thread ----------------------------------------------------------------
    def _link_on_loop(self, up: bool) -> None:
        if self.on_link is not None:
            self.on_link(up)

    def _gone_on_loop(self, why: str) -> None:
        log.error("MCU link: %s", why)

    def _identify_on_loop(self, msg: Identify) -> None:
        for fut in self.identify_waiters:
            if not fut.done():
                fut.set_result(msg)
        self.identify_waiters.clear()

    def _ping_on_loop(self, arg: tuple[int, float]) -> None:
        fut = self.hb_waiters.pop(arg[0], None)
        if fut is not None and not fut.done():
            fut.set_result(arg[1])

    def _fault_on_loop(self, ev: FaultEvent) -> None:
        self.faults.append(ev)
        log.warning("MCU fault %s (code %d, detail %d)", ev.name, ev.code, ev.detail)
        if self.on_fault is not None:
            self.on_fault(ev)

    def _stepper_on_loop(self, msg: StepperState) -> None:
        self.steppers[msg.axis] = msg
        if self.on_stepper is not None:
            self.on_stepper(msg)

    def _refused_on_loop(self, ref: Refusal) -> None:
        self.stats.nacks += 1  # counted here, with the refusal kept: a count seen is one handled
        self.refusals.append(ref)
        # pwm_set answers every batch of state frames: while the outputs are disarmed each one is
        # refused. One line per kind per second, with the count, not a line per frame.
        key = (ref.name, ref.status)
        logged_at, repeats = self._refusal_log.get(key, (-math.inf, 0))
        if ref.host_time - logged_at >= REFUSAL_LOG_INTERVAL_S:
            more = f" ({repeats} more like it since the last report)" if repeats else ""
            log.warning("MCU refused %s%s: %s%s", ref.name, ref.values, ref.reason, more)
            self._refusal_log[key] = (ref.host_time, 0)
        else:
            self._refusal_log[key] = (logged_at, repeats + 1)
        if self.on_refused is not None:
            self.on_refused(ref)

    def _stats_on_loop(self, msg: McuStats) -> None:
        for fut in self.stats_waiters:
            if not fut.done():
                fut.set_result(msg)
        self.stats_waiters.clear()
