"""The virtual MCU (firmware core on the host) through a real pty and pyserial.

Frames are built here from firmware/protocol.yaml with a few lines of struct, on purpose: the
host codec (tvsd/hw/mcu) is tested elsewhere, and this test must catch a firmware that drifts
from the spec even if both sides drifted together.
"""

from __future__ import annotations

import math
import re
import struct
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import pytest
import serial
import yaml

from tvsd.sim.virtual_mcu import PULSE_OPTICAL, PULSE_ZERO, VirtualMcu

SPEC_PATH = Path(__file__).resolve().parents[1] / "firmware" / "protocol.yaml"
CLOCK_HZ = 16_000_000
TICK_S = 1e-4  # the core's control tick: watchdog and state frames are checked once per tick
FMT = {"u8": "B", "i8": "b", "u16": "H", "i16": "h", "u32": "I", "i32": "i"}


class _Yaml12(yaml.SafeLoader):
    """YAML 1.2 booleans: `on` (laser_set's field) stays a string."""


_Yaml12.yaml_implicit_resolvers = {
    k: [(tag, rx) for tag, rx in v if tag != "tag:yaml.org,2002:bool"]
    for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Yaml12.add_implicit_resolver(
    "tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF")
)
SPEC = yaml.load(SPEC_PATH.read_text(), Loader=_Yaml12)
MSG = {m["name"]: m for m in SPEC["messages"]}
BY_ID = {m["id"]: m for m in SPEC["messages"]}
FAULTS = {name: code for code, name in SPEC["fault_codes"].items()}


def _struct(name: str) -> struct.Struct:
    return struct.Struct("<" + "".join(FMT[t] for _, t in MSG[name]["fields"]))


def encode(name: str, seq: int = 0, **fields: int) -> bytes:
    m = MSG[name]
    payload = _struct(name).pack(*(fields[f] for f, _ in m["fields"]))
    # v2: SYNC LEN SEQ(u16) ID PAYLOAD, then CRC-32 (zlib) over all of it
    body = struct.pack("<BBHB", SPEC["sync"], len(payload), seq, m["id"]) + payload
    return body + struct.pack("<I", zlib.crc32(body))


@dataclass
class Frame:
    seq: int
    name: str
    fields: dict[str, int]


class Reader:
    """Frames from the pty; the CRC of each is checked."""

    def __init__(self, port: serial.Serial) -> None:
        self.port = port
        self.buf = bytearray()

    def frames(self, timeout: float) -> Iterator[Frame]:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.buf += self.port.read(max(1, self.port.in_waiting))
            while len(self.buf) >= 9:
                if self.buf[0] != SPEC["sync"]:
                    del self.buf[0]
                    continue
                n = self.buf[1] + 9
                if len(self.buf) < n:
                    break
                raw = bytes(self.buf[:n])
                del self.buf[:n]
                crc = zlib.crc32(raw[:-4])
                assert crc == struct.unpack("<I", raw[-4:])[0], f"bad CRC in {raw.hex()}"
                seq, msg_id = struct.unpack("<HB", raw[2:5])
                m = BY_ID[msg_id]
                values = _struct(m["name"]).unpack(raw[5:-4])
                yield Frame(seq, m["name"], dict(zip([f for f, _ in m["fields"]], values, strict=True)))

    def wait(self, name: str, timeout: float = 2.0) -> Frame:
        for f in self.frames(timeout):
            if f.name == name:
                return f
        raise AssertionError(f"no {name} frame within {timeout} s")

    def collect(self, name: str, timeout: float) -> list[Frame]:
        return [f for f in self.frames(timeout) if f.name == name]


def _tick_steps(states: list[Frame]) -> set[int]:
    return {(b.fields["ticks"] - a.fields["ticks"]) % 2**32 for a, b in pairwise(states)}


@pytest.fixture
def manual() -> Iterator[tuple[VirtualMcu, serial.Serial, Reader]]:
    with VirtualMcu(clock="manual", counts_per_rev=4096, drive_volts=24.0) as vm:
        port = serial.Serial(vm.port, timeout=0.05)
        try:
            yield vm, port, Reader(port)
        finally:
            port.close()


def _arm(port: serial.Serial, rd: Reader, watchdog_ms: int, state_div: int) -> None:
    port.write(encode("config_set", 1, watchdog_ms=watchdog_ms, state_div=state_div, max_on_ms=0))
    assert rd.wait("ack").fields == {"seq": 1, "status": 0}
    port.write(encode("heartbeat", 2, host_us=7))
    assert rd.wait("heartbeat_ack").fields["host_us"] == 7  # handled: the watchdog runs


