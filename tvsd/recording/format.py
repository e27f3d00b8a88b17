"""The daemon's recording format (``.tvsrec`` segments): record layout, kinds, one record in and out.

Shared by the writer (`tvsd.recording.writer`) and the reader (`tvsd.recording.reader`); it
owns the bytes on disk and nothing else.

One recording = one directory of segment files ``seg-00000.tvsrec``, ``seg-00001.tvsrec``...;
little-endian throughout::

    segment  = MAGIC (8 bytes b"TVSREC\\x00\\x01") record*
    record   = sync b"\\xa5R" | kind u8 | channel u16 | length u32 | crc32 u32 | payload[length]
    crc32    = zlib.crc32 over (sync, kind, channel, length) then the payload

    kind 0 HEADER   JSON {"format": 1, "segment": k, "started_utc": ..., "started_unix": ...}
    kind 1 CONFIG   the config the daemon runs with, as UTF-8 text
    kind 2 CHANNEL  JSON {"id": n, "name": ..., "fields": numpy dtype.descr}  (declares channel n)
    kind 3 DATA     rows of channel n: the raw bytes of a numpy structured array of its dtype
    kind 4 MARK     JSON {"t_unix": ..., "event": ..., <fields>}  (state changes, faults, notes)
    kind 5 STATS    JSON {"final": bool, "channels": {name: {"rows", "dropped_rows", "dropped_batches"}},
                    "dropped_marks": n}  written every fsync when drops changed, and at close

Every segment starts with HEADER, CONFIG and the CHANNEL records of all channels declared so far,
so each one reads on its own. A segment is closed and the next one begun past ``segment_bytes``.
"""

from __future__ import annotations

import struct
import zlib

MAGIC = b"TVSREC\x00\x01"
SYNC = b"\xa5R"
RECORD = struct.Struct("<2sBHII")  # sync, kind, channel, length, crc32
HEADER, CONFIG, CHANNEL, DATA, MARK, STATS = range(6)
FORMAT_VERSION = 1
SEGMENT_PREFIX = "seg-"
SEGMENT_GLOB = f"{SEGMENT_PREFIX}*.tvsrec"

# The convention `tvsctl export` relies on: the loop's decimated signals in SI units.
LOOP_CHANNEL = "loop"
LOOP_FIELDS = (("t", "<f8"), ("u", "<f8"), ("omega", "<f8"), ("phi", "<f8"))


_HEAD = struct.Struct("<2sBHI")  # the record's fields before its crc32
_CRC = struct.Struct("<I")


def record_head(kind: int, channel: int, payload: bytes | memoryview) -> bytes:
    """A record's RECORD.size bytes before its payload: the fields and the crc32."""
    head = _HEAD.pack(SYNC, kind, channel, len(payload))
    return head + _CRC.pack(zlib.crc32(payload, zlib.crc32(head)))


def encode(kind: int, channel: int, payload: bytes) -> bytes:
    return record_head(kind, channel, payload) + payload


def encode_into(buf: memoryview, pos: int, kind: int, channel: int, payload: bytes) -> int:
    """encode()'s bytes written into `buf` at `pos` (no new object: the recorder's fixed
    buffer); the record's end offset. `buf` must have RECORD.size + len(payload) bytes there."""
    end = pos + RECORD.size + len(payload)
    _HEAD.pack_into(buf, pos, SYNC, kind, channel, len(payload))
    crc = zlib.crc32(payload, zlib.crc32(buf[pos : pos + _HEAD.size]))
    _CRC.pack_into(buf, pos + _HEAD.size, crc)
    buf[pos + RECORD.size : end] = payload
    return end


def record_at(data: bytes, pos: int) -> tuple[int, int, bytes, int] | None:
    """The record starting at pos if it is whole and its CRC checks out: (kind, channel, payload,
    end offset)."""
    end = pos + RECORD.size
    if end > len(data):
        return None
    sync, kind, cid, length, crc = RECORD.unpack_from(data, pos)
    if sync != SYNC or kind > STATS or end + length > len(data):
        return None
    payload = data[end : end + length]
    if zlib.crc32(payload, zlib.crc32(data[pos : pos + RECORD.size - 4])) != crc:
        return None
    return kind, cid, payload, end + length


def segment_name(index: int) -> str:
    return f"{SEGMENT_PREFIX}{index:05d}.tvsrec"
