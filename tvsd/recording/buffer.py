"""The recorder's write buffer: records encoded into one block of memory allocated once.

Why: the writer used to build each flush in a `bytearray` it cleared after the write, so every
0.2 s cycle grew it again from nothing through realloc: past glibc's mmap threshold each growth
is an mremap and every page a fresh minor fault (measured: 73 faults a cycle at 300 kB, 219 at
900 kB, in the recorder's thread), each taken under the process's memory-map lock while the
thread holds the GIL (the soak's stall sampler caught the recorder in mremap for 60-90 ms with
every other Python thread waiting). This block is allocated and zero-filled (every page touched)
once, when the recording starts, and a memoryview on it stays exported for its lifetime, so
CPython cannot resize it: a resize would raise BufferError instead of reallocating.
"""

from __future__ import annotations

from tvsd.recording.format import RECORD, encode_into

FLUSH_BYTES = 1 << 20  # the writer hands the kernel at most this much at a time


class RecordBuffer:
    """Encoded records waiting for one os.write, in a fixed block of `capacity` bytes."""

    def __init__(self, capacity: int = FLUSH_BYTES) -> None:
        self._block = bytearray(capacity)  # zero-filled: every page faulted in here, once
        self._view = memoryview(self._block)  # exported: the block can no longer move or grow
        self.used = 0

    @property
    def capacity(self) -> int:
        return len(self._view)

    def add(self, kind: int, channel: int, payload: bytes) -> bool:
        """Append one record; False (nothing written) if it does not fit in what is left."""
        if RECORD.size + len(payload) > self.capacity - self.used:
            return False
        self.used = encode_into(self._view, self.used, kind, channel, payload)
        return True

    def data(self) -> memoryview:
        """The records added since the last clear (a view: valid until the next add)."""
        return self._view[: self.used]

    def clear(self) -> None:
        self.used = 0
