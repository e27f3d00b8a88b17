"""McuLink through a real pseudo-terminal, with the MCU played in Python on the master side."""

from __future__ import annotations

import asyncio
import logging
import math
import os
import threading
import time
import tty
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field

import pytest
from conftest import until
from fake_mcu_side import answer_handshake, read_host_frames

from tvsd.errors import DeviceError, ProtocolError, UsageError
from tvsd.hw.mcu.events import PulseEvent, Refusal
from tvsd.hw.mcu.framing import Frame, FrameDecoder, encode_frame
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec

SPEC = load_spec()
ID = {m.name: m for m in SPEC.messages}
HZ = 16_000_000


@dataclass
class FakeMcu:
    """The MCU's side of the wire, on the pty master: answers identify, heartbeat and stats."""

    master: int
    version: int = SPEC.version
    table_hash: int = SPEC.table_hash
    answer: bool = True
    tick0: int = 0xFFFF_0000  # near the 32-bit wrap, so the host must unwrap
    seq: int = 0
    received: list[Frame] = field(default_factory=list)
    decoder: FrameDecoder = field(
        default_factory=lambda: FrameDecoder(payload_sizes=SPEC.payload_sizes("h2m"))
    )
    t0: float = field(default_factory=time.monotonic)

    frozen: int | None = None  # a fixed tick count, for exact expectations

    def ticks(self) -> int:
        if self.frozen is not None:
            return self.frozen
        return self.tick0 + int((time.monotonic() - self.t0) * HZ)

    def send(self, name: str, *values: int) -> bytes:
        m = ID[name]
        frame = encode_frame(self.seq, m.id, m.codec.pack(*values))
        self.seq = (self.seq + 1) & 0xFFFF
        os.write(self.master, frame)
        return frame

    def on_readable(self) -> None:
        for f in read_host_frames(self.master, self.decoder):
            self.received.append(f)
            if self.answer:
                answer_handshake(
                    f, self.decoder, self.send, self.ticks,
                    board=2, version=self.version, table_hash=self.table_hash,
                )

    def pwm(self) -> list[int]:
        return [
            ID["pwm_set"].codec.unpack(f.payload)[0] for f in self.received if f.msg_id == ID["pwm_set"].id
        ]


@asynccontextmanager
async def pty_link(fake_kw: dict | None = None, **link_kw: object) -> AsyncIterator[tuple[McuLink, FakeMcu]]:
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    loop = asyncio.get_running_loop()
    fake = FakeMcu(master, **(fake_kw or {}))
    loop.add_reader(master, fake.on_readable)
    cbs = {k: link_kw.pop(k) for k in list(link_kw) if k.startswith("on_")}
    # Tests of link loss give their timeout; for the others, a 50 ms stall of this process (it
    # plays the MCU too) must not read as a loss and break the chain of stamps they check.
    link_kw.setdefault("link_lost_ms", 10_000.0)
    link = McuLink(McuSettings(port=path, **link_kw), SPEC, **cbs)  # type: ignore[arg-type]
    try:
        await link.open()
        yield link, fake
    finally:
        await link.close()
        loop.remove_reader(master)
        os.close(slave)
        os.close(master)


def run(coro_fn: Callable[[], object]) -> None:
    asyncio.run(coro_fn())  # type: ignore[arg-type]


def test_identify_ok_and_ping() -> None:
    async def main() -> None:
        async with pty_link() as (link, _):
            ident = await link.identify()
            assert (ident.proto_version, ident.table_hash, ident.clock_hz) == (
                SPEC.version,
                SPEC.table_hash,
                HZ,
            )
            rtts = [await link.ping() for _ in range(50)]
            st = link.stats()
            rtts.sort()
            print(f"pty RTT: p50 {rtts[25] * 1e6:.0f} µs, max {rtts[-1] * 1e6:.0f} µs")
            # both ends on one event loop: a round trip is two pty hops and two loop turns
            assert 0 < rtts[25] < 5e-3
            assert st.rtt_samples == 50 and st.rtt_last_s == pytest.approx(rtts[-1], rel=10)
            assert st.frames_rx == 51 and st.frames_tx == 51
            assert st.crc_errors == st.lost_frames == 0
            stats = await link.request_stats()
            assert stats.rx_frames == 52

    run(main)


