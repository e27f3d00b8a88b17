"""CAN bridge: frame round trips (pure functions) and the bridge on python-can's virtual bus.

The bus tests put two virtual buses on one channel — the bridge's and the robot's — as python-can's
own back-to-back tests do; each test uses its own channel name so tests cannot hear each other.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import statistics
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import can
import pytest
from can.interfaces.virtual import VirtualBus
from hypothesis import given
from hypothesis import strategies as st

from tvsd.errors import ConfigError
from tvsd.hw.can.bridge import CanBridge, CanSettings
from tvsd.hw.can.frames import (
    FLAG_SATURATED,
    SIGMA_LSB_M,
    SIGMA_MAX,
    XYZ_LSB_M,
    XYZ_MAX,
    XYZ_MIN,
    Ack,
    BadFrame,
    Command,
    CommandCode,
    Reason,
    State,
    decode_ack,
    decode_command,
    decode_point,
    decode_status,
    encode_ack,
    encode_command,
    encode_point,
    encode_status,
    point_part,
)
from tvsd.scan.points import FLAG_COMPENSATED, FLAG_VIBRATION
from tvsd.schema import Where, build, load_yaml

BASE = 0x580
CMD, ACK, STATUS, POINT = BASE, BASE + 1, BASE + 2, BASE + 3
_channels = itertools.count()

# --- pure frames -----------------------------------------------------------------------------------

coord = st.floats(XYZ_MIN * XYZ_LSB_M, XYZ_MAX * XYZ_LSB_M)
sigma = st.floats(0.0, SIGMA_MAX * SIGMA_LSB_M)


def _record(x: float, y: float, z: float, sx: float, sy: float, sz: float, flags: int) -> dict[str, Any]:
    return {"t": 1.0, "x": x, "y": y, "z": z, "sigma_x": sx, "sigma_y": sy, "sigma_z": sz, "flags": flags}


@given(coord, coord, coord, sigma, sigma, sigma, st.integers(0, FLAG_SATURATED - 1), st.integers(0, 255))
def test_point_round_trips_to_the_stated_resolution(
    x: float, y: float, z: float, sx: float, sy: float, sz: float, flags: int, seq: int
) -> None:
    p0, p1 = encode_point(_record(x, y, z, sx, sy, sz, flags), seq)
    assert len(p0) == len(p1) == 8
    assert point_part(p0) == (0, seq % 8) and point_part(p1) == (1, seq % 8)
    p = decode_point(p0, p1)
    # Round to nearest: half an LSB, plus float slack for the division.
    for got, want in ((p.x, x), (p.y, y), (p.z, z)):
        assert abs(got - want) <= XYZ_LSB_M / 2 + 1e-12, (got, want)
    for got, want in ((p.sigma_x, sx), (p.sigma_y, sy), (p.sigma_z, sz)):
        assert abs(got - want) <= SIGMA_LSB_M / 2 + 1e-12, (got, want)
    assert p.flags == flags and p.seq == seq % 8


@given(
    st.sampled_from(["x", "y", "z", "sigma_x", "sigma_y", "sigma_z"]),
    st.one_of(st.floats(53.0, 1e9), st.floats(-1e9, -53.0), st.just(math.nan), st.just(math.inf)),
)
def test_out_of_range_saturates_and_flags(key: str, value: float) -> None:
    rec = _record(1.0, 2.0, -0.5, 1e-4, 2e-4, 3e-4, FLAG_VIBRATION)
    rec[key] = value
    p = decode_point(*encode_point(rec, 3))
    assert p.flags == FLAG_VIBRATION | FLAG_SATURATED
    got = getattr(p, key)
    if key.startswith("sigma"):
        want = 0.0 if value < 0 else SIGMA_MAX * SIGMA_LSB_M  # negative σ clamps to 0, NaN/huge to max
    elif math.isnan(value):
        want = 0.0
    else:
        want = XYZ_MAX * XYZ_LSB_M if value > 0 else XYZ_MIN * XYZ_LSB_M
    assert got == pytest.approx(want, abs=1e-9)
    others = {"x": 1.0, "y": 2.0, "z": -0.5, "sigma_x": 1e-4, "sigma_y": 2e-4, "sigma_z": 3e-4}
    for k, v in others.items():
        if k != key:
            assert getattr(p, k) == pytest.approx(v, abs=1e-9), "one saturated field leaves the others"


def test_flag_bits_beyond_the_wire_set_the_saturated_flag() -> None:
    p = decode_point(*encode_point(_record(0, 0, 0, 0, 0, 0, 1 << 20 | FLAG_COMPENSATED), 0))
    assert p.flags == FLAG_COMPENSATED | FLAG_SATURATED


def test_point_parts_of_different_points_do_not_pair() -> None:
    a0, _ = encode_point(_record(0, 0, 0, 0, 0, 0, 0), 1)
    _, b1 = encode_point(_record(0, 0, 0, 0, 0, 0, 0), 2)
    with pytest.raises(BadFrame):
        decode_point(a0, b1)


@given(
    st.sampled_from(list(State)),
    st.floats(0, 655.35),
    st.integers(0, 255),
    st.integers(0, 10**6),
    st.integers(0, 10**6),
    st.integers(0, 10**6),
)
def test_status_round_trips(
    state: State, rps: float, faults: int, missed: int, dropped: int, seq: int
) -> None:
    s = decode_status(encode_status(state, rps, faults, missed, dropped, seq))
    assert s.state is state and abs(s.rps - rps) <= 0.005 + 1e-9 and s.faults == faults
    assert (s.missed_ticks, s.dropped, s.seq) == (missed % 2**16, dropped % 2**8, seq % 2**8), "counters wrap"


def test_status_levels_saturate() -> None:
    s = decode_status(encode_status(State.FAULT, 1e6, 1000, 0, 0, 0))
    assert (s.rps, s.faults) == (655.35, 255)


@given(
    st.one_of(
        st.builds(Command, st.sampled_from([CommandCode.START, CommandCode.STOP]), st.integers(0, 255)),
        st.builds(
            lambda i, r: Command(CommandCode.SPEED, i, rps=r), st.integers(0, 255), st.integers(0, 5000)
        ),
        st.builds(
            lambda i, p, g: Command(CommandCode.AIM, i, phi_deg=p / 100, gamma_deg=g / 100),
            st.integers(0, 255),
            st.integers(-18000, 18000),
            st.integers(-9000, 9000),
        ),
    )
)
def test_command_round_trips(cmd: Command) -> None:
    if cmd.code is CommandCode.SPEED:
        cmd = Command(cmd.code, cmd.cmd_id, rps=(cmd.rps or 0) / 100)
    assert decode_command(encode_command(cmd)) == cmd


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\x01\x07", Reason.BAD_LENGTH),
        (b"", Reason.BAD_LENGTH),
        (b"\x01\x07" + bytes(7), Reason.BAD_LENGTH),
        (b"\x7f\x07" + bytes(6), Reason.UNKNOWN_COMMAND),
        (b"\x03\x07" + (5001).to_bytes(2, "little") + bytes(4), Reason.OUT_OF_RANGE),
        (b"\x04\x07" + (18001).to_bytes(2, "little") + bytes(4), Reason.OUT_OF_RANGE),
        (b"\x04\x07" + bytes(2) + (-9001).to_bytes(2, "little", signed=True) + bytes(2), Reason.OUT_OF_RANGE),
    ],
)
def test_bad_command_frames_name_their_reason(data: bytes, reason: Reason) -> None:
    with pytest.raises(BadFrame) as err:
        decode_command(data)
    assert err.value.reason is reason


def test_ack_round_trips() -> None:
    a = decode_ack(encode_ack(CommandCode.AIM, 42, Ack.refused(Reason.OUT_OF_RANGE)))
    assert (a.code, a.cmd_id, a.accepted, a.reason) == (CommandCode.AIM, 42, False, Reason.OUT_OF_RANGE)
    assert decode_ack(encode_ack(1, 2, Ack.ok())).accepted


def test_settings_are_off_by_default() -> None:
    s = CanSettings()
    assert (s.enabled, s.interface, s.channel, s.bitrate, s.base_id, s.status_hz) == (
        False,
        "socketcan",
        "can0",
        500000,
        0x580,
        10.0,
    )


# --- the bridge on the virtual bus -----------------------------------------------------------------

Handler = Callable[[Command], Awaitable[Ack]] | Callable[[Command], Ack]


def _buses() -> tuple[can.BusABC, can.BusABC]:
    channel = f"tvsd-can-test-{next(_channels)}"
    bridge = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    robot = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    return bridge, robot


async def _recv(robot: can.BusABC, arbitration_id: int, timeout: float = 2.0) -> can.Message:
    """The robot waits for one frame of an id (in a thread: recv blocks)."""
    end = time.monotonic() + timeout
    while (left := end - time.monotonic()) > 0:
        msg = await asyncio.to_thread(robot.recv, min(left, 0.2))
        if msg is not None and msg.arbitration_id == arbitration_id:
            return msg
    raise AssertionError(f"no frame 0x{arbitration_id:03x} within {timeout} s")


def _run(
    body: Callable[[CanBridge, can.BusABC], Awaitable[None]],
    handler: Handler = lambda cmd: Ack.ok(),
    **settings: Any,
) -> CanBridge:
    bus, robot = _buses()

    async def main() -> CanBridge:
        bridge = CanBridge(CanSettings(enabled=True, interface="virtual", **settings), handler, bus=bus)
        await bridge.start()
        try:
            await body(bridge, robot)
        finally:
            await bridge.close()
        return bridge

    try:
        return asyncio.run(main())
    finally:
        bus.shutdown()
        robot.shutdown()


def test_status_frames_arrive_at_about_10_hz() -> None:
    async def body(bridge: CanBridge, robot: can.BusABC) -> None:
        bridge.publish_status({"state": "scanning", "rps": 20.5, "faults": [], "loop": {"missed_ticks": 3}})
        await _recv(robot, STATUS)  # the window starts after the first frame, not at start-up
        frames = []
        end = time.monotonic() + 1.0
        while (left := end - time.monotonic()) > 0:
            msg = await asyncio.to_thread(robot.recv, left)
            if msg is not None and msg.arbitration_id == STATUS:
                frames.append(decode_status(msg.data))
        # The ticker runs on absolute deadlines and skips (never bursts) missed ticks, so on a quiet
        # machine 1 s holds 10 ± 1 frames (window edges). 5..15 leaves room for a loaded CI runner
        # stalling the loop or the reader thread for up to ~0.5 s, and still catches a wrong rate
        # (1 Hz, 100 Hz, or two tickers = 20 Hz) without flaking.
        assert 5 <= len(frames) <= 15, f"{len(frames)} status frames in 1 s, expected ~10"
        last = frames[-1]
        assert (last.state, last.rps, last.faults, last.missed_ticks) == (State.SCANNING, 20.5, 0, 3)
        seqs = [f.seq for f in frames]
        assert all((b - a) % 256 == 1 for a, b in itertools.pairwise(seqs)), f"sequence gaps: {seqs}"

    _run(body)


def test_published_point_arrives_decodable() -> None:
    rec = _record(0.1234, -2.5, 1.00004, 0.00012, 0.0031, 0.65, FLAG_VIBRATION | FLAG_COMPENSATED)

    async def body(bridge: CanBridge, robot: can.BusABC) -> None:
        bridge.publish_point(rec)
        p0 = (await _recv(robot, POINT)).data
        p1 = (await _recv(robot, POINT)).data
        p = decode_point(p0, p1)
        for k in ("x", "y", "z"):
            assert getattr(p, k) == pytest.approx(rec[k], abs=XYZ_LSB_M / 2), k
        for k in ("sigma_x", "sigma_y", "sigma_z"):
            assert getattr(p, k) == pytest.approx(rec[k], abs=SIGMA_LSB_M / 2), k
        assert p.flags == rec["flags"]

    bridge = _run(body)
    assert bridge.stats.dropped == 0 and bridge.stats.tx >= 2


def test_start_command_reaches_the_handler_and_is_acked() -> None:
    seen: list[Command] = []

    async def handler(cmd: Command) -> Ack:
        seen.append(cmd)
        await asyncio.sleep(0)  # an async handler, as the daemon's will be
        return Ack.ok()

    async def body(bridge: CanBridge, robot: can.BusABC) -> None:
        robot.send(
            can.Message(
                arbitration_id=CMD, data=encode_command(Command(CommandCode.START, 17)), is_extended_id=False
            )
        )
        ack = decode_ack((await _recv(robot, ACK)).data)
        assert (ack.code, ack.cmd_id, ack.accepted, ack.reason) == (CommandCode.START, 17, True, Reason.OK)
        aim = Command(CommandCode.AIM, 18, phi_deg=12.34, gamma_deg=-5.0)
        robot.send(can.Message(arbitration_id=CMD, data=encode_command(aim), is_extended_id=False))
        assert decode_ack((await _recv(robot, ACK)).data).cmd_id == 18

    bridge = _run(body, handler)
    assert seen == [
        Command(CommandCode.START, 17),
        Command(CommandCode.AIM, 18, phi_deg=12.34, gamma_deg=-5.0),
    ]
    assert bridge.stats.rx == 2 and bridge.stats.bad_frames == 0


def test_daemon_refusal_and_handler_failure_reach_the_robot() -> None:
    def handler(cmd: Command) -> Ack:  # a plain function works too
        if cmd.code is CommandCode.STOP:
            raise RuntimeError("bug")
        return Ack.refused(Reason.REFUSED)

    async def body(bridge: CanBridge, robot: can.BusABC) -> None:
        for code, want in ((CommandCode.START, Reason.REFUSED), (CommandCode.STOP, Reason.INTERNAL)):
            robot.send(
                can.Message(arbitration_id=CMD, data=encode_command(Command(code, 1)), is_extended_id=False)
            )
            ack = decode_ack((await _recv(robot, ACK)).data)
            assert (ack.accepted, ack.reason) == (False, want)

    _run(body, handler)


def test_malformed_commands_get_refused_acks_and_are_counted() -> None:
    seen: list[Command] = []

    def handler(cmd: Command) -> Ack:
        seen.append(cmd)
        return Ack.ok()

    bad = [
        (b"\x01\x05\x00", Reason.BAD_LENGTH),
        (b"\x99\x06" + bytes(6), Reason.UNKNOWN_COMMAND),
        (b"\x03\x07" + (60000).to_bytes(2, "little") + bytes(4), Reason.OUT_OF_RANGE),
    ]

    async def body(bridge: CanBridge, robot: can.BusABC) -> None:
        # Frames on other ids, extended ids and remote frames belong to other nodes: ignored.
        robot.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        robot.send(can.Message(arbitration_id=CMD, data=b"\x01\x02" + bytes(6), is_extended_id=True))
        robot.send(can.Message(arbitration_id=CMD, is_remote_frame=True, dlc=8, is_extended_id=False))
        for data, reason in bad:
            robot.send(can.Message(arbitration_id=CMD, data=data, is_extended_id=False))
            ack = decode_ack((await _recv(robot, ACK)).data)
            assert (ack.code, ack.cmd_id, ack.accepted, ack.reason) == (data[0], data[1], False, reason)
        assert bridge.running, "bad frames never stop the bridge"

    bridge = _run(body, handler)
    assert seen == [], "bad frames never reach the daemon"
    assert (bridge.stats.rx, bridge.stats.bad_frames) == (3, 3)


def test_point_flood_with_a_tiny_queue_drops_and_counts_without_blocking() -> None:
    n, queue = 2000, 4

    async def body(bridge: CanBridge, robot: can.BusABC) -> None:
        t0 = time.perf_counter()
        for i in range(n):  # far faster than any bus: the tx task cannot run until we yield
            bridge.publish_point(_record(i * 1e-3, 0, 0, 0, 0, 0, 0))
        elapsed = time.perf_counter() - t0
        assert elapsed < 1.0, f"publish_point blocked: {n} calls took {elapsed:.2f} s"
        assert bridge.stats.dropped == n - queue
        frames: list[bytearray] = []
        while len(frames) < 2 * queue:
            frames.append((await _recv(robot, POINT)).data)
        xs = [decode_point(a, b).x for a, b in zip(frames[::2], frames[1::2], strict=True)]
        # Oldest dropped: the robot gets the newest points, in order.
        assert xs == pytest.approx([i * 1e-3 for i in range(n - queue, n)], abs=XYZ_LSB_M)

    bridge = _run(body, point_queue=queue)
    assert bridge.stats.dropped == n - queue


def test_disabled_bridge_does_nothing() -> None:
    bus, robot = _buses()

    async def main() -> None:
        bridge = CanBridge(CanSettings(), lambda cmd: Ack.ok(), bus=bus)
        await bridge.start()
        bridge.publish_point(_record(0, 0, 0, 0, 0, 0, 0))
        assert not bridge.running
        assert await asyncio.to_thread(robot.recv, 0.3) is None, "off by default: nothing on the bus"
        await bridge.close()

    try:
        asyncio.run(main())
    finally:
        bus.shutdown()
        robot.shutdown()


class _SlowBus(VirtualBus):
    """A bus that takes 20 ms a frame (a saturated 125 kbit/s bus, or a busy controller)."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        time.sleep(0.02)
        super().send(msg, timeout)


