"""Framing (protocol v2): CRC-32, encoder, and the incremental decoder under a damaged byte stream."""

from __future__ import annotations

import itertools
import random
import zlib
from dataclasses import dataclass

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tvsd.hw.mcu.framing import (
    Frame,
    FrameDecoder,
    bench_decode,
    crc32,
    encode_frame,
)
from tvsd.hw.mcu.spec import load_spec

SPEC = load_spec()
M2H = [m for m in SPEC.messages if m.dir == "m2h"]
SIZES = SPEC.payload_sizes("m2h")


def _crc32_bitwise(data: bytes) -> int:
    crc = 0xFFFF_FFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xEDB8_8320 if crc & 1 else crc >> 1
    return crc ^ 0xFFFF_FFFF


def test_crc_check_value() -> None:
    # The catalogue check value of CRC-32/ISO-HDLC (the firmware's test checks the same).
    assert crc32(b"123456789") == 0xCBF4_3926


@given(st.binary(max_size=64))
def test_crc_equals_the_definition(data: bytes) -> None:
    assert crc32(data) == _crc32_bitwise(data)


def test_every_message_round_trips() -> None:
    for i, m in enumerate(SPEC.messages):
        payload = bytes(range(m.size))
        dec = FrameDecoder(payload_sizes={m.id: m.size})
        assert dec.feed(encode_frame(i, m.id, payload)) == [Frame(i, m.id, payload)]


def test_frame_layout() -> None:
    f = encode_frame(0x1234, 0x83, b"\x01\x02\x03\x04\x05\x06")
    assert f[:5] == bytes((0xA5, 6, 0x34, 0x12, 0x83)) and len(f) == 6 + 9
    # SYNC and LEN are under the check
    assert int.from_bytes(f[-4:], "little") == zlib.crc32(f[:-4])


def test_sync_and_len_are_under_the_crc() -> None:
    good = bytearray(encode_frame(1, 0x82, bytes(8)))
    dec = FrameDecoder(sync=0x5A)
    other_sync = bytes((0x5A,)) + good[1:]  # same body and CRC behind another SYNC byte
    assert dec.feed(other_sync) == [] and dec.stats.crc_errors == 1


def test_impossible_len_resyncs_at_once_and_keeps_next_frame() -> None:
    good = encode_frame(1, 0x83, b"abcdef")
    dec = FrameDecoder(payload_sizes=SIZES)
    # LEN 200 > max_payload: refused after 2 bytes without waiting for 209.
    assert dec.feed(bytes((0xA5, 200, 0, 0, 0x83)) + good) == [Frame(1, 0x83, b"abcdef")]
    assert dec.stats.bad_headers == 1 and dec.stats.resyncs == 1
    assert dec.stats.bytes_dropped == 5


def test_len_not_matching_the_id_is_impossible() -> None:
    dec = FrameDecoder(payload_sizes=SIZES)
    bad = encode_frame(0, 0x83, b"abc")  # state carries 6 bytes, not 3
    assert dec.feed(bad + encode_frame(1, 0x83, b"abcdef")) == [Frame(1, 0x83, b"abcdef")]
    assert dec.stats.bad_headers == 1 and dec.stats.crc_errors == 0


def test_garbage_run_is_one_resync() -> None:
    dec = FrameDecoder()
    out = dec.feed(b"\x00\x11\x22\x33" + encode_frame(5, 0x83, b"uvwxyz"))
    assert out == [Frame(5, 0x83, b"uvwxyz")]
    assert (dec.stats.resyncs, dec.stats.bytes_dropped) == (1, 4)


def test_sequence_gaps_wrap_and_duplicates() -> None:
    dec = FrameDecoder()
    seqs = [65534, 65535, 0, 3, 3, 4]  # wrap, then 1 and 2 lost, then 3 repeated
    out = dec.feed(b"".join(encode_frame(s, 0x87, b"ok!") for s in seqs))
    assert [f.seq for f in out] == [65534, 65535, 0, 3, 4]
    assert [f.gap for f in out] == [0, 0, 0, 2, 0]  # the loss sits before frame 3
    assert (dec.stats.lost_frames, dec.stats.duplicates) == (2, 1)


def test_split_anywhere_gives_the_same_frames() -> None:
    stream = b"".join(encode_frame(i, 0x84, bytes([i] * 7)) for i in range(20))
    for step in (1, 2, 3, 9, 64):
        dec = FrameDecoder(payload_sizes=SIZES)
        out = [f for i in range(0, len(stream), step) for f in dec.feed(stream[i : i + step])]
        assert [f.seq for f in out] == list(range(20)), step