def test_identify_mismatch_is_refused_with_the_fix() -> None:
    async def main() -> None:
        # a v1 image: refused on the version, in one line with the fix
        async with pty_link({"version": 1, "table_hash": 0xDEADBEEF}) as (link, _):
            with pytest.raises(ProtocolError) as info:
                await link.identify()
            msg = str(info.value)
            assert f"speaks protocol v1, this tvsd speaks v{SPEC.version}" in msg
            assert "flash the firmware image of this tvsd (make -C firmware" in msg
            assert "\n" not in msg
        # the right version but another command table: refused on the hash
        async with pty_link({"table_hash": 0xDEADBEEF}) as (link, _):
            with pytest.raises(ProtocolError) as info:
                await link.identify()
            msg = str(info.value)
            assert f"command table 0xDEADBEEF (protocol v{SPEC.version})" in msg
            assert f"expects 0x{SPEC.table_hash:08X}" in msg and "flash the firmware image" in msg

    run(main)


def test_silent_mcu_is_a_device_error() -> None:
    async def main() -> None:
        async with pty_link({"answer": False}, identify_timeout_ms=150) as (link, fake):
            with pytest.raises(DeviceError, match="no answer from the MCU"):
                await link.identify()
            assert len(fake.received) == 3  # one request per attempt

    run(main)


def test_bad_port_message() -> None:
    async def main() -> None:
        link = McuLink(McuSettings(port="/dev/ttyNOPE9"), SPEC)
        with pytest.raises(DeviceError) as info:
            await link.open()
        assert str(info.value) == (
            "cannot open serial port /dev/ttyNOPE9: No such file or directory; "
            "check the cable / the path / permissions (dialout group)"
        )

    run(main)


def test_heartbeat_task_feeds_clock_sync() -> None:
    async def main() -> None:
        async with pty_link(watchdog_ms=20) as (link, fake):  # heartbeats every 5 ms
            await link.identify()
            link.start_heartbeat()
            await wait_for(lambda: link.stats().rtt_samples >= 60, timeout=5.0)
            st = link.stats()
            assert link.clock is not None and link.clock.ready
            # The fake's ticks are host-monotonic × 16 MHz exactly (no drift, known offset).
            # A kept round trip is off by at most (min RTT + margin)/2; the fitted line's
            # weights sum in absolute value to < 2 inside the window (5/3 for even spacing).
            e = (min(link._rx.rtts) + link.settings.clock.rtt_margin_s) / 2
            t = time.monotonic()
            assert abs(link.clock.to_host(fake.ticks()) - t) <= 2 * e + 1e-4  # + 0.1 ms: now
            # drift: a unit mistake (µs vs ticks) would show as 1e6 ppm; 0.3 s of pty round
            # trips pins the slope to ~3e/L ≈ 1000 ppm at worst
            assert abs(st.clock_drift_ppm) < 3 * e / 0.3 * 1e6 + 100
            assert st.rtt_p50_s <= st.rtt_max_s


def test_pulse_loss_and_tick_unwrap() -> None:
    async def main() -> None:
        got: list[PulseEvent] = []
        async with pty_link(on_pulse=got.append) as (link, fake):
            await link.identify()
            # The first 32-bit count the link sees fixes its 64-bit epoch: 3500 ticks before
            # the wrap, so the pulses below cross it.
            base = fake.frozen = 2**32 - 3500
            await link.ping()
            seqs = [65533, 65534, 65535, 0, 3, 4, 4, 10]  # wrap; 1,2 lost; 4 twice; 5..9 lost
            for i, s in enumerate(seqs):
                fake.send("pulse", i % 2, s, (base + 1000 * i) & 0xFFFF_FFFF)
            await wait_for(lambda: len(got) == 7)
            assert [p.event_seq for p in got] == [65533, 65534, 65535, 0, 3, 4, 10]
            assert link.stats().lost_events == 2 + 5
            ticks = [p.mcu_ticks for p in got]
            assert ticks == [base + 1000 * i for i in (0, 1, 2, 3, 4, 5, 7)]  # past 2**32
            assert [p.channel_name for p in got[:2]] == ["zero", "optical"]

    run(main)


