"""tvsd.hw.heap.tune asks glibc only for what it grants, and says what it got.

A fake C library stands in for glibc here (mallopt's settings are the whole process's: the real
one must not be tuned inside the test run); tests/test_imu_heap.py runs the real one in a child.
"""

from __future__ import annotations

import pytest

from tvsd.hw import heap


class FakeLibc:
    """mallopt as glibc's: M_MMAP_THRESHOLD refused above `limit` (returns 0, sets nothing)."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.set: list[tuple[int, int]] = []

    def mallopt(self, param: int, value: int) -> int:
        if param == heap.M_MMAP_THRESHOLD and value > self.limit:
            return 0
        self.set.append((param, value))
        return 1


def test_the_largest_mmap_threshold_is_glibcs_for_the_word_size() -> None:
    """glibc malloc.c: DEFAULT_MMAP_THRESHOLD_MAX is 512 KiB where __WORDSIZE is 32 (armhf, a
    32-bit Raspberry Pi OS), 4 MiB·sizeof(long) on 64-bit. Before: 4 MiB·4 = 16 MiB on 32-bit,
    which mallopt refuses there."""
    assert heap.mmap_threshold_max(4) == 512 * 1024
    assert heap.mmap_threshold_max(8) == 32 * 1024 * 1024


def test_a_refused_threshold_sets_nothing_and_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    """A glibc that refuses the mmap threshold (a 32-bit one asked for 16 MiB, before) gets no
    trim threshold or top pad either (before: both set, the reply a bare "parameter(s) -3"), and
    the reader takes no reserve."""
    fake = FakeLibc(limit=512 * 1024)
    monkeypatch.setattr(heap, "_libc", lambda: fake)
    monkeypatch.setattr(heap, "_tuned", False)
    monkeypatch.setattr(heap, "MMAP_THRESHOLD_MAX", 16 * 1024 * 1024)
    monkeypatch.delenv(heap.ENV_MALLOC, raising=False)
    said = heap.tune()
    assert fake.set == []
    assert "M_MMAP_THRESHOLD" in said and "nothing set before it" in said, said
    assert heap.reserve(1 << 20) is False


def test_granted_thresholds_are_all_set(monkeypatch: pytest.MonkeyPatch) -> None:
    fake = FakeLibc(limit=heap.MMAP_THRESHOLD_MAX)
    monkeypatch.setattr(heap, "_libc", lambda: fake)
    monkeypatch.setattr(heap, "_tuned", False)  # restored after: tune() sets it
    monkeypatch.delenv(heap.ENV_MALLOC, raising=False)
    assert heap.tune().startswith("heaps kept")
    assert [p for p, _ in fake.set] == [heap.M_MMAP_THRESHOLD, heap.M_TRIM_THRESHOLD, heap.M_TOP_PAD]