def test_slow_bus_drops_points_and_never_stalls_the_loop() -> None:
    channel = f"tvsd-can-test-{next(_channels)}"
    bus = _SlowBus(channel=channel, receive_own_messages=False)

    async def main() -> tuple[CanBridge, float]:
        bridge = CanBridge(CanSettings(enabled=True, point_queue=8), lambda cmd: Ack.ok(), bus=bus)
        await bridge.start()
        laps: list[float] = []
        for i in range(100):  # 500 points/s for 0.2 s; the bus takes ~25 points/s
            t0 = time.monotonic()
            bridge.publish_point(_record(i * 1e-3, 0, 0, 0, 0, 0, 0))
            await asyncio.sleep(0.002)
            laps.append(time.monotonic() - t0)
        await bridge.close()
        return bridge, statistics.median(laps)

    try:
        bridge, lap = asyncio.run(main())
    finally:
        bus.shutdown()
    # If sends ran on the loop, nearly every lap would take ≥ 20 ms (one send); through the tx
    # thread a lap is the 2 ms sleep. The median ignores the odd scheduler hiccup of a busy CI host.
    assert lap < 0.010, f"median lap {lap * 1e3:.1f} ms: a slow bus stalls the event loop"
    assert bridge.stats.dropped > 50, bridge.stats
    assert bridge.stats.tx_errors == 0