def test_state_frames_unwrap_32_bit_ticks_and_16_bit_encoder() -> None:
    async def main() -> None:
        got: list[StateSample] = []
        async with pty_link(on_state=got.append) as (link, fake):
            await link.identify()
            await link.ping()
            t = fake.ticks()
            enc = 0
            # 300 frames 1600 ticks apart (10 kHz at 16 MHz) from 2**32 - 65536 + x: across the
            # 32-bit wrap; encoder at -300 counts per frame runs through -32768 several times
            for _ in range(300):
                fake.send("state", t & 0xFFFF_FFFF, ((enc + 0x8000) & 0xFFFF) - 0x8000)
                t += 1600
                enc -= 300
            await wait_for(lambda: len(got) == 300)
            assert [g.mcu_ticks - got[0].mcu_ticks for g in got] == [1600 * i for i in range(300)]
            assert [g.encoder for g in got] == [-300 * i for i in range(300)]

    run(main)


def wait_for(cond: Callable[[], object], timeout: float = 2.0) -> Awaitable[float]:
    """The shared poll (conftest.until) with this file's usual bound."""
    return until(cond, timeout)


class ThreadLag:
    """How late a 1 ms sleep of a thread of this process wakes, at worst, while it runs: the
    same scheduler and GIL delays as the link's I/O thread sees."""

    def __init__(self) -> None:
        self.max_s = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            due = time.monotonic() + 0.001
            time.sleep(0.001)
            self.max_s = max(self.max_s, time.monotonic() - due)

    def stop(self) -> float:
        self._stop.set()
        self._thread.join()
        return self.max_s


def test_link_loss_reported_in_time_and_recovers() -> None:
    async def main() -> None:
        events: list[bool] = []
        loop = asyncio.get_running_loop()
        timeout = 0.05
        async with pty_link(on_link=events.append, link_lost_ms=1e3 * timeout) as (link, fake):
            last_sent = 0.0
            for _ in range(50):  # 1 kHz state stream for 50 ms
                fake.send("state", fake.ticks() & 0xFFFF_FFFF, 0)
                last_sent = time.monotonic()
                await asyncio.sleep(0.001)
            await wait_for(lambda: events == [True])
            assert link.link_up
            lag = ThreadLag()  # the I/O thread's lateness while the loss is pending, same run
            await wait_for(lambda: len(events) == 2)
            lag_s = lag.stop()
            latency = link.stats().last_loss_s - last_sent  # when the I/O thread called it
            print(f"link loss {latency * 1e3:.1f} ms after the last frame (lag ≤ {lag_s * 1e3:.1f} ms)")
            assert events[1] is False and not link.link_up and link.stats().link_losses == 1
            # Not early: the last frame was read after it was sent, so the deadline is later.
            # Late by no more than a thread of this process was, plus 2 ms: the read of the last
            # frame follows its write by well under 1 ms, select's timeout rounds up < 1 ms.
            assert timeout <= latency <= timeout + lag_s + 0.002
            fake.send("state", fake.ticks() & 0xFFFF_FFFF, 0)
            await wait_for(lambda: len(events) == 3)
            assert events[2] is True and link.link_up
            del loop

    run(main)


