"""The safety path off the event loop (issue 13, item 1): the MCU link's I/O thread against the
firmware core itself (the virtual MCU on a pty), its heartbeat tied to the real control kernel's
tick count.

A live control loop means a live heartbeat: the event loop blocked for twice the firmware's
watchdog (sleeping, or busy in pure Python and so holding the GIL but for the interpreter's
switch interval) starves neither the heartbeat nor the state frames. A dead one means the
firmware cuts within its watchdog: the kernel stopped, the I/O thread withholds the heartbeat.
The shipped fail-safe times are used (watchdog 50 ms, states every 1 ms; link loss 50 ms, stricter
than the shipped 500 ms).
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest
from conftest import until

from tvsd.control.runner import Runner
from tvsd.daemon.main import SWITCH_INTERVAL_S
from tvsd.hw.mcu.events import FaultEvent
from tvsd.hw.mcu.io_bench import GilHold
from tvsd.hw.mcu.io_thread import IO_THREAD_PRIORITY
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.receiving import EVENT_QUEUE, Receiver
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec
from tvsd.sim import virtual_mcu as vm

WATCHDOG_MS = 50
LINK_TIMEOUT_S = 0.040  # the control thread's stale limit (mcu.link_timeout_ms)
STATE_DIV = 10  # a state frame every 1 ms


class Seen:
    def __init__(self) -> None:
        self.states: list[float] = []  # arrival, time.monotonic() on the I/O thread
        self.faults: list[FaultEvent] = []
        self.links: list[bool] = []

    def state(self, s: StateSample) -> None:
        self.states.append(time.monotonic())

    def watchdog_cuts(self) -> list[FaultEvent]:
        return [f for f in self.faults if f.name == "watchdog_expired"]


async def connect(port: str, runner: Runner, seen: Seen, kernel_tx: bool = False) -> McuLink:
    """The link at the daemon's --realtime I/O priority (refused: said); `kernel_tx`: sharing
    the port with the control kernel, which then writes the heartbeats (tvsd.control.link_tx)."""
    await until(lambda: runner.is_running, 60.0, "the control kernel running")
    settings = McuSettings(port=port, watchdog_ms=WATCHDOG_MS, link_lost_ms=50.0)
    link = McuLink(
        settings,
        on_state=seen.state,
        on_fault=seen.faults.append,
        on_link=seen.links.append,
        liveness=lambda: runner.ticks,
        io_priority=IO_THREAD_PRIORITY,
        shared_tx=runner.tx if kernel_tx else None,
    )
    await link.__aenter__()
    link.send_config(watchdog_ms=WATCHDOG_MS, state_div=STATE_DIV, max_on_ms=0)
    await link.ping()  # the config is applied
    return link


# The virtual MCU in a process of its own, as `tvsd --sil` runs it: in this process its pump thread
# would share the GIL with the blocked event loop under test, and a pure-Python block held it off
# long enough for the emulated clock to jump past the watchdog (a fresh-clone CI run) — the
# emulator starved, not the link. And with the SIL's wire model (tvsd.sim.mcu_wire, G as the SIL
# devices' process has it): the host's bytes reach this pty's reader only when the kernel's tty
# flip-buffer worker (a normal-priority kworker) has run, which CPU load delays by 100+ ms
# (docs/measurements/wdflake.md); a real UART has them when they are written. So the firmware's
# watchdog counts each heartbeat from its own send stamp, as a chip would see it on the wire. A
# host gap still cuts: a heartbeat sent after last + watchdog cuts the moment it is read.
VMCU_CHILD = """
import os, sys
from tvsd.sim import virtual_mcu as vm
from tvsd.sim.mcu_wire import WIRE_ALLOWANCE_S
try:  # the emulator at a real-time priority, as the SIL devices' process under --realtime: what
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))  # is tested is the host's path,
except OSError:  # not the emulated clock jumping after a starved pump (refused: as it was)
    pass
try:
    v = vm.VirtualMcu(wire_allowance_s=WIRE_ALLOWANCE_S)
except vm.VirtualMcuError as exc:
    print("unavailable:", exc, flush=True)
    sys.exit(0)
with v:
    print(v.port, flush=True)
    sys.stdin.read()
