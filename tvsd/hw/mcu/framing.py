"""Frames on the MCU serial line (protocol v2): encoder, incremental decoder with resync.

Frame (little-endian): SYNC | LEN u8 | SEQ u16 | ID u8 | PAYLOAD[LEN] | CRC32 u32, the CRC-32
(zlib) over SYNC..PAYLOAD (firmware/protocol.yaml). The decoder takes arbitrary chunks, as
os.read hands them over, and returns whole frames. An impossible header (LEN not the size of ID)
or a bad CRC drops one byte and hunts for the next SYNC in the bytes already held, so a frame that
follows a damaged one is never lost with it. A frame repeating the previous SEQ is dropped.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field

from tvsd.hw.mcu.spec import FRAME_CRC, FRAME_HEADER, FRAME_OVERHEAD, SEQ_MODULO

SYNC = 0xA5
MAX_PAYLOAD = 18  # protocol.yaml max_payload (a test checks they agree)
HEADER = FRAME_HEADER  # SYNC, LEN, SEQ (2), ID
_SEQ_MASK = SEQ_MODULO - 1


def crc32(data: bytes | bytearray | memoryview) -> int:
    """CRC-32/ISO-HDLC (zlib's, in C): what the firmware's table-driven crc32 computes."""
    return zlib.crc32(data)


def encode_frame(seq: int, msg_id: int, payload: bytes = b"", sync: int = SYNC) -> bytes:
    if not 0 <= len(payload) <= 0xFF:
        raise ValueError(f"payload of {len(payload)} bytes does not fit the LEN byte")
    s = seq & _SEQ_MASK
    body = bytes((sync, len(payload), s & 0xFF, s >> 8, msg_id & 0xFF)) + payload
    return body + zlib.crc32(body).to_bytes(FRAME_CRC, "little")


@dataclass(frozen=True, slots=True)
class Frame:
    seq: int
    msg_id: int
    payload: bytes
    # frames missing just before this one by the SEQ gap: lets a consumer place a loss between
    # the frames of one read (stats.lost_frames is only the total after the whole chunk)
    gap: int = field(default=0, compare=False)


@dataclass
class DecoderStats:
    frames: int = 0  # good frames delivered
    crc_errors: int = 0  # complete candidates whose CRC did not match
    bad_headers: int = 0  # impossible LEN (> max, or not the size of that id) or unknown id
    # as the firmware counts it (firmware/PROTOCOL.md), so both sides' stats compare: each bad
    # CRC, each impossible header, and each run of junk where a SYNC was expected
    resyncs: int = 0
    bytes_dropped: int = 0  # bytes discarded while hunting for SYNC
    lost_frames: int = 0  # frames missing by SEQ gaps (modulo 65536: a gap >= 65536 aliases)
    duplicates: int = 0  # a frame repeating the previous SEQ (dropped, not delivered)

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class FrameDecoder:
    """Incremental decoder for one direction of the line.

    ``payload_sizes`` (id -> payload bytes, from the spec) lets the decoder refuse an impossible
    header after 4 bytes instead of waiting for a LEN-long frame and its CRC, and refuse ids this
    direction never carries.
    """

    def __init__(
        self,
        sync: int = SYNC,
        max_payload: int = MAX_PAYLOAD,
        payload_sizes: Mapping[int, int] | None = None,
    ) -> None:
        self.sync = sync
        self.max_payload = max_payload
        self.payload_sizes = dict(payload_sizes) if payload_sizes is not None else None
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._hunting = False
        self._last_seq: int | None = None
        self._sync_byte = bytes((sync,))

    def reset_sequence(self) -> None:
        """Forget the last SEQ (after a reconnect the gap means nothing)."""
        self._last_seq = None

    def _lose_sync(self) -> None:
        self._hunting = True
        self.stats.resyncs += 1

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        buf = self._buf
        buf += data
        out: list[Frame] = []
        st = self.stats
        sizes = self.payload_sizes
        max_payload = self.max_payload
        crc = zlib.crc32
        pos = 0
        n = len(buf)
        while pos < n:
            if buf[pos] != self.sync:
                j = buf.find(self._sync_byte, pos)
                if j < 0:
                    j = n
                if not self._hunting:  # junk after a good frame; after a bad one it is the hunt
                    self._lose_sync()
                st.bytes_dropped += j - pos
                pos = j
                continue
            if n - pos < 2:
                break
            length = buf[pos + 1]
            # the length check, as soon as its bytes are in: LEN fits, and is the size of ID
            bad = length > max_payload
            if not bad and n - pos >= HEADER and sizes is not None:
                bad = sizes.get(buf[pos + 4]) != length
            if bad:
                st.bad_headers += 1
                self._lose_sync()
                st.bytes_dropped += 1
                pos += 1
                continue
            body = pos + HEADER + length
            end = body + FRAME_CRC
            if n < end:
                break
            if crc(buf[pos:body]) != int.from_bytes(buf[body:end], "little"):
                st.crc_errors += 1
                self._lose_sync()
                st.bytes_dropped += 1
                pos += 1
                continue
            self._hunting = False
            seq = buf[pos + 2] | buf[pos + 3] << 8
            msg_id = buf[pos + 4]
            payload = bytes(buf[pos + HEADER : body])
            pos = end
            last = self._last_seq
            gap = 0
            if last is not None:
                gap = (seq - last - 1) & _SEQ_MASK
                if gap == _SEQ_MASK:  # the same SEQ again: a repeated frame
                    st.duplicates += 1
                    continue
                st.lost_frames += gap
            self._last_seq = seq
            st.frames += 1
            out.append(Frame(seq, msg_id, payload, gap))
        del buf[:pos]
        return out


def bench_decode(n: int = 100_000, chunk: int = 64) -> dict[str, float]:
    """Decode cost per frame: n 10 kHz ``state`` frames (6-byte payload) fed in ``chunk``-byte
    reads (a USB full-speed packet is 64 bytes). Returns frames/s and µs/frame."""
    from tvsd.hw.mcu.spec import load_spec

    spec = load_spec()
    state = spec.by_name("state")
    stream = b"".join(
        encode_frame(i, state.id, state.codec.pack(i * 1600, (i * 7) & 0x7FFF)) for i in range(n)
    )
    dec = FrameDecoder(spec.sync, spec.max_payload, spec.payload_sizes("m2h"))
    mv = memoryview(stream)
    t0 = time.perf_counter()
    got = 0
    for i in range(0, len(stream), chunk):
        got += len(dec.feed(mv[i : i + chunk]))
    dt = time.perf_counter() - t0
    if got != n:  # the benchmark checks itself: a decoder that drops frames is not fast
        raise RuntimeError(f"bench_decode: decoded {got} of {n} frames")
    return {
        "frames": float(n),
        "frame_bytes": float(FRAME_OVERHEAD + state.size),
        "chunk_bytes": float(chunk),
        "frames_per_s": n / dt,
        "us_per_frame": dt / n * 1e6,
    }
