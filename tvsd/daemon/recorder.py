"""The daemon's recorder: everything, append-only, crash-safe; and its reader.

Producers (the 10 kHz thread's batches, the IMU reader, the scan pipeline, the event loop) call
``Channel.append(array)``, which copies the rows and hands them to a writer thread without ever
blocking: if more than ``max_pending_bytes`` wait for the disk, the batch is dropped and counted.

Format (one recording = one directory of segment files ``seg-00000.tvsrec``, ``seg-00001.tvsrec``...;
little-endian throughout)::

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

Crash safety: the writer hands its buffer to the kernel (``os.write``) every ``flush_interval_s``
(0.2 s) and fsyncs every ``fsync_interval_s`` (1 s). ``kill -9`` of the daemon loses only what had
not reached the kernel: at most ~flush_interval_s plus the queue's backlog; a power cut loses at
most the last fsync interval. The reader checks every record's CRC: a damaged record is skipped by
searching for the next sync whose record checks out, and counted (``corrupt_records``); bytes after
the last good record of the last segment are a torn tail (``torn_tail_bytes``), reported, not raised.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import struct
import threading
import time
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from tvsd.errors import DataFileError, UsageError

MAGIC = b"TVSREC\x00\x01"
SYNC = b"\xa5R"
RECORD = struct.Struct("<2sBHII")  # sync, kind, channel, length, crc32
HEADER, CONFIG, CHANNEL, DATA, MARK, STATS = range(6)
FORMAT_VERSION = 1
SEGMENT_GLOB = "seg-*.tvsrec"

# The convention `tvsctl export` relies on: the loop's decimated signals in SI units.
LOOP_CHANNEL = "loop"
LOOP_FIELDS = (("t", "<f8"), ("u", "<f8"), ("omega", "<f8"), ("phi", "<f8"))


def encode(kind: int, channel: int, payload: bytes) -> bytes:
    head = struct.pack("<2sBHI", SYNC, kind, channel, len(payload))
    return head + struct.pack("<I", zlib.crc32(payload, zlib.crc32(head))) + payload


def segment_name(index: int) -> str:
    return f"seg-{index:05d}.tvsrec"


@dataclass
class ChannelStats:
    rows: int = 0
    dropped_rows: int = 0
    dropped_batches: int = 0


class Channel:
    """One named stream of rows with a fixed numpy structured dtype. Thread-safe, never blocks."""

    def __init__(self, recorder: Recorder, cid: int, name: str, dtype: np.dtype[Any]) -> None:
        self._recorder = recorder
        self.id = cid
        self.name = name
        self.dtype = dtype
        self.stats = ChannelStats()

    def append(self, rows: np.ndarray | Mapping[str, ArrayLike]) -> bool:
        """Queue rows (a structured array with this channel's field names, or a dict of columns).
        False if they were dropped (queue full or recorder closed/failed)."""
        arr = self._coerce(rows)
        return self._recorder._submit(self, arr.tobytes(), len(arr))  # tobytes: the caller may reuse arr

    def _coerce(self, rows: np.ndarray | Mapping[str, ArrayLike]) -> np.ndarray:
        names = self.dtype.names or ()
        if isinstance(rows, Mapping):
            if set(rows) != set(names):
                raise UsageError(f"channel {self.name}: columns {sorted(rows)}, expected {list(names)}")
            cols = {k: np.atleast_1d(np.asarray(v)) for k, v in rows.items()}
            arr = np.empty(len(next(iter(cols.values()))), self.dtype)
            for k, v in cols.items():
                arr[k] = v
            return arr
        arr = np.atleast_1d(rows)
        if arr.dtype.names != names or arr.ndim != 1:
            raise UsageError(
                f"channel {self.name}: got {arr.ndim}-D rows with fields {arr.dtype.names}, "
                f"expected 1-D rows with fields {names}"
            )
        return arr if arr.dtype == self.dtype else arr.astype(self.dtype)


class Recorder:
    """Writes one recording directory; see the module doc for the format and the crash policy."""

    def __init__(
        self,
        directory: str | Path,
        config_text: str,
        *,
        flush_interval_s: float = 0.2,
        fsync_interval_s: float = 1.0,
        max_pending_bytes: int = 64 << 20,
        segment_bytes: int = 256 << 20,
    ) -> None:
        self.directory = Path(directory)
        if self.directory.is_dir() and any(self.directory.glob(SEGMENT_GLOB)):
            raise UsageError(f"{self.directory}: already holds a recording; choose a new directory")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"{self.directory}: cannot create the recording folder: {exc.strerror}") from exc
        self.flush_interval_s = flush_interval_s
        self.fsync_interval_s = fsync_interval_s
        self.max_pending_bytes = max_pending_bytes
        self.segment_bytes = segment_bytes
        self.started_unix = time.time()
        self._config = config_text.encode()
        self._channels: dict[str, Channel] = {}
        self._lock = threading.Lock()  # guards counters and _pending; held for nanoseconds
        self._pending = 0
        self._queue: queue.SimpleQueue[tuple[int, int, bytes] | None] = queue.SimpleQueue()
        self.dropped_marks = 0
        self.error: OSError | None = None  # set if the disk failed; the daemon reports it as a fault
        self._closed = False
        self._segment = -1
        self._fd = -1
        self._segment_size = 0
        try:  # the first segment synchronously: a bad directory fails here, not in the thread
            self._open_segment()
        except OSError as exc:
            raise UsageError(f"{self.directory}: cannot start a recording: {exc.strerror}") from exc
        self._thread = threading.Thread(target=self._writer, name="tvsd-recorder", daemon=True)
        self._thread.start()

    # -- producer side -------------------------------------------------------------------------
    def channel(self, name: str, fields: DTypeLike) -> Channel:
        """Declare (or get again) a channel; `fields` e.g. [("t", "<f8"), ("u", "<f4")]."""
        dtype = np.dtype(fields)
        if not dtype.names or dtype.hasobject:
            raise UsageError(f"channel {name}: fields must be named numeric fields, got {dtype}")
        with self._lock:
            ch = self._channels.get(name)
            if ch is not None:
                if ch.dtype != dtype:
                    raise UsageError(f"channel {name}: already declared with fields {ch.dtype.descr}")
                return ch
            if self._closed:
                raise UsageError(f"channel {name}: the recorder of {self.directory} is closed")
            ch = Channel(self, len(self._channels) + 1, name, dtype)
            self._channels[name] = ch
            # Declarations bypass the byte bound: losing one would make the channel's data unreadable.
            self._queue.put((CHANNEL, ch.id, _channel_payload(ch)))
        return ch

    def mark(self, event: str, **data: Any) -> bool:
        """Record an event (state change, fault, note) with the wall-clock time; never blocks."""
        payload = json.dumps({"t_unix": time.time(), "event": event, **data}, default=str).encode()
        with self._lock:
            if not self._accept(len(payload), MARK, 0, payload):
                self.dropped_marks += 1
                return False
        return True

    def stats(self) -> dict[str, ChannelStats]:
        with self._lock:
            return {n: ChannelStats(**vars(c.stats)) for n, c in self._channels.items()}

    def _submit(self, ch: Channel, payload: bytes, nrows: int) -> bool:
        with self._lock:
            if self._accept(len(payload), DATA, ch.id, payload):
                ch.stats.rows += nrows
                return True
            ch.stats.dropped_rows += nrows
            ch.stats.dropped_batches += 1
            return False

    def _accept(self, nbytes: int, kind: int, cid: int, payload: bytes) -> bool:
        # Called under _lock; SimpleQueue.put never blocks, and putting under the lock keeps every
        # accepted item ahead of close()'s end-of-queue marker.
        if self._closed or self.error is not None or self._pending + nbytes > self.max_pending_bytes:
            return False
        self._pending += nbytes
        self._queue.put((kind, cid, payload))
        return True

    # -- writer thread -------------------------------------------------------------------------
    def _writer(self) -> None:
        buf = bytearray()
        last_flush = last_sync = time.monotonic()
        last_drops: tuple[int, ...] = ()
        stop = False
        while not stop:
            timeout = max(0.0, last_flush + self.flush_interval_s - time.monotonic())
            try:
                item = self._queue.get(timeout=timeout)
                while True:  # drain what is there without waking up per batch
                    if item is None:
                        stop = True
                        break
                    kind, cid, payload = item
                    buf += encode(kind, cid, payload)
                    if kind in (DATA, MARK):
                        with self._lock:
                            self._pending -= len(payload)
                    if self._full(buf):
                        break
                    item = self._queue.get_nowait()
            except queue.Empty:
                pass
            now = time.monotonic()
            try:
                if stop or self._full(buf) or now - last_flush >= self.flush_interval_s:
                    if self.error is None:
                        drops = self._drop_counts()
                        if drops != last_drops and now - last_sync >= self.fsync_interval_s:
                            buf += encode(STATS, 0, self._stats_payload(final=False))
                            last_drops = drops
                        self._write(buf)
                    buf.clear()
                    last_flush = now
                if self.error is None and (stop or now - last_sync >= self.fsync_interval_s):
                    os.fsync(self._fd)
                    last_sync = now
            except OSError as exc:  # disk full, I/O error: stop writing, keep the daemon alive
                with self._lock:
                    self.error = exc
                buf.clear()

    def _full(self, buf: bytearray) -> bool:
        # Hand over 1 MiB at a time, and end a segment close to segment_bytes.
        return len(buf) >= 1 << 20 or self._segment_size + len(buf) >= self.segment_bytes

    def _write(self, buf: bytearray) -> None:
        view = memoryview(buf)
        while view:
            view = view[os.write(self._fd, view) :]
        self._segment_size += len(buf)
        if self._segment_size >= self.segment_bytes:
            self._open_segment()

    def _open_segment(self) -> None:
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.fsync(fd)
            os.close(fd)
        self._segment += 1
        path = self.directory / segment_name(self._segment)
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o640)
        started = datetime.fromtimestamp(self.started_unix, UTC).isoformat()
        header = {"format": FORMAT_VERSION, "segment": self._segment, "started_utc": started}
        head = bytearray(MAGIC)
        head += encode(HEADER, 0, json.dumps({**header, "started_unix": self.started_unix}).encode())
        head += encode(CONFIG, 0, self._config)
        with self._lock:
            channels = list(self._channels.values())
        for ch in channels:  # channels declared but still queued are declared again: harmless
            head += encode(CHANNEL, ch.id, _channel_payload(ch))
        os.write(self._fd, head)
        os.fsync(self._fd)
        self._segment_size = len(head)
        dirfd = os.open(self.directory, os.O_RDONLY)  # make the new file's name itself durable
        try:
            os.fsync(dirfd)
        finally:
            os.close(dirfd)

    def _drop_counts(self) -> tuple[int, ...]:
        with self._lock:
            return (self.dropped_marks, *(c.stats.dropped_rows for c in self._channels.values()))

    def _stats_payload(self, final: bool) -> bytes:
        chans = {n: vars(s) for n, s in self.stats().items()}
        return json.dumps({"final": final, "channels": chans, "dropped_marks": self.dropped_marks}).encode()

    def close(self) -> None:
        """Write what is queued, the final stats, fsync and close. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._queue.put(None)
        self._thread.join()
        if self._fd < 0:
            return
        if self.error is None:
            with contextlib.suppress(OSError):
                os.write(self._fd, encode(STATS, 0, self._stats_payload(final=True)))
                os.fsync(self._fd)
        os.close(self._fd)
        self._fd = -1

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _channel_payload(ch: Channel) -> bytes:
    return json.dumps({"id": ch.id, "name": ch.name, "fields": ch.dtype.descr}).encode()


# -- reader ------------------------------------------------------------------------------------
@dataclass
class RecordingFile:
    """What open_recording() found: channels as structured arrays, and what was damaged."""

    path: Path
    segments: list[Path]
    config_text: str
    header: dict[str, Any]
    channels: dict[str, np.ndarray]
    marks: list[dict[str, Any]]
    stats: dict[str, Any] | None  # the last STATS record; stats["final"] only after close()
    corrupt_records: int = 0  # damaged regions skipped inside the recording
    corrupt_bytes: int = 0
    torn_tail_bytes: int = 0  # partial record at the very end (the writer was killed mid-write)
    problems: list[str] = field(default_factory=list)

    @property
    def closed_cleanly(self) -> bool:
        return bool(self.stats and self.stats.get("final"))


def open_recording(path: str | Path) -> RecordingFile:
    """Read a recording directory (or one segment file). Damage is counted, never raised."""
    path = Path(path)
    if path.is_dir():
        segments = sorted(path.glob(SEGMENT_GLOB))
        if not segments:
            raise DataFileError(f"{path}: not a tvsd recording (no {SEGMENT_GLOB} segment files in it)")
    elif path.is_file():
        segments = [path]
    else:
        raise DataFileError(f"{path}: no such recording (expected a directory written by the recorder)")
    rec = RecordingFile(path, segments, "", {}, {}, [], None)
    parts: dict[str, list[np.ndarray]] = {}
    for k, seg in enumerate(segments):
        _read_segment(seg, rec, parts, last=k == len(segments) - 1)
    for name, chunks in parts.items():
        rec.channels[name] = np.concatenate(chunks) if len(chunks) > 1 else chunks[0]
    return rec


def _read_segment(seg: Path, rec: RecordingFile, parts: dict[str, list[np.ndarray]], last: bool) -> None:
    try:
        data = seg.read_bytes()
    except OSError as exc:
        raise DataFileError(f"{seg}: cannot read: {exc.strerror}") from exc
    if not data.startswith(MAGIC):
        raise DataFileError(f"{seg}: not a tvsd recording segment (does not start with {MAGIC!r})")
    dtypes: dict[int, tuple[str, np.dtype[Any]]] = {}
    pos = len(MAGIC)
    while pos < len(data):
        found = _record_at(data, pos)
        if found is None:
            nxt = _resync(data, pos + 1)
            if nxt is None and last:
                rec.torn_tail_bytes = len(data) - pos
                rec.problems.append(f"{seg.name}: torn tail of {len(data) - pos} bytes at offset {pos}")
                return
            end = len(data) if nxt is None else nxt
            rec.corrupt_records += 1
            rec.corrupt_bytes += end - pos
            rec.problems.append(f"{seg.name}: {end - pos} damaged bytes skipped at offset {pos}")
            pos = end
            continue
        kind, cid, payload, pos = found
        _apply(kind, cid, payload, rec, dtypes, parts, seg)


def _apply(
    kind: int,
    cid: int,
    payload: bytes,
    rec: RecordingFile,
    dtypes: dict[int, tuple[str, np.dtype[Any]]],
    parts: dict[str, list[np.ndarray]],
    seg: Path,
) -> None:
    if kind == HEADER:
        rec.header = rec.header or json.loads(payload)
    elif kind == CONFIG:
        rec.config_text = rec.config_text or payload.decode("utf-8", "replace")
    elif kind == CHANNEL:
        decl = json.loads(payload)
        fields = [tuple(f) if len(f) == 2 else (f[0], f[1], tuple(f[2])) for f in decl["fields"]]
        dtypes[decl["id"]] = (decl["name"], np.dtype(fields))
    elif kind == DATA:
        if cid not in dtypes:  # its declaration was in a damaged record
            rec.problems.append(f"{seg.name}: data of undeclared channel {cid} skipped")
            return
        name, dtype = dtypes[cid]
        parts.setdefault(name, []).append(np.frombuffer(payload, dtype))
    elif kind == MARK:
        rec.marks.append(json.loads(payload))
    elif kind == STATS and payload:
        rec.stats = json.loads(payload)


def _record_at(data: bytes, pos: int) -> tuple[int, int, bytes, int] | None:
    """The record starting at pos if it is whole and its CRC checks out."""
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


def _resync(data: bytes, start: int) -> int | None:
    """Offset of the next whole, CRC-valid record at or after start (a false sync fails its CRC)."""
    pos = data.find(SYNC, start)
    while pos >= 0:
        if _record_at(data, pos) is not None:
            return pos
        pos = data.find(SYNC, pos + 1)
    return None


def flatten_config(config_text: str, sections: Sequence[str]) -> dict[str, str]:
    """Scalar leaves of the YAML config's given sections as "section.key" -> value (one line each)."""
    import yaml

    try:
        doc = yaml.safe_load(config_text)
    except yaml.YAMLError:
        return {}
    out: dict[str, str] = {}

    def walk(prefix: str, node: object) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(f"{prefix}.{k}", v)
        elif isinstance(node, (int, float, str, bool)):
            out[prefix] = " ".join(str(node).split())  # metadata values are single lines

    if isinstance(doc, dict):
        for s in sections:
            walk(s, doc.get(s))
    return out