def test_corruption_is_counted_and_link_stays_up() -> None:
    async def main() -> None:
        async with pty_link() as (link, fake):
            await link.identify()
            n = 0
            expected_crc = expected_bad = expected_lost = 0
            for k in range(200):
                wire = bytearray(encode_frame(fake.seq, ID["state"].id, b"\x00\x01\x02\x03\x04\x05"))
                fake.seq = (fake.seq + 1) & 0xFFFF
                if k % 20 == 5:  # payload byte flipped: caught by the CRC
                    wire[6] ^= 0x40
                    expected_crc += 1
                    expected_lost += 1
                elif k % 20 == 15:  # LEN byte flipped: impossible header
                    wire[1] ^= 0x10
                    expected_bad += 1
                    expected_lost += 1
                else:
                    n += 1
                if k % 50 == 0:
                    wire = bytearray(b"\x00\xff\x13") + wire  # line noise before a good frame
                os.write(fake.master, bytes(wire))
            await wait_for(lambda: link.stats().frames_rx >= 1 + n)
            st = link.stats()
            assert st.frames_rx == 1 + n  # identify + the intact state frames
            assert st.crc_errors == expected_crc and st.bad_headers == expected_bad
            assert st.lost_frames == expected_lost
            assert st.resyncs >= expected_crc + expected_bad + 4
            assert link.link_up and st.link_losses == 0
            assert await link.ping() > 0  # still talking

    run(main)


def test_send_pwm_from_another_thread() -> None:
    async def main() -> None:
        async with pty_link(watchdog_ms=8) as (link, fake):  # heartbeats every 2 ms
            await link.identify()
            link.start_heartbeat()  # the loop thread sends too: SEQ must stay consistent
            n = 3000
            sent = []

            def control() -> None:
                for i in range(n):
                    duty = ((i % 200) - 100) / 100
                    if link.send_pwm(duty):
                        sent.append(round(duty * 32767))
                    time.sleep(0.0001)  # ~10 kHz

            th = threading.Thread(target=control)
            th.start()
            while th.is_alive():
                await asyncio.sleep(0.01)
            th.join()
            await wait_for(lambda: len(fake.pwm()) == len(sent))
            st = link.stats()
            assert fake.pwm() == sent  # in order, none torn
            assert len(sent) + st.tx_dropped == n
            # the fake saw every frame of both threads with consecutive SEQs
            assert fake.decoder.stats.lost_frames == fake.decoder.stats.crc_errors == 0
            assert fake.decoder.stats.duplicates == 0

    run(main)


def test_full_output_refuses_whole_frames() -> None:
    async def main() -> None:
        async with pty_link(tx_buffer_bytes=64) as (link, fake):
            loop = asyncio.get_running_loop()
            loop.remove_reader(fake.master)  # the MCU stops reading: the pty fills up
            ok = sum(link.send_pwm(0.5) for _ in range(20000))
            st = link.stats()
            assert st.tx_dropped > 0 and ok + st.tx_dropped == 20000
            loop.add_reader(fake.master, fake.on_readable)
            for _ in range(200):  # drain: the MCU reads, the host flushes what is pending
                link.flush()
                await asyncio.sleep(0.002)
                if len(fake.pwm()) == ok:
                    break
            assert len(fake.pwm()) == ok
            assert fake.decoder.stats.crc_errors == fake.decoder.stats.bad_headers == 0

    run(main)


def test_nan_duty_is_zero_and_out_of_range_is_clamped() -> None:
    async def main() -> None:
        async with pty_link() as (link, fake):
            for d in (float("nan"), 2.0, -7.0, 0.25):
                assert link.send_pwm(d)
            await wait_for(lambda: len(fake.pwm()) == 4)
            assert fake.pwm() == [0, 32767, -32767, round(0.25 * 32767)]

    run(main)


def test_refusal_names_the_frame_by_its_seq() -> None:
    async def main() -> None:
        refused: list[Refusal] = []
        async with pty_link(on_refused=refused.append) as (link, fake):
            link.send_laser(True)
            link.send_stepper_move(1, -250, 400, 800)
            await wait_for(lambda: len(fake.received) == 2)
            seq = fake.received[1].seq
            fake.send("ack", fake.received[0].seq, 0)  # ok: not a refusal
            fake.send("ack", seq, 3)
            await wait_for(lambda: len(refused) == 1)
            r = refused[0]
            assert (r.name, r.values, r.status) == ("stepper_move", (1, -250, 400, 800), 3)
            assert r.reason == "the stepper axis is already moving"
            assert link.stats().nacks == 1

    run(main)


