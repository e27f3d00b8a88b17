"""The daemon's recorder: the writer of a recording — everything, append-only, crash-safe.

Producers (the 10 kHz thread's batches, the IMU reader, the scan pipeline, the event loop) call
``Channel.append(array)``, which copies the rows and hands them to a writer thread without ever
blocking: if more than ``max_pending_bytes`` wait for the disk, the batch is dropped and counted.

It owns writing only. The bytes on disk are `tvsd.recording.format`; reading them back, damage
included, is `tvsd.recording.reader` (``open_recording``).

Crash safety: the writer hands its buffer (one fixed block, `tvsd.recording.buffer`) to the
kernel (``os.write``) every ``flush_interval_s`` (0.2 s) and fsyncs every ``fsync_interval_s``
(1 s). ``kill -9`` of the daemon loses only what had not reached the kernel: at most
~flush_interval_s plus the queue's backlog; a power cut loses at most the last fsync interval.
The reader then finds a torn tail at most, reported, not raised.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from tvsd.errors import UsageError
from tvsd.recording.buffer import FLUSH_BYTES, RecordBuffer
from tvsd.recording.format import (
    CHANNEL,
    CONFIG,
    DATA,
    FORMAT_VERSION,
    HEADER,
    MAGIC,
    MARK,
    SEGMENT_PREFIX,
    STATS,
    encode,
    record_head,
    segment_name,
)


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
        self._dirfd = _open_dir(self.directory)  # no-follow: a planted symlink is refused, not used
        if any(name.startswith(SEGMENT_PREFIX) for name in os.listdir(self._dirfd)):
            os.close(self._dirfd)
            raise UsageError(f"{self.directory}: already holds a recording; choose a new directory")
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
        self._buffer = RecordBuffer(FLUSH_BYTES)  # allocated once: see tvsd.recording.buffer
        try:  # the first segment synchronously: a bad directory fails here, not in the thread
            self._open_segment()
        except OSError as exc:
            os.close(self._dirfd)
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
                    self._put(kind, cid, payload)
                    if kind in (DATA, MARK):
                        with self._lock:
                            self._pending -= len(payload)
                    if self._full():
                        break
                    item = self._queue.get_nowait()
            except queue.Empty:
                pass
            now = time.monotonic()
            if stop or self._full() or now - last_flush >= self.flush_interval_s:
                if self.error is None:
                    drops = self._drop_counts()
                    if drops != last_drops and now - last_sync >= self.fsync_interval_s:
                        self._put(STATS, 0, self._stats_payload(final=False))
                        last_drops = drops
                self._flush()
                last_flush = now
            if self.error is None and (stop or now - last_sync >= self.fsync_interval_s):
                try:
                    os.fsync(self._fd)
                except OSError as exc:
                    self._failed(exc)
                last_sync = now

    def _put(self, kind: int, cid: int, payload: bytes) -> None:
        """One record into the fixed buffer; if it has no room, the buffer is written out first,
        and a record larger than the whole buffer goes to the kernel on its own (no growth)."""
        if self._buffer.add(kind, cid, payload):
            return
        self._flush()
        if not self._buffer.add(kind, cid, payload) and self.error is None:
            try:
                self._write(record_head(kind, cid, payload), payload)
            except OSError as exc:
                self._failed(exc)

    def _flush(self) -> None:
        """Hand the buffer to the kernel (after a disk error: drop it) and empty it."""
        if self.error is None and self._buffer.used:
            try:
                self._write(self._buffer.data())
            except OSError as exc:
                self._failed(exc)
        self._buffer.clear()

    def _failed(self, exc: OSError) -> None:
        # disk full, I/O error: stop writing, keep the daemon alive
        with self._lock:
            self.error = exc

    def _full(self) -> bool:
        # Hand over FLUSH_BYTES at a time, and end a segment close to segment_bytes.
        used = self._buffer.used
        return used >= FLUSH_BYTES or self._segment_size + used >= self.segment_bytes

    def _write(self, *parts: bytes | memoryview) -> None:
        """The parts to the segment, one after the other; then a new segment if this one is full
        (a record is never split across two)."""
        for part in parts:
            view = memoryview(part)
            while view:
                view = view[os.write(self._fd, view) :]
            self._segment_size += len(part)
        if self._segment_size >= self.segment_bytes:
            self._open_segment()

    def _open_segment(self) -> None:
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.fsync(fd)
            os.close(fd)
        self._segment += 1
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
        self._fd = os.open(segment_name(self._segment), flags, 0o640, dir_fd=self._dirfd)
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
        os.fsync(self._dirfd)  # make the new file's name itself durable

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
        with contextlib.suppress(OSError):
            os.close(self._dirfd)
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


def _open_dir(directory: Path) -> int:
    """The recording directory opened without following a symlink (created if missing, its
    parents too): files go in by this descriptor, so a link swapped in later is not followed."""
    try:
        directory.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(FileExistsError):
            os.mkdir(directory, 0o750)
        return os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError as exc:
        if directory.is_symlink():
            raise UsageError(
                f"{directory}: is a symbolic link; recordings are written only into real "
                "directories (remove the link, or choose another directory)"
            ) from exc
        raise UsageError(f"{directory}: cannot create the recording folder: {exc.strerror}") from exc


def new_recording_dir(parent: Path, stem: str) -> Path:
    """A new, empty directory `parent/stem` (or stem-2, stem-3 ...), made by this call: never one
    that was there before, a symlink planted under the predictable name included."""
    for k in range(1, 1000):
        path = parent / (stem if k == 1 else f"{stem}-{k}")
        try:
            os.mkdir(path, 0o750)  # fails on anything already there, a dangling symlink too
        except FileExistsError:
            continue
        return path
    raise UsageError(f"{parent}: {stem} and 998 more names are taken; clean up the data directory")


def _channel_payload(ch: Channel) -> bytes:
    return json.dumps({"id": ch.id, "name": ch.name, "fields": ch.dtype.descr}).encode()