"""


@pytest.fixture
def vmcu_port() -> Iterator[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", VMCU_CHILD], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None and proc.stdin is not None
    line = proc.stdout.readline().strip()
    if not line.startswith("/dev/"):
        proc.wait(10)
        pytest.skip(f"virtual MCU {line or 'did not start'}")
    try:
        yield line
    finally:
        proc.stdin.close()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


@pytest.mark.parametrize("block", ["sleep", "busy"])
def test_a_blocked_event_loop_starves_neither_heartbeat_nor_states(
    vmcu_port: str, runner: Runner, block: str
) -> None:
    """The loop blocked 2 × watchdog_ms. Heartbeats are due every watchdog_ms / 4 (12.5 ms): the
    longest gap between two must stay under the watchdog, and the firmware must report no expiry
    (no fault frame, and its own count unchanged, asked after two heartbeats sent after the block
    have reached it: the wire model decides a waiting cut at the first heartbeat read past its
    edge); states must reach the measurement less than the control thread's 40 ms stale limit
    apart, and the link must not be called lost. (On the event loop, as before, the whole block
    went without a heartbeat or a state: an expiry and a loss each time.)"""

    async def main() -> None:
        seen = Seen()
        link = await connect(vmcu_port, runner, seen)
        try:
            await asyncio.sleep(0.2)
            expiries = (await link.request_stats(timeout_s=5.0)).watchdog_expiries
            faults = len(seen.faults)  # the block's, not the start-up's (a stall of this loaded machine)
            link.reset_peaks()
            t0 = time.monotonic()
            t1 = t0 + 2 * WATCHDOG_MS / 1e3
            if block == "sleep":
                time.sleep(t1 - t0)
            else:  # pure Python: the GIL is handed over only at the switch interval
                while time.monotonic() < t1:
                    pass
            sent = link.stats().heartbeats
            await until(lambda: link.stats().heartbeats >= sent + 2, 5.0, "two heartbeats after the block")
            expiries = (await link.request_stats(timeout_s=5.0)).watchdog_expiries - expiries
            st = link.stats()
        finally:
            await link.close()
        during = [t for t in seen.states if t0 <= t <= t1]
        gaps = [b - a for a, b in zip([t0, *during], [*during, t1], strict=True)]
        print(
            f"{block}: heartbeat gap max {st.heartbeat_gap_max_s * 1e3:.1f} ms, late max "
            f"{st.heartbeat_late_max_s * 1e3:.1f} ms; {len(during)} states in the block, longest "
            f"gap {max(gaps) * 1e3:.1f} ms"
        )
        cuts = [f for f in seen.faults[faults:] if f.name == "watchdog_expired"]
        assert not cuts and expiries == 0, (seen.faults, expiries)
        assert st.heartbeat_gap_max_s < WATCHDOG_MS / 1e3, st
        assert st.link_losses == 0 and False not in seen.links
        assert max(gaps) < LINK_TIMEOUT_S, gaps

    switch = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)  # the daemon's (tvsd.daemon.main)
    try:
        asyncio.run(main())
    finally:
        sys.setswitchinterval(switch)


def test_a_stopped_kernel_stops_the_heartbeat_and_the_firmware_cuts(
    vmcu: vm.VirtualMcu, runner: Runner
) -> None:
    """The kernel stops: the heartbeat that was due when it last ticked may still go (one period
    plus the I/O thread's own lateness after the stop), none after. The firmware then cuts PWM
    and laser watchdog_ms after that last heartbeat: not sooner, and later by no more than 25 ms
    (the virtual MCU's pump wakes every 1 ms, the fault frame crosses the pty and wakes the I/O
    thread: two thread wake-ups on a loaded 2-core machine). The kernel back, heartbeats resume."""

    async def main() -> None:
        seen = Seen()
        link = await connect(vmcu.port, runner, seen)
        try:
            assert link.send_pwm(0.3)
            await until(lambda: vmcu.pwm_duty > 0.25, 2.0, "the firmware taking the duty")
            runner.stop(timeout=2.0)
            t_stop = time.monotonic()
            await until(seen.watchdog_cuts, 2.0, "the firmware's watchdog expiry")
            st = link.stats()
            cut = seen.watchdog_cuts()[0]
            period = link.settings.heartbeat_period_s
            assert st.heartbeats_withheld > 0
            assert st.last_heartbeat_s <= t_stop + period + st.heartbeat_late_max_s, st
            after_s = cut.host_time - st.last_heartbeat_s
            print(f"firmware cut {after_s * 1e3:.1f} ms after the last heartbeat (watchdog {WATCHDOG_MS} ms)")
            assert WATCHDOG_MS / 1e3 <= after_s <= WATCHDOG_MS / 1e3 + 0.025
            assert cut.detail == WATCHDOG_MS and vmcu.pwm_duty == 0.0
            sent = st.heartbeats
            runner.start()
            await until(lambda: link.stats().heartbeats > sent + 2, 5.0, "heartbeats again")
        finally:
            await link.close()

    asyncio.run(main())


def test_a_silent_link_is_called_lost_while_the_io_thread_owns_the_heartbeat(
    vmcu: vm.VirtualMcu, runner: Runner
) -> None:
    """The loss check's look at the tty (which waits for the kernel's flip-buffer worker) runs on
    the probe thread when the I/O thread sends the heartbeats (tvsd.hw.mcu.tty_probe): a cut cable
    (nothing either way) is still called lost, the heartbeats go on meanwhile, and the next frame
    brings the link back. Outcomes only: the loss's timing is test_mcu_link's."""

    async def main() -> None:
        seen = Seen()
        link = await connect(vmcu.port, runner, seen)
        try:
            await until(lambda: seen.links[-1:] == [True], 5.0, "the link up")
            vmcu.cable_cut = True
            await until(lambda: seen.links[-1:] == [False], 5.0, "the link called lost")
            sent = link.stats().heartbeats
            await until(lambda: link.stats().heartbeats > sent + 2, 5.0, "heartbeats while lost")
            vmcu.cable_cut = False
            await until(lambda: seen.links[-1:] == [True], 5.0, "the link back")
            assert link.stats().link_losses == 1
        finally:
            await link.close()

    asyncio.run(main())


def test_a_full_event_queue_drops_and_counts_but_keeps_link_changes() -> None:
    """The I/O thread never waits for the loop: past EVENT_QUEUE waiting events a new one is
    refused and counted; a link change always goes in; the loop is woken once for all of them."""
    from tvsd.hw.mcu.events import LinkStats
    from tvsd.hw.mcu.messages import Pulse

    loop = asyncio.new_event_loop()
    try:
        stats = LinkStats()
        got: list[object] = []
        rx = Receiver(load_spec(), stats, [None] * 0x1_0000, 8, on_pulse=got.append, on_link=got.append)
        rx.attach(loop)  # not running: nothing is drained while we post
        for seq in range(EVENT_QUEUE + 10):
            rx._on_pulse(Pulse(0, seq & 0xFFFF, seq), 0.0)
        rx.on_link_change(False)
        assert stats.events_dropped == 10
        assert len(loop._ready) == 1  # type: ignore[attr-defined]  # one wake-up, not 4106
        loop.run_until_complete(asyncio.sleep(0))
        assert len(got) == EVENT_QUEUE + 1 and got[-1] is False
    finally:
        loop.close()


# --- heartbeats from the nogil control kernel (tvsd.control.link_tx) ---------------------------


async def connect_kernel(port: str, runner: Runner, seen: Seen) -> McuLink:
    """As the daemon does it (tvsd.daemon.drive_link): the kernel writes the heartbeats."""
    link = await connect(port, runner, seen, kernel_tx=True)
    spec_ids = (link.message_id("heartbeat"), link.message_id("pwm_set"))
    runner.attach_link(link.settings.heartbeat_period_s, link.spec.sync, *spec_ids)
    link.kernel_heartbeats(True)
    return link


@pytest.fixture
def rt_runner(setup: object) -> Iterator[Runner]:
    """The kernel at the daemon's --realtime priority (SCHED_FIFO 80; refused: as it is), no mlockall."""
    r = Runner(setup, sil=False, realtime=True, lock_memory=False)  # type: ignore[arg-type]
    r.start()
    try:
        yield r
    finally:
        r.stop(timeout=2.0)


