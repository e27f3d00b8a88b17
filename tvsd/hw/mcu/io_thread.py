"""The MCU link's own thread: the serial port's bytes both ways, the heartbeat, the loss check.

Why a thread and not the event loop: the heartbeat arms the firmware's watchdog and the state
frames feed the control thread (a PWM frame answers each batch). On the event loop they waited
for whatever else the loop did: under 2 CPU hogs, 50 RPC clients and a 500-call batch every 3 s
the SIL daemon saw 53 firmware watchdog cuts and 14 link losses in 60 s. Here only this thread
runs them: it sleeps in ``epoll`` on the port (GIL released), wakes for bytes, for the next
heartbeat or for the loss deadline, and hands the decoded frames to the receiver on this thread.

Why epoll, edge-triggered, and not select/poll: a poll of a tty that finds no input waits for the
kernel's tty flip-buffer work (``n_tty_poll`` -> ``tty_buffer_flush_work``), a normal-priority
kworker, uninterruptibly. Under CPU load that work, preempted while the MCU's frames keep coming,
did not finish for 100-215 ms, and this SCHED_FIFO thread sat in ``select`` (state D) as long:
no heartbeat, no state, no stop (docs/measurements/wdflake.md). An edge-triggered epoll entry is
polled only after the line discipline's wake-up, when input is there: a timer wake never waits for
that worker, and bytes are read as each part is handed over, not when the whole work ends.
Other Python code delays it only by holding the GIL (it is handed over every
``sys.getswitchinterval()``; the daemon sets 1 ms) or, under ``--realtime``, not at all by CPU
load: the thread runs SCHED_FIFO between the control thread and the event loop.

Writing: every frame goes through one lock-protected, non-blocking write with a bounded
pending buffer, so any thread may send without blocking and frames never interleave; when the
line cannot keep up, whole new frames are refused and counted, never half-written; this thread
flushes the rest when the port is writable. The write is ``shared_tx.SharedTx.write``: the
control kernel writes heartbeats to the same fd (``kernel_heartbeats``), and that mutex and
torn-frame word keep the two writers' frames whole.

The heartbeat goes every ``settings.heartbeat_period_s`` while ``liveness()`` (the control
kernel's tick count, in the daemon) has moved since the last one: a live control loop means a
live heartbeat, a dead one means the firmware cuts within its watchdog. In the daemon the
control kernel sends them itself (tvsd.control.link_tx: no GIL needed) and this thread's
schedule is off (``kernel_heartbeats(True)``).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import os
import select
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from tvsd.hw.mcu.events import LinkStats
from tvsd.hw.mcu.framing import Frame, FrameDecoder, encode_frame
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.shared_tx import BUSY, IO_SEQ_MODULUS, KERNEL_SEQ, SharedTx
from tvsd.hw.mcu.tty_probe import TtyProbe

log = logging.getLogger("tvsd.hw.mcu.link")  # the link's log, whichever part writes it

READ_CHUNK = 65536
# SCHED_FIFO priority the daemon asks for this thread under --realtime: below the control thread
# (80), above the event loop (40)
IO_THREAD_PRIORITY = 60
IDLE_WAKE_S = 0.05  # the longest wait: a stop request or a changed schedule is never later
TX_RETRY_S = 0.001  # pending bytes the line would not take: tried again this often (no EPOLLOUT:
# its poll would wait for the flip-buffer work as select did)


def request_fifo(priority: int) -> str:
    """SCHED_FIFO for the calling thread (Linux: pid 0 is this thread), or why not, in words."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f"granted (priority {priority})"
    except OSError as exc:
        return f"refused: {exc.strerror or exc} (needs root, CAP_SYS_NICE or an rtprio limit)"