def test_identify_matches_spec() -> None:
    canonical = "".join(
        f"{m['id']}:{m['name']}:" + ",".join(f"{f}:{t}" for f, t in m["fields"]) + "\n"
        for m in sorted(SPEC["messages"], key=lambda m: m["id"])
    )
    # manual clock: no time passes, so no state frame can come first and take SEQ 0
    with VirtualMcu(clock="manual") as vm, serial.Serial(vm.port, timeout=0.05) as port:
        port.write(encode("identify_req", 5))
        f = Reader(port).wait("identify")
    assert f.fields == {
        "proto_version": SPEC["version"],
        "clock_hz": CLOCK_HZ,
        "table_hash": zlib.crc32(canonical.encode()),
        "board": 2,  # host, per protocol.yaml boards:
    }
    assert f.seq == 0  # the first frame the MCU sent


def test_pwm_set_reaches_plant(manual: tuple[VirtualMcu, serial.Serial, Reader]) -> None:
    vm, port, rd = manual
    port.write(encode("pwm_set", 0, duty=16384))
    assert rd.wait("ack").fields == {"seq": 0, "status": 2}  # refused: no heartbeat yet
    assert vm.pwm_duty == 0.0
    _arm(port, rd, watchdog_ms=500, state_div=0)
    port.write(encode("pwm_set", 3, duty=-16384))
    port.write(encode("laser_set", 4, on=1))
    assert rd.wait("ack").fields == {"seq": 4, "status": 0}  # frames are handled in order
    assert vm.pwm_duty == pytest.approx(-16384 / 32767, abs=1e-12)
    assert vm.motor_volts == pytest.approx(-24.0 * 16384 / 32767, abs=1e-9)
    assert vm.laser_on


def test_watchdog_cuts_outputs(manual: tuple[VirtualMcu, serial.Serial, Reader]) -> None:
    vm, port, rd = manual
    _arm(port, rd, watchdog_ms=50, state_div=0)
    t_hb = vm.time_s  # the heartbeat was handled at this simulated time
    port.write(encode("pwm_set", 3, duty=30000))
    port.write(encode("laser_set", 4, on=1))
    rd.wait("ack")
    vm.advance_to(t_hb + 0.050 - TICK_S)
    assert vm.pwm_duty > 0 and vm.laser_on, "cut before the watchdog time"
    # The deadline is checked every control tick: off at most one tick after 50 ms.
    vm.advance_to(t_hb + 0.050 + TICK_S)
    assert vm.pwm_duty == 0.0 and not vm.laser_on
    fault = rd.wait("fault")
    assert fault.fields == {"code": FAULTS["watchdog_expired"], "detail": 50}