# --- property test: a damaged stream ---------------------------------------------------------

CORRUPTIONS = ("flip", "delete", "truncate", "dup_bytes")
OPS = ("none", "none", "none", "dup_frame", *CORRUPTIONS)


@dataclass
class Planned:
    frame: Frame
    wire: bytes
    op: str


@st.composite
def damaged_streams(draw: st.DrawFn) -> tuple[list[Planned], bytes, list[int]]:
    n = draw(st.integers(2, 40))
    seq0 = draw(st.integers(0, 0xFFFF))
    plan: list[Planned] = []
    for k in range(n):
        m = draw(st.sampled_from(M2H))
        payload = draw(st.binary(min_size=m.size, max_size=m.size))
        frame = Frame((seq0 + k) & 0xFFFF, m.id, payload)
        wire = bytearray(encode_frame(frame.seq, frame.msg_id, payload))
        # The first and last frames stay intact so every loss shows up as a SEQ gap.
        op = "none" if k in (0, n - 1) else draw(st.sampled_from(OPS))
        if op == "flip":  # one byte replaced: a burst of <= 8 bits, which CRC-32 always sees
            i = draw(st.integers(0, len(wire) - 1))
            wire[i] ^= draw(st.integers(1, 255))
        elif op == "delete":
            # (from byte 1: a deleted SYNC after a run ending in 0xA5 would rebuild the frame;
            # flip covers a lost SYNC)
            i = draw(st.integers(1, len(wire) - 1))
            del wire[i : i + draw(st.integers(1, 4))]
        elif op == "truncate":
            wire = wire[: draw(st.integers(1, len(wire) - 1))]
        elif op == "dup_bytes":  # a stuttering line repeats a run inside the frame
            # (from byte 1: a repeated run starting at SYNC is only garbage before an intact frame)
            i = draw(st.integers(1, len(wire) - 2))
            j = draw(st.integers(i + 1, len(wire) - 1))
            wire[j:j] = wire[i:j]
        elif op == "dup_frame":
            wire = wire + wire
        plan.append(Planned(frame, bytes(wire), op))
        if k < n - 1 and draw(st.booleans()):
            plan.append(Planned(frame, draw(st.binary(max_size=12)), "garbage"))
    # A damaged frame can leave a plausible header whose LEN runs past the bytes sent so far; the
    # decoder then waits for up to one longest frame (9 + max_payload = 25 bytes) of later traffic
    # before it can reject it. On the line the 10 kHz state stream supplies that within ~0.2 ms;
    # here a tail of 4 state frames (60 bytes) does.
    for k in range(n, n + 4):
        frame = Frame((seq0 + k) & 0xFFFF, 0x83, draw(st.binary(min_size=6, max_size=6)))
        plan.append(Planned(frame, encode_frame(frame.seq, frame.msg_id, frame.payload), "none"))
    stream = b"".join(p.wire for p in plan)
    cuts = sorted(draw(st.lists(st.integers(0, len(stream)), max_size=12)))
    return plan, stream, cuts