def test_a_burst_of_refusals_is_one_log_line_with_its_count(caplog: pytest.LogCaptureFixture) -> None:
    """While the outputs are disarmed every pwm_set (1 kHz) is refused: each is counted and kept,
    the log gets the first, then the count in the next report a second later."""

    async def main() -> None:
        async with pty_link() as (link, fake):
            for _ in range(30):
                link.send_pwm(0.0)
            await wait_for(lambda: len(fake.received) == 30)
            for f in fake.received:
                fake.send("ack", f.seq, 2)
            await wait_for(lambda: link.stats().nacks == 30)
            lines = [r.getMessage() for r in caplog.records if "MCU refused" in r.getMessage()]
            assert lines == [
                "MCU refused pwm_set(0,): outputs are refused until a heartbeat arms the watchdog"
            ]
            assert len(link.refusals) == 30
            link._rx._refusal_log[("pwm_set", 2)] = (-math.inf, 29)  # as if the second had passed
            link.send_pwm(0.0)
            await wait_for(lambda: len(fake.received) == 31)
            fake.send("ack", fake.received[-1].seq, 2)
            await wait_for(lambda: link.stats().nacks == 31)
            lines = [r.getMessage() for r in caplog.records if "MCU refused" in r.getMessage()]
            assert len(lines) == 2 and lines[1].endswith("(29 more like it since the last report)")

    with caplog.at_level(logging.WARNING, logger="tvsd.hw.mcu.link"):
        run(main)


def test_state_ticks_survive_a_loss() -> None:
    async def main() -> None:
        got: list[StateSample] = []
        async with pty_link(on_state=got.append) as (link, fake):
            await link.identify()
            t = fake.frozen = 1_000_000
            await link.ping()
            fake.send("state", t & 0xFFFF_FFFF, 0)
            # 5 frames lost, and meanwhile 3 wraps of v1's 16-bit stamp that no host clock saw
            # pass (the fake's clock is frozen): v2's 32-bit stamp places the next frame exactly
            fake.seq = (fake.seq + 5) & 0xFFFF
            jump = 3 * 65536 + 1600
            fake.send("state", (t + jump) & 0xFFFF_FFFF, 0)
            await wait_for(lambda: len(got) == 2)
            assert got[1].mcu_ticks - got[0].mcu_ticks == jump
            assert got[0].exact and got[1].exact
            assert link.stats().lost_frames == 5

    run(main)


def test_unplugged_device_is_reported() -> None:
    async def main() -> None:
        events: list[bool] = []
        master, slave = os.openpty()
        tty.setraw(slave)
        loop = asyncio.get_running_loop()
        fake = FakeMcu(master)
        loop.add_reader(master, fake.on_readable)
        link = McuLink(McuSettings(port=os.ttyname(slave)), SPEC, on_link=events.append)
        await link.open()
        try:
            await link.identify()
            assert events == [True]
            loop.remove_reader(master)
            os.close(master)  # the pty's other end vanishes, as a USB adapter pulled out
            os.close(slave)
            await wait_for(lambda: events == [True, False])
            assert link.tx_error is not None and not link.send_pwm(0.2)
        finally:
            await link.close()

    run(main)


def test_out_of_range_field_is_a_usage_error() -> None:
    async def main() -> None:
        async with pty_link() as (link, _):
            with pytest.raises(UsageError, match=r"cannot send stepper_move\(axis=0, steps="):
                link.send_stepper_move(0, 2**40, 100, 100)

    run(main)


def test_settings_are_checked() -> None:
    with pytest.raises(UsageError, match=r"link_lost_ms: must be above 0 ms"):
        McuSettings(port="/dev/x", link_lost_ms=0)
    with pytest.raises(UsageError, match="tx_buffer_bytes: must be at least 41 B"):
        McuSettings(port="/dev/x", tx_buffer_bytes=10)  # below one frame
    with pytest.raises(UsageError, match="link_timeout_ms: must be at most link_lost_ms"):
        McuSettings(port="/dev/x", link_timeout_ms=600)