def test_encoder_follows_shaft(manual: tuple[VirtualMcu, serial.Serial, Reader]) -> None:
    vm, port, rd = manual
    _arm(port, rd, watchdog_ms=1000, state_div=1)
    t = vm.time_s
    angles = [0.3, -1.0, 7.5, 100.0]  # 100 rad = 65190 counts: encoder16 wraps
    for i, a in enumerate(angles):
        vm.set_shaft(a, t + (i + 1) * 0.001)  # the count holds from this time on
    vm.advance_to(t + (len(angles) + 1) * 0.001)
    states = rd.collect("state", timeout=0.3)
    # state frames sample the encoder each 0.1 ms tick: each 1 ms step shows
    # round(angle / 2 pi * 4096), as i16 on the wire
    want = [((round(a / math.tau * 4096) + 2**15) % 2**16) - 2**15 for a in angles]
    seen = [s.fields["encoder16"] for s in states]
    for w in want:
        assert w in seen, f"encoder16 {w} never reported; saw {sorted(set(seen))}"
    assert _tick_steps(states) == {CLOCK_HZ // 10_000}, "one state frame per tick, none lost"


def test_encoder_moves_linearly_between_feeds_on_the_manual_clock(
    manual: tuple[VirtualMcu, serial.Serial, Reader],
) -> None:
    """A real encoder counts all the way: each control tick between two feeds samples the
    linear ramp, also across a whole revolution (whose zero pulse advances the core mid-ramp)."""
    vm, port, rd = manual
    _arm(port, rd, watchdog_ms=1000, state_div=1)
    t0 = round(vm.time_s / TICK_S) * TICK_S + 0.001  # feeds on tick times
    a0, a1 = 6.0, 6.0 + 0.5  # crosses 2π
    vm.set_shaft(a0, t0)
    vm.set_shaft(a1, t0 + 0.001)
    vm.advance_to(t0 + 0.0015)
    states = rd.collect("state", timeout=0.3)
    counts = {}
    for st in states:
        counts[st.fields["ticks"]] = st.fields["encoder16"]
    for k in range(1, 10):  # the 9 ticks strictly inside the 1 ms ramp
        t = t0 + k * TICK_S
        want = round((a0 + (a1 - a0) * k / 10) / math.tau * 4096)
        assert counts[round(t * CLOCK_HZ) % 2**32] == want, f"tick {k}"


def test_a_zero_pulse_on_the_feeds_own_tick_does_not_sample_the_old_count(
    manual: tuple[VirtualMcu, serial.Serial, Reader],
) -> None:
    """A revolution completed exactly at a feed's time: its zero pulse advances the core through
    that tick before the feed sets the new count. The tick must still read the shaft there, not
    the count of the feed before (1 ms old: in a SIL identify export a step in phi of 0.08 rad
    and back, named `cogging` of order 13 at z 95)."""
    vm, port, rd = manual
    _arm(port, rd, watchdog_ms=1000, state_div=1)
    t0 = round(vm.time_s / TICK_S) * TICK_S + 0.001  # feeds on tick times
    a0, a1 = math.tau - 0.5, math.tau  # the crossing of 2π at the second feed's own time
    vm.set_shaft(a0, t0)
    vm.set_shaft(a1, t0 + 0.001)
    vm.set_shaft(a1 + 0.5, t0 + 0.002)
    vm.advance_to(t0 + 0.0025)
    counts = {st.fields["ticks"]: st.fields["encoder16"] for st in rd.collect("state", timeout=0.3)}
    assert counts[round((t0 + 0.001) * CLOCK_HZ) % 2**32] == round(a1 / math.tau * 4096)


def test_pulse_events_sequence(manual: tuple[VirtualMcu, serial.Serial, Reader]) -> None:
    vm, _, rd = manual
    vm.set_shaft(0.0, 0.010)
    vm.pulse(PULSE_OPTICAL, 0.0105)
    vm.set_shaft(2 * math.tau + 1.0, 0.030)  # crosses 2 pi and 4 pi: two zero pulses
    vm.pulse(PULSE_OPTICAL, 0.031)
    pulses = rd.collect("pulse", timeout=0.3)
    got = [(p.fields["channel"], p.fields["event_seq"], p.fields["mcu_ticks"]) for p in pulses]
    rate = (2 * math.tau + 1.0) / 0.020  # rad/s between the two set_shaft calls
    t_zero = [0.010 + k * math.tau / rate for k in (1, 2)]
    expect = [
        (PULSE_OPTICAL, 0, round(0.0105 * CLOCK_HZ)),
        (PULSE_ZERO, 1, round(t_zero[0] * CLOCK_HZ)),
        (PULSE_ZERO, 2, round(t_zero[1] * CLOCK_HZ)),
        (PULSE_OPTICAL, 3, round(0.031 * CLOCK_HZ)),
    ]
    assert got == expect


def test_wall_clock_runs_core() -> None:
    """With the wall clock, the core's time follows the monotonic clock (state frames come
    at their rate, none lost); 30 % slack covers a busy CI machine's thread wake-ups."""
    with VirtualMcu() as vm, serial.Serial(vm.port, timeout=0.05) as port:
        rd = Reader(port)
        port.write(encode("config_set", 1, watchdog_ms=1000, state_div=10, max_on_ms=0))
        rd.wait("ack")
        t0 = time.monotonic()
        states = rd.collect("state", timeout=0.5)
        elapsed = time.monotonic() - t0
    assert len(states) == pytest.approx(elapsed * 1000, rel=0.3)
    assert _tick_steps(states) == {10 * CLOCK_HZ // 10_000}


def test_steppers_move_and_home(manual: tuple[VirtualMcu, serial.Serial, Reader]) -> None:
    vm, port, rd = manual
    _arm(port, rd, watchdog_ms=5000, state_div=0)
    t = vm.time_s
    port.write(encode("stepper_move", 3, axis=0, steps=-200, rate_sps=1000, accel_sps2=5000))
    assert rd.wait("ack").fields == {"seq": 3, "status": 0}
    vm.set_limit(1, -50)  # axis 1's home switch closes 50 steps below where it starts
    port.write(encode("stepper_home", 4, axis=1))
    assert rd.wait("ack").fields == {"seq": 4, "status": 0}
    # 200 steps: 100-step ramps each way at 5000 sps^2 peak at sqrt(a n) = 707 sps, 0.28 s in
    # all; homing: 50 steps at 500 sps = 0.1 s. 1 s covers both with room.
    final: dict[int, dict[str, int]] = {}  # last stepper_state per axis
    for k in range(1, 11):
        vm.advance_to(t + 0.1 * k)
        port.write(encode("heartbeat", 5 + k, host_us=k))
        for f in rd.frames(2.0):
            if f.name == "stepper_state":
                final[f.fields["axis"]] = f.fields
            if f.name == "heartbeat_ack":
                break
    assert vm.stepper_position(0) == -200 and vm.step_count(0) == 200
    assert vm.stepper_position(1) == -50  # the mechanism stopped on the switch
    assert final[0] == {"axis": 0, "position": -200, "flags": 0}
    assert final[1] == {"axis": 1, "position": 0, "flags": 2 | 4}  # homed, at limit


def test_long_advance_loses_no_frame(manual: tuple[VirtualMcu, serial.Serial, Reader]) -> None:
    # One 0.2 s step of the clock (a plant stepping coarsely, or the pump woken late on a loaded
    # host) makes 2000 state frames at state_div 1, 30 kB; the host build's TX ring holds 8 kB.
    # The UART drains it while time runs (1 ms slices), as the chip's UART would: no SEQ gap,
    # no tx_overflow fault.
    vm, port, rd = manual
    _arm(port, rd, watchdog_ms=1000, state_div=1)
    vm.advance_to(vm.time_s + 0.2)
    frames = list(rd.frames(0.5))
    states = [f for f in frames if f.name == "state"]
    assert len(states) >= 2000 and not [f for f in frames if f.name == "fault"]
    assert {(b.seq - a.seq) % 2**16 for a, b in pairwise(frames)} == {1}
    assert _tick_steps(states) == {CLOCK_HZ // 10_000}


def test_a_heartbeat_read_late_enters_the_core_at_its_own_send_time(
    manual: tuple[VirtualMcu, serial.Serial, Reader],
) -> None:
    """On a paced line (rx_timeline: host time → core time, as McuPlant sets it), a heartbeat
    whose host_us says it was built 40 ms before it could be read enters the core at that
    time, not at the read: host bytes reach the pty through the kernel's tty flip-buffer work,
    which CPU load delays by tens of ms, and a real wire would have had them at once.
    Tolerance: host_us has 1 µs steps and the core 62.5 ns ticks: 2 µs; the read's own time
    (the old stamp) is ≥ 40 ms later."""
    vm, port, rd = manual
    _arm(port, rd, watchdog_ms=1000, state_div=10)
    base = time.monotonic() - 1.0  # host time `base` is core time 0: now is ~1 s
    vm.advance_to(0.5)
    vm.rx_timeline = lambda t: t - base
    sent = time.monotonic() - 0.040
    host_us = int(sent * 1e6) & 0xFFFF_FFFF
    port.write(encode("heartbeat", 4, host_us=host_us))
    assert until_queued(vm)
    vm.advance_to(time.monotonic() - base + 0.5)  # the core past the read's own time
    ack = rd.wait("heartbeat_ack")
    assert ack.fields["host_us"] == host_us
    assert ack.fields["mcu_ticks"] / CLOCK_HZ == pytest.approx(int(sent * 1e6) / 1e6 - base, abs=2e-6)


def until_queued(vm: VirtualMcu, timeout: float = 5.0) -> bool:
    """The pump has read the host's bytes (they wait in the core's queue for their time)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if vm._rx_queue:
            return True
        time.sleep(0.001)
    return False


def test_a_heartbeat_split_across_two_reads_is_still_found() -> None:
    """The pty hands bytes over in any cut: a heartbeat whose first bytes came in the previous
    read still cuts the second at its end, with its own send time."""
    with VirtualMcu(clock="manual") as vm:
        arrival = time.monotonic()
        host_us = int((arrival - 0.030) * 1e6) & 0xFFFF_FFFF
        hb, pwm = encode("heartbeat", 9, host_us=host_us), encode("pwm_set", 10, duty=5)
        first = vm._wire.sent_times(pwm + hb[:6], arrival)
        second = vm._wire.sent_times(hb[6:] + pwm, arrival)
    assert first == [(arrival, pwm + hb[:6])]
    (t_hb, part_hb), (t_rest, rest) = second
    assert part_hb == hb[6:] and t_hb == pytest.approx(arrival - 0.030, abs=2e-6)
    assert rest == pwm and t_rest == arrival