class LinkIo:
    """One serial port served by one thread. On that thread: ``on_frames(frames, now)`` for every
    read that decoded frames, ``on_link(up)`` when frames start or stop (none for
    ``settings.link_lost_s``), ``on_gone(why)`` once when the port fails (the thread then ends),
    ``heartbeat()`` (sends one; False if refused) when one is due."""

    def __init__(
        self,
        settings: McuSettings,
        sync: int,
        decoder: FrameDecoder,
        stats: LinkStats,
        *,
        on_frames: Callable[[list[Frame], float], None],
        on_link: Callable[[bool], None],
        on_gone: Callable[[str], None],
        heartbeat: Callable[[], bool],
        liveness: Callable[[], int] | None = None,
        priority: int | None = None,
        shared: SharedTx | None = None,
    ) -> None:
        self.settings, self.sync, self.decoder, self.stats = settings, sync, decoder, stats
        self.on_frames, self.on_link, self.on_gone, self.heartbeat = on_frames, on_link, on_gone, heartbeat
        self.liveness, self.priority = liveness, priority
        self.realtime = "not requested"
        self.tx_error: OSError | None = None
        # what went out under each SEQ (an ack names a frame by its SEQ only); written under the lock
        self.sent: list[Any] = [None] * 0x1_0000
        self.sent[KERNEL_SEQ] = self.sent[KERNEL_SEQ + 1] = ("heartbeat", ())  # the kernel's
        self._fd: int | None = None
        self.shared = shared or SharedTx()  # the fd's write side, shared with the control kernel
        self._tx_lock = threading.Lock()
        self._tx_buf = np.zeros(settings.tx_buffer_bytes, dtype=np.uint8)  # pending bytes: [0, _tx_len)
        self._tx_len = 0
        self._kernel_hb = False
        self._tx_seq = 0
        self._last_rx = -math.inf
        self._heartbeats_on = False
        self._next_hb = 0.0
        self._last_hb = math.nan
        self._live_count: int | None = None
        self._wake_r, self._wake_w = -1, -1
        self._ep: select.epoll | None = None  # this thread's, while it runs
        self._probe = TtyProbe(self._wake)  # the loss check's look at the tty, off this thread
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # --- life cycle (the owner's thread) --------------------------------------------------------
    def start(self, fd: int) -> None:
        self._fd = fd
        self.shared.open(fd)
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_w, False)
        self._stop.clear()
        self._probe.start(fd)
        self._thread = threading.Thread(target=self._run, name="tvsd-mcu-io", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread (joined), then forget the port; the caller closes it."""
        self._stop.set()
        self._probe.stop()
        self._wake()
        th, self._thread = self._thread, None
        if th is not None and th is not threading.current_thread():
            th.join(timeout=2.0)
        self._forget_fd()
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._wake_r = self._wake_w = -1

    def _forget_fd(self) -> None:
        with self._tx_lock:
            self._fd = None
            self.shared.close()  # the kernel writes no more to it either

    def kernel_heartbeats(self, on: bool) -> None:
        """The control kernel sends the heartbeats (this thread's schedule pauses), or no more."""
        self._kernel_hb = on
        self._wake()

    def heartbeats(self, on: bool) -> None:
        """Start (the first one now) or stop the heartbeat schedule."""
        self._next_hb = time.monotonic()
        self._heartbeats_on = on
        self._wake()

    @property
    def fd(self) -> int | None:
        return self._fd

    def _wake(self) -> None:
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")

    # --- sending (any thread) -------------------------------------------------------------------
    def send(self, msg_id: int, payload: bytes, tag: object = None) -> bool:
        """Queue one whole frame and write what the port takes now; False (counted) if it does not
        fit. ``tag`` is kept under the SEQ the frame goes out with (``sent``)."""
        with self._tx_lock:
            if self._fd is None:
                return False
            frame = encode_frame(self._tx_seq, msg_id, payload, self.sync)
            n = len(frame)
            if self._tx_len + n > len(self._tx_buf):
                self.stats.tx_dropped += 1
                self._flush_locked()
                return False
            # SEQ only advances for frames that go out: a gap at the MCU is a loss on the wire.
            # It skips the kernel's two (shared_tx.KERNEL_SEQ).
            self.sent[self._tx_seq] = tag
            self._tx_seq = (self._tx_seq + 1) % IO_SEQ_MODULUS
            self._tx_buf[self._tx_len : self._tx_len + n] = np.frombuffer(frame, dtype=np.uint8)
            self._tx_len += n
            self.stats.frames_tx += 1
            self._flush_locked()
            return True

    def _flush_locked(self) -> None:
        shared = self.shared
        while self._tx_len and self._fd is not None:
            n = shared.write(self._tx_buf, 0, self._tx_len)
            if n == BUSY or n == -errno.EAGAIN:  # the kernel's frame is half out, or the line full
                return
            if n < 0:  # the device went away; the reader reports it
                self.tx_error = OSError(-n, os.strerror(-n))
                self._tx_len = 0
                return
            rest = self._tx_len - n
            self._tx_buf[:rest] = self._tx_buf[n : self._tx_len].copy()
            self._tx_len = rest

    @property
    def _tx_pending(self) -> bool:
        return self._tx_len > 0

    def flush(self) -> None:
        with self._tx_lock:
            self._flush_locked()

    # --- the thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        if self.priority is not None:
            self.realtime = request_fifo(self.priority)
        fd = self._fd
        if fd is None:
            return
        try:
            with select.epoll() as ep:
                ep.register(fd, select.EPOLLIN | select.EPOLLET)  # see the module's docstring
                ep.register(self._wake_r, select.EPOLLIN)
                self._ep = ep
                self._loop(ep, fd)
        except Exception:  # a bug here must say so, not silently stop the heartbeat
            log.exception("MCU link I/O thread failed")
            self.on_gone("the link's I/O thread failed (a bug: see the log)")
        finally:
            self._ep = None

    def _loop(self, ep: select.epoll, fd: int) -> None:
        while not self._stop.is_set():
            if self._fd is None:
                return
            now = time.monotonic()
            timeout = IDLE_WAKE_S
            if self._heartbeats_on and not self._kernel_hb:
                timeout = min(timeout, self._next_hb - now)
            if self.stats.link_up and not self._probe.busy:  # busy: it wakes us
                timeout = min(timeout, self._last_rx + self.settings.link_lost_s - now)
            if self._tx_pending:  # 0.1 ms when the kernel ends its torn frame next tick
                timeout = min(timeout, 1e-4 if self.shared.torn_by_kernel else TX_RETRY_S)
            try:
                events = ep.poll(max(0.0, timeout))
            except (OSError, ValueError):  # closed under us: stopping
                return
            ready = {f for f, _ in events}
            if self._wake_r in ready:
                with contextlib.suppress(OSError):
                    os.read(self._wake_r, 64)
            if self._stop.is_set():
                return
            if fd in ready and not self._read(fd):
                return
            if self._tx_pending:
                self.flush()
            now = time.monotonic()
            if self._heartbeats_on and not self._kernel_hb and now >= self._next_hb:
                self._heartbeat(now)
            if self.stats.link_up and now >= self._last_rx + self.settings.link_lost_s:
                self._check_link()

    def _heartbeat(self, now: float) -> None:
        st = self.stats
        st.heartbeat_late_max_s = max(st.heartbeat_late_max_s, now - self._next_hb)
        period = self.settings.heartbeat_period_s
        # on schedule, not from now (a late wake does not shift the ones after it), but no burst
        # after a long stall either
        self._next_hb = max(self._next_hb + period, now + 0.25 * period)
        if self.liveness is not None:
            count = self.liveness()
            if count == self._live_count:  # the control loop has not ticked since the last one
                st.heartbeats_withheld += 1
                return
            self._live_count = count
        if self.heartbeat():
            if math.isfinite(self._last_hb):
                st.heartbeat_gap_max_s = max(st.heartbeat_gap_max_s, now - self._last_hb)
            st.heartbeats += 1
            self._last_hb = st.last_heartbeat_s = now

    def _read(self, fd: int) -> bool:
        """Read and hand over what is waiting; False once the port is gone."""
        data = b""
        try:
            while True:  # edge-triggered: take all there is (a full chunk: more may wait)
                chunk = os.read(fd, READ_CHUNK)
                data += chunk
                if len(chunk) < READ_CHUNK:
                    break
        except BlockingIOError:
            if not data:
                return True
        except OSError as exc:
            self._gone(f"read failed: {exc.strerror}")
            return False
        if not data:  # epoll said readable: end of file
            self._gone("end of file")
            return False
        now = time.monotonic()
        if not self.stats.link_up:
            self.decoder.reset_sequence()  # a SEQ gap across an outage means nothing
        frames = self.decoder.feed(data)
        if frames:
            self._last_rx = now
            if not self.stats.link_up:
                self._set_link(True)
            self.on_frames(frames, now)
        if self._tx_pending:
            self.flush()
        return True

    def _gone(self, why: str) -> None:
        self.tx_error = self.tx_error or OSError(why)
        self._forget_fd()
        self.on_gone(why)
        if self.stats.link_up:
            self._set_link(False)

    def _set_link(self, up: bool) -> None:
        self.stats.link_up = up
        if not up:
            self.stats.link_losses += 1
            self.stats.last_loss_s = time.monotonic()
        self.on_link(up)

    def _check_link(self) -> None:
        """No frame for link_lost_s: read what is waiting first (this thread may itself have been
        kept from running: the frames then prove the link alive), and only then call it lost."""
        fd = self._fd
        if fd is None or not self.stats.link_up:
            return
        if self._heartbeats_on and not self._kernel_hb:
            # this thread owns the heartbeat: the look that waits for the flip-buffer work is the
            # probe's (tvsd.hw.mcu.tty_probe); while it waits, the tty holds bytes for us: alive
            if self._probe.busy:
                return
            answer = self._probe.answer(since=self._last_rx)
            if answer is None:
                self._probe.ask()
                return
            ready = answer
        else:  # select on purpose: it waits for that work, whose frames, if any, prove the link
            ready = bool(select.select([fd], [], [], 0)[0])  # alive (the kernel sends heartbeats)
        if ready and not self._read(fd):
            return
        if self.stats.link_up and time.monotonic() >= self._last_rx + self.settings.link_lost_s:
            self._set_link(False)  # the next frame brings it back
