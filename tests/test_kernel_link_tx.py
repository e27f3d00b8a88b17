"""The control kernel's own MCU frames (tvsd.control.link_tx) and the port it shares with the link's
I/O thread (tvsd.hw.mcu.shared_tx): the frames are the protocol's, and frames of the two writers
never interleave on a real pty, even when the line is full and writes come back short.
"""

from __future__ import annotations

import os
import threading
import time
import tty
import zlib
from collections.abc import Iterator

import numpy as np
import pytest
from conftest import wait_for

from tvsd.control.runner import Runner
from tvsd.hw.mcu.events import LinkStats
from tvsd.hw.mcu.framing import FrameDecoder, encode_frame
from tvsd.hw.mcu.io_thread import LinkIo
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.shared_tx import KERNEL_SEQ, SharedTx, crc32, put_frame
from tvsd.hw.mcu.spec import load_spec

SPEC = load_spec()
IDS = {m.name: m.id for m in SPEC.messages}


def test_the_kernels_frame_encoder_is_the_protocols() -> None:
    """put_frame (nopython) against framing.encode_frame (Python, zlib's CRC) byte for byte."""
    buf = np.zeros(32, dtype=np.uint8)
    data = np.frombuffer(b"123456789", dtype=np.uint8).copy()
    assert crc32(data, 0, 9) == 0xCBF43926 == zlib.crc32(b"123456789")
    for seq, host_us in ((KERNEL_SEQ, 0), (KERNEL_SEQ + 1, 0xDEADBEEF), (0x1234, 0xFFFF_FFFF)):
        n = put_frame(buf, 3, SPEC.sync, seq, IDS["heartbeat"], host_us, 4)
        want = encode_frame(seq, IDS["heartbeat"], host_us.to_bytes(4, "little"), SPEC.sync)
        assert bytes(buf[3 : 3 + n]) == want
    n = put_frame(buf, 0, SPEC.sync, KERNEL_SEQ, IDS["pwm_set"], 0, 2)
    assert bytes(buf[:n]) == encode_frame(KERNEL_SEQ, IDS["pwm_set"], b"\0\0", SPEC.sync)


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, int]]:
    """A raw pty (no output processing: 0x0A stays 0x0A), the writers' end non-blocking."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(slave, False)
    try:
        yield master, slave
    finally:
        os.close(slave)
        os.close(master)


def test_kernel_and_io_thread_frames_never_interleave(setup: object, pty_pair: tuple[int, int]) -> None:
    """The kernel writes a heartbeat every tick (0.1 ms) while a Python thread sends bursts of
    pwm_set frames through the link's real I/O path (LinkIo.send → SharedTx.write), and the far
    end of the pty reads in pauses, so the pty's buffer fills and writes come back short or
    refused (EAGAIN). Every byte that arrives must decode: no CRC error, no bad header, no junk,
    and every frame either side counted as written arrives. A tty write is atomic against other
    writers (the kernel's n_tty holds atomic_write_lock for the whole write()); a short write is
    not, and shared_tx's torn-frame word keeps the other writer out until its rest is written:
    without it the stream tears (this test fails with TX_TORN ignored)."""
    master, slave = pty_pair
    runner = Runner(setup, sil=False)  # type: ignore[arg-type]
    settings = McuSettings(port="pty")
    decoder_io = FrameDecoder(SPEC.sync, SPEC.max_payload, SPEC.payload_sizes("h2m"))
    stats = LinkStats()
    io = LinkIo(
        settings,
        SPEC.sync,
        FrameDecoder(SPEC.sync, SPEC.max_payload, SPEC.payload_sizes("m2h")),
        stats,
        on_frames=lambda f, t: None,
        on_link=lambda up: None,
        on_gone=lambda why: None,
        heartbeat=lambda: True,
        shared=runner.tx,
    )
    got: list[bytes] = []
    reading = threading.Event()
    done = threading.Event()

    def reader() -> None:  # reads in bursts with pauses: the pty buffer runs full in between
        os.set_blocking(master, False)
        while not done.is_set() or reading.is_set():
            try:
                chunk = os.read(master, 65536)
                got.append(chunk)
            except BlockingIOError:
                if done.is_set():
                    return
                time.sleep(0.02)
                continue
            if not done.is_set():
                time.sleep(0.2)  # ~30 KB arrive meanwhile: the pty's buffer fills

    runner.start()
    io.start(slave)
    th = threading.Thread(target=reader)
    try:
        wait_for(lambda: runner.is_running, 60.0, "the control kernel running")
        runner.attach_link(1e-4, SPEC.sync, IDS["heartbeat"], IDS["pwm_set"])
        th.start()
        sent = 0
        t_end = time.monotonic() + 1.5
        while time.monotonic() < t_end:
            for k in range(50):
                sent += io.send(IDS["pwm_set"], (k * 97).to_bytes(2, "little"))
            time.sleep(0.001)
        runner.detach_link()
        wait_for(lambda: not io._tx_pending, 5.0, "the I/O thread's pending frames written")
        time.sleep(0.05)
    finally:
        done.set()
        th.join(5.0) if th.is_alive() else None
        io.stop()
        runner.stop(timeout=2.0)
    # what is still in the pty after the reader stopped
    os.set_blocking(master, False)
    while True:
        try:
            got.append(os.read(master, 65536))
        except (BlockingIOError, OSError):
            break
    frames = decoder_io.feed(b"".join(got))
    hb = runner.heartbeat_stats()
    kinds = {IDS["heartbeat"]: 0, IDS["pwm_set"]: 0}
    for f in frames:
        kinds[f.msg_id] += 1
    st = decoder_io.stats
    counters = runner.tx.counters()
    print(
        f"{sent} I/O frames, {hb.sent} kernel heartbeats sent; {st.frames} decoded; kernel busy "
        f"{hb.busy}, I/O busy {counters['io_busy']}, refused (full) {stats.tx_dropped}"
    )
    assert (st.crc_errors, st.bad_headers, st.bytes_dropped, st.resyncs) == (0, 0, 0, 0), st
    assert kinds[IDS["pwm_set"]] == sent and kinds[IDS["heartbeat"]] == hb.sent, (kinds, sent, hb)
    assert hb.sent > 100 and sent > 100
    assert stats.tx_dropped > 0 or hb.busy > 0, "the line never filled: the test proved nothing"


def test_a_closed_port_is_never_written(pty_pair: tuple[int, int]) -> None:
    """After SharedTx.close the kernel's writes fail (counted) instead of going to whatever file
    reuses the fd number."""
    _, slave = pty_pair
    tx = SharedTx()
    tx.open(slave)
    tx.close()
    buf = np.zeros(4, dtype=np.uint8)
    assert tx.write(buf, 0, 4) == -9  # EBADF, nothing written
    assert not tx.is_open