def test_states_before_the_first_ack_are_placed_at_once() -> None:
    # State frames flow from power-on; v1 had to hold them until a heartbeat_ack gave their
    # 16-bit stamps an epoch. v2's 32-bit stamps are the MCU's own count: delivered at once,
    # and the ack that follows agrees with them (no jump).
    async def main() -> None:
        got: list[StateSample] = []
        # A 50 ms silence before the ping would rightly be a link loss (which drops held frames
        # that no ack can place); a loaded CI machine can take that long, so this test, which is
        # not about link loss, gives the link 10 s.
        async with pty_link(on_state=got.append, link_lost_ms=10_000) as (link, fake):
            await link.identify()
            t = 5_000_000  # the MCU's count; the host has not seen any of it yet
            for i in range(60):  # 60 frames 1 ms apart: 14 wraps of v1's 16-bit stamp
                fake.send("state", (t + 16_000 * i) & 0xFFFF_FFFF, i)
            await wait_for(lambda: len(got) == 60)
            fake.frozen = t + 16_000 * 59 + 500
            await link.ping()
            assert [g.mcu_ticks for g in got] == [t + 16_000 * i for i in range(60)]
            assert link.clock is not None and link.clock.to_ticks(time.monotonic()) > got[-1].mcu_ticks
            assert all(g.exact for g in got) and [g.encoder for g in got] == list(range(60))
            assert link.stats().states_unanchored == 0

    run(main)


def test_a_stalled_io_thread_is_not_a_link_loss() -> None:
    # The I/O thread not scheduled for longer than link_lost_ms (a loaded machine), then its loss
    # check running before it read: the frames waiting in the pty prove the link alive.
    # (Declaring it lost reset the SEQ, so the gap before them went uncounted.)
    async def main() -> None:
        got: list[StateSample] = []
        async with pty_link(on_state=got.append, link_lost_ms=50) as (link, fake):
            await link.identify()
            t = fake.frozen = 1_000_000
            await link.ping()
            fake.send("state", t & 0xFFFF_FFFF, 0)
            await wait_for(lambda: len(got) == 1 and link.link_up)
            io = link._io
            io._stop.set()  # fault injection: the I/O thread stops running (the port stays open)
            io._wake()
            assert io._thread is not None
            io._thread.join()
            fake.seq = (fake.seq + 5) & 0xFFFF  # 5 frames lost
            time.sleep(0.08)  # ... past the link timeout, while the MCU kept talking
            fake.send("state", (t + 1600) & 0xFFFF_FFFF, 0)
            io._check_link()  # what the thread runs first when it wakes after its deadline
            assert link.link_up
            await wait_for(lambda: len(got) == 2)
            st = link.stats()
            assert st.link_losses == 0 and st.lost_frames == 5
            assert got[1].mcu_ticks == t + 1600 and got[1].exact  # v2: the stamp is whole

    run(main)


def test_a_blocked_event_loop_still_feeds_the_measurement() -> None:
    """State frames every 1 ms from another thread while the event loop is blocked 0.3 s: each
    reaches on_state (the control thread's measurement) meanwhile, none more than the control
    thread's 40 ms stale limit after the one before (on the event loop they all waited 0.3 s)."""

    async def main() -> None:
        arrived: list[float] = []
        async with pty_link(on_state=lambda s: arrived.append(time.monotonic()), link_lost_ms=50) as (
            link,
            fake,
        ):
            await link.identify()
            stop = threading.Event()

            def mcu() -> None:
                while not stop.is_set():
                    fake.send("state", fake.ticks() & 0xFFFF_FFFF, 0)
                    time.sleep(0.001)

            talker = threading.Thread(target=mcu)
            talker.start()
            try:
                await wait_for(lambda: len(arrived) > 10)
                t0 = time.monotonic()
                time.sleep(0.3)  # the event loop blocked
                t1 = time.monotonic()
            finally:
                stop.set()
                talker.join()
            during = [a for a in arrived if t0 <= a <= t1]
            gaps = [b - a for a, b in zip([t0, *during], [*during, t1], strict=True)]
            assert max(gaps) < 0.040, max(gaps)
            assert link.stats().link_losses == 0

    run(main)
