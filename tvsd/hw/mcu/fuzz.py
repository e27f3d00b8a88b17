"""Corrupted-stream fuzz of the host's frame decoder (``python -m tvsd.hw.mcu.fuzz``).

The same corruption model as the firmware's (firmware/tests/fuzz.c, run by ``make -C firmware
fuzz`` together with this): random valid MCU -> host frames with SEQ counting up; on average every
other frame is damaged by one of

    flip       1..3 random bits anywhere in the frame
    drop       one byte removed
    insert     one byte inserted (a SYNC half of the time: a false frame start)
    duplicate  the whole frame sent twice (half the time) or one byte repeated
    truncate   the frame cut short at a random point (the next frame follows at once)
    burst      a run of 2..8 bytes overwritten with random ones

and the stream goes to :class:`~tvsd.hw.mcu.framing.FrameDecoder` in random chunks. A frame the
decoder hands over is a *false accept* unless it is byte-identical to the frame sent under its SEQ;
a frame handed over twice in a row is a *duplicate executed*. Exit status 1 if either happens.
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from tvsd.hw.mcu.framing import Frame, FrameDecoder, encode_frame
from tvsd.hw.mcu.spec import ProtocolSpec, load_spec

OPS = ("flip", "drop", "insert", "duplicate", "truncate", "burst")


class Decoder(Protocol):
    def feed(self, data: bytes) -> list[Frame]: ...


@dataclass
class FuzzResult:
    frames: int = 0  # frames put on the line
    corrupted: int = 0
    intact: int = 0
    delivered: int = 0  # handed over, byte-identical to the frame sent under that SEQ
    false_accepts: int = 0
    duplicates_run: int = 0
    by_op: dict[str, int] = field(default_factory=lambda: dict.fromkeys(OPS, 0))
    seconds: float = 0.0
    decoder_stats: dict[str, int] = field(default_factory=dict)


class TruncatedCheckDecoder:
    """A decoder that compares only the low ``bits`` of the CRC-32: the same resync rules, a
    weaker check. Not used on the line; it shows what the harness reports for a check of v1's
    strength (``--check-bits 16``), so a 0 for the real decoder means something."""

    def __init__(self, spec: ProtocolSpec, bits: int) -> None:
        import zlib

        self._crc = zlib.crc32
        self.mask = (1 << bits) - 1
        self.sync = spec.sync
        self.sizes = spec.payload_sizes("m2h")
        self.buf = bytearray()
        self.last: int | None = None

    def feed(self, data: bytes) -> list[Frame]:
        buf = self.buf
        buf += data
        out: list[Frame] = []
        pos = 0
        while pos < len(buf):
            if buf[pos] != self.sync:
                pos += 1
                continue
            if len(buf) - pos < 5:
                break
            length = buf[pos + 1]
            if self.sizes.get(buf[pos + 4]) != length:
                pos += 1
                continue
            body, end = pos + 5 + length, pos + 9 + length
            if len(buf) < end:
                break
            if (self._crc(buf[pos:body]) ^ int.from_bytes(buf[body:end], "little")) & self.mask:
                pos += 1
                continue
            seq = buf[pos + 2] | buf[pos + 3] << 8
            if seq != self.last:
                out.append(Frame(seq, buf[pos + 4], bytes(buf[pos + 5 : body])))
            self.last = seq
            pos = end
        del buf[:pos]
        return out


def _corrupt(rng: random.Random, f: bytes, op: str, sync: int) -> bytes:
    n = len(f)
    w = bytearray(f)
    at = rng.randrange(n)
    if op == "flip":
        for _ in range(rng.randint(1, 3)):
            w[rng.randrange(n)] ^= 1 << rng.randrange(8)
    elif op == "drop":
        del w[at]
    elif op == "insert":
        w.insert(at, sync if rng.random() < 0.5 else rng.randrange(256))
    elif op == "duplicate":
        if rng.random() < 0.5:
            return f + f
        w.insert(at, w[at])
    elif op == "truncate":
        del w[at:]
    else:  # burst
        for i in range(at, min(n, at + rng.randint(2, 8))):
            w[i] = rng.randrange(256)
    return bytes(w)


def fuzz_decoder(
    corrupted: int,
    seed: int = 1,
    spec: ProtocolSpec | None = None,
    make_decoder: Callable[[ProtocolSpec], Decoder] | None = None,
) -> FuzzResult:
    """Run until ``corrupted`` frames have been damaged (about half of all frames are)."""
    spec = spec or load_spec()
    dec = (
        make_decoder(spec)
        if make_decoder is not None
        else FrameDecoder(spec.sync, spec.max_payload, spec.payload_sizes("m2h"))
    )
    m2h = [m for m in spec.messages if m.dir == "m2h"]
    rng = random.Random(seed)
    sent: list[tuple[int, bytes] | None] = [None] * 0x1_0000
    res = FuzzResult()
    last: Frame | None = None
    pending = bytearray()
    t0 = time.perf_counter()
    seq = 0

    def deliver(frames: list[Frame]) -> None:
        nonlocal last
        for fr in frames:
            if sent[fr.seq] != (fr.msg_id, fr.payload):
                res.false_accepts += 1
            elif last is not None and (last.seq, last.payload) == (fr.seq, fr.payload):
                res.duplicates_run += 1
            else:
                res.delivered += 1
                last = fr

    while res.corrupted < corrupted:
        m = rng.choice(m2h)
        payload = rng.randbytes(m.size)
        sent[seq] = (m.id, payload)
        f = encode_frame(seq, m.id, payload, spec.sync)
        seq = (seq + 1) & 0xFFFF
        res.frames += 1
        if rng.random() < 0.5:
            pending += f
            res.intact += 1
        else:
            op = rng.choice(OPS)
            res.corrupted += 1
            res.by_op[op] += 1
            pending += _corrupt(rng, f, op, spec.sync)
        if len(pending) >= 64:  # reads of 1..64 bytes, as os.read hands them over
            cut = rng.randint(1, len(pending))
            deliver(dec.feed(bytes(pending[:cut])))
            del pending[:cut]
    deliver(dec.feed(bytes(pending)))
    res.seconds = time.perf_counter() - t0
    if isinstance(dec, FrameDecoder):
        res.decoder_stats = dec.stats.as_dict()
    return res


def report(res: FuzzResult, name: str = "host decoder (tvsd/hw/mcu/framing.py)") -> str:
    ops = ", ".join(f"{k} {v}" for k, v in res.by_op.items())
    st = res.decoder_stats
    counters = (
        f", crc_errors {st['crc_errors']}, bad_headers {st['bad_headers']}, resyncs {st['resyncs']}, "
        f"duplicates dropped {st['duplicates']}"
        if st
        else ""
    )
    return (
        f"{name}\n"
        f"  frames {res.frames}, corrupted {res.corrupted} ({ops})\n"
        f"  intact {res.intact}, delivered {res.delivered}{counters}, {res.seconds:.1f} s\n"
        f"  FALSE ACCEPTS {res.false_accepts}, duplicates executed {res.duplicates_run}"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000, help="corrupted frames to run")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--check-bits",
        type=int,
        default=32,
        help="compare only this many CRC bits (16 shows what a v1-strength check lets through)",
    )
    args = ap.parse_args(argv)
    if args.frames < 1:
        print(f"fuzz: --frames must be at least 1, got {args.frames}", file=sys.stderr)
        return 2
    if not 1 <= args.check_bits <= 32:
        print(f"fuzz: --check-bits must be 1..32, got {args.check_bits}", file=sys.stderr)
        return 2
    if args.check_bits == 32:
        res = fuzz_decoder(args.frames, args.seed)
        name = "host decoder (tvsd/hw/mcu/framing.py)"
    else:
        bits = args.check_bits
        res = fuzz_decoder(args.frames, args.seed, make_decoder=lambda s: TruncatedCheckDecoder(s, bits))
        name = f"reference decoder with a {bits}-bit check (not the real one: a contrast)"
    print(f"seed {args.seed}")
    print(report(res, name))
    return 1 if res.false_accepts or res.duplicates_run else 0


if __name__ == "__main__":
    sys.exit(main())