@pytest.mark.slow
@pytest.mark.parametrize("sender", ["kernel", "io_thread"])
def test_the_gil_held_in_c_starves_no_kernel_heartbeat(
    vmcu_port: str, rt_runner: Runner, sender: str
) -> None:
    """The GIL held inside C for >= 200 ms (4 x the firmware's 50 ms watchdog), the virtual MCU in
    its own process (at a real-time priority, as the SIL devices' process runs). Heartbeats from
    the kernel, at the daemon's --realtime priority: the longest gap under half the watchdog
    (due every 12.5 ms, the kernel ticks every 0.1 ms: measured 12.5–15 ms under every load of
    `tvsctl bench --only mcu_io`; 25 ms would be a stall of a FIFO 80 thread), no watchdog
    expiry, and the kernel's heartbeat acks still feed the round trips. From the I/O thread (how
    it was before): the same hold starves it, and the firmware cuts — the test's proof that the
    hold is real."""
    runner = rt_runner

    async def main() -> None:
        seen = Seen()
        if sender == "kernel":
            link = await connect_kernel(vmcu_port, runner, seen)
        else:
            link = await connect(vmcu_port, runner, seen)
        try:
            # Sized here for 0.3 s, on this machine as loaded now: the same match can run faster a
            # moment later (191 ms for a 200 ms sizing, in 2 of 3 runs), and the test needs >= 0.2 s.
            hold = GilHold(0.3)
            await asyncio.sleep(0.2)
            link.reset_peaks()
            runner.reset_heartbeat_peaks()
            rtts = link.stats().rtt_samples
            held = hold()
            await asyncio.sleep(0.15)  # the firmware's word on the hold reaches us
            st = link.stats()
        finally:
            runner.detach_link()
            await link.close()
        hb = runner.heartbeat_stats()
        gap = hb.gap_max_s if sender == "kernel" else st.heartbeat_gap_max_s
        print(f"{sender}: GIL held {held * 1e3:.0f} ms; heartbeat gap max {gap * 1e3:.1f} ms; "
              f"{len(seen.watchdog_cuts())} watchdog expiries")  # fmt: skip
        assert held >= 0.2
        if sender == "kernel":
            assert not seen.watchdog_cuts(), seen.faults
            assert gap < WATCHDOG_MS / 2e3, hb
            assert hb.errors == 0 and st.rtt_samples > rtts, (hb, st)
        else:
            assert seen.watchdog_cuts(), "the I/O thread's heartbeat survived a 200 ms GIL hold?"

    switch = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        asyncio.run(main())
    finally:
        sys.setswitchinterval(switch)