# derandomize: a deletion or truncation is caught by CRC-32 with probability 1 - 2^-32 per damaged
# frame, not certainly; a fixed example set keeps CI deterministic.
@settings(max_examples=400, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(damaged_streams(), st.booleans())
def test_damaged_stream(case: tuple[list[Planned], bytes, list[int]], use_sizes: bool) -> None:
    plan, stream, cuts = case
    dec = FrameDecoder(payload_sizes=SIZES if use_sizes else None)
    out: list[Frame] = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += dec.feed(stream[a:b])
    intact = [p.frame for p in plan if p.op in ("none", "dup_frame")]
    damaged = [p.frame for p in plan if p.op in CORRUPTIONS]
    frames = [p for p in plan if p.op != "garbage"]
    # Delivered in order, at most once each, and never altered: a damaged frame comes through
    # only where the bytes after it rebuilt it exactly (its cut last byte equals the next byte).
    assert out == sorted(set(out), key=lambda f: f.seq - plan[0].frame.seq & 0xFFFF)
    assert set(out) <= set(intact) | set(damaged)
    rebuilt = {f for f in out if f in damaged}
    # Every untouched frame is delivered, except one whose SYNC was taken to rebuild the
    # damaged frame just before it (a lost last CRC byte that equalled 0xA5: the CRC cannot
    # cover itself, so no receiver can tell; the frame is then rebuilt exactly, not altered).
    for prev, cur in itertools.pairwise(frames):
        if cur.op in ("none", "dup_frame") and cur.frame not in out:
            assert prev.frame in rebuilt, f"intact frame {cur.frame.seq} lost"
    st_ = dec.stats
    assert st_.frames == len(out)
    # Every frame not delivered is counted as lost by its SEQ gap (runs < 65536 frames).
    assert st_.lost_frames == len({p.frame for p in frames}) - len(out)
    assert st_.duplicates == sum(p.op == "dup_frame" and p.frame in out for p in plan)
    garbage = sum(len(p.wire) for p in plan if p.op == "garbage")
    if damaged or garbage:
        assert st_.resyncs >= 1 and st_.bytes_dropped >= 1
    else:
        assert st_.resyncs == st_.bytes_dropped == st_.crc_errors == 0


@settings(max_examples=200, derandomize=True)
@given(st.binary(max_size=300))
def test_pure_noise_never_raises(noise: bytes) -> None:
    dec = FrameDecoder(payload_sizes=SIZES)
    out = dec.feed(noise)
    # Accepting random bytes needs SYNC, a valid id/LEN pair and a 32-bit CRC match.
    assert len(out) <= 1
    assert dec.stats.bytes_dropped <= len(noise)


def test_random_burst_noise_stream_statistics() -> None:
    # 2000 frames with 5 % of them hit by one random byte: each hit must be lost, never delivered.
    rng = random.Random(1)
    dec = FrameDecoder(payload_sizes=SIZES)
    hit = 0
    good = []
    for k in range(2000):
        w = bytearray(encode_frame(k, 0x83, rng.randbytes(6)))
        if rng.random() < 0.05 and k < 1999:
            w[rng.randrange(len(w))] ^= rng.randrange(1, 256)
            hit += 1
        else:
            good.append(k & 0xFFFF)
        dec.feed(bytes(w))
    assert dec.stats.frames == len(good) and dec.stats.lost_frames == hit


def test_bench_decode_is_fast_enough_for_10khz() -> None:
    r = bench_decode(20_000)
    print(f"decode: {r['us_per_frame']:.2f} µs/frame, {r['frames_per_s']:.0f} frames/s")
    # The 10 kHz state stream leaves 100 µs per frame for everything; decoding may take a
    # quarter of it on a slow CI machine (a Pi 4 measures ~5 µs/frame).
    assert r["us_per_frame"] < 25.0
    assert r["frames"] == 20_000


@pytest.mark.parametrize("chunk", [1, 7, 4096])
def test_bench_decode_chunk_sizes(chunk: int) -> None:
    assert bench_decode(2_000, chunk)["frames"] == 2_000


# --- the fuzz (the long run is `make -C firmware fuzz`: >= 10^6 corrupted frames each side) ----


def test_fuzz_seeded_no_false_accept_no_duplicate_run() -> None:
    """20 000 corrupted frames (flips, drops, inserts, duplicates, truncation, bursts) through
    the real decoder: nothing false is accepted, no repeated frame is handed over twice, and the
    intact frames around the damage survive. Expected false accepts for a 32-bit check: about
    (candidate windows ≈ 2 per damaged frame) × 2^-32 ≈ 1e-5 here, so any accept is a bug."""
    from tvsd.hw.mcu.fuzz import fuzz_decoder

    r = fuzz_decoder(20_000, seed=7)
    assert r.corrupted == 20_000 and all(v > 3000 for v in r.by_op.values())
    assert r.false_accepts == 0 and r.duplicates_run == 0
    assert r.decoder_stats["duplicates"] > 0  # whole-frame duplicates were seen and dropped
    # every intact frame (and the duplicated ones) comes through, give or take the few a
    # damaged header holds up past the end of the run
    assert r.delivered >= 0.99 * r.intact


def test_fuzz_harness_reports_a_weak_check() -> None:
    """The harness can fail: the same stream through a decoder that compares only 4 CRC bits
    lets damaged frames through (about 1 in 16 candidate windows), and they are counted."""
    from tvsd.hw.mcu.fuzz import TruncatedCheckDecoder, fuzz_decoder

    r = fuzz_decoder(2_000, seed=7, make_decoder=lambda s: TruncatedCheckDecoder(s, 4))
    assert r.false_accepts > 10


def test_the_decoders_default_max_payload_is_the_protocols() -> None:
    from tvsd.hw.mcu.framing import MAX_PAYLOAD

    assert SPEC.max_payload == MAX_PAYLOAD