def test_slow_handler_gets_a_timeout_ack() -> None:
    async def handler(cmd: Command) -> Ack:
        await asyncio.sleep(5)
        return Ack.ok()

    async def body(bridge: CanBridge, robot: can.BusABC) -> None:
        robot.send(
            can.Message(
                arbitration_id=CMD, data=encode_command(Command(CommandCode.STOP, 9)), is_extended_id=False
            )
        )
        ack = decode_ack((await _recv(robot, ACK)).data)
        assert (ack.cmd_id, ack.accepted, ack.reason) == (9, False, Reason.TIMEOUT)

    _run(body, handler, handler_timeout_s=0.1)


def test_settings_are_checked_when_loaded(tmp_path: Path) -> None:
    cfg = tmp_path / "tvsd.yaml"
    cfg.write_text("can:\n  enabled: true\n  base_id: 0x590\n  status_hz: 20\n")
    data = load_yaml(cfg)
    s = build(CanSettings, data["can"], Where(cfg, data.line, "can"))
    assert (s.enabled, s.base_id, s.status_hz) == (True, 0x590, 20.0)
    for bad, words in (("base_id: 0x7FE", "at most"), ("status_hz: 0", "above"), ("bitrat: 1", "bitrate")):
        cfg.write_text(f"can:\n  {bad}\n")
        data = load_yaml(cfg)
        with pytest.raises(ConfigError, match=words):
            build(CanSettings, data["can"], Where(cfg, data.line, "can"))