def test_a_stopped_kernel_stops_its_heartbeat_and_the_firmware_cuts(
    vmcu: vm.VirtualMcu, runner: Runner
) -> None:
    """Kernel heartbeats: the kernel stops, the heartbeats stop with it (no other thread sends
    any), and the firmware cuts PWM watchdog_ms after the last one, within the same 25 ms of
    slack as the I/O thread's test above (the virtual MCU's 1 ms pump, two thread wake-ups)."""

    async def main() -> None:
        seen = Seen()
        link = await connect_kernel(vmcu.port, runner, seen)
        io_heartbeats = link.stats().heartbeats  # the I/O thread's, before the kernel took over
        try:
            assert link.send_pwm(0.3)
            await until(lambda: vmcu.pwm_duty > 0.25, 2.0, "the firmware taking the duty")
            runner.stop(timeout=2.0)
            await until(seen.watchdog_cuts, 2.0, "the firmware's watchdog expiry")
            last = runner.heartbeat_stats().last_s
            after_s = seen.watchdog_cuts()[0].host_time - last
            print(f"firmware cut {after_s * 1e3:.1f} ms after the kernel's last heartbeat")
            assert WATCHDOG_MS / 1e3 <= after_s <= WATCHDOG_MS / 1e3 + 0.025
            assert vmcu.pwm_duty == 0.0 and link.stats().heartbeats == io_heartbeats  # none since
            assert (await link.request_stats()).watchdog_expiries == 1  # the firmware's own count
        finally:
            await link.close()

    asyncio.run(main())


def test_the_kernels_safe_state_reaches_the_firmware_without_the_io_thread(
    vmcu: vm.VirtualMcu, runner: Runner
) -> None:
    """The loop's stale-measurement fault holds command 0; the kernel itself puts PWM 0 on the
    wire behind the heartbeat (the I/O thread, which sends the duty, may be the starved one), so
    the motor never runs on the last duty while the kernel keeps the watchdog quiet."""

    async def main() -> None:
        seen = Seen()
        link = await connect_kernel(vmcu.port, runner, seen)
        try:
            assert link.send_pwm(0.3)
            await until(lambda: vmcu.pwm_duty > 0.25, 2.0, "the firmware taking the duty")
            runner.stale_after(LINK_TIMEOUT_S)
            runner.position(0.0)  # no measurement ever written: stale at once
            await until(lambda: vmcu.pwm_duty == 0.0, 2.0, "PWM 0 from the kernel")
            assert runner.fault and runner.heartbeat_stats().cuts > 0
            assert not seen.watchdog_cuts()
        finally:
            runner.detach_link()
            await link.close()

    asyncio.run(main())
