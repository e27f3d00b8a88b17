"""McuLink's queries: a request sent, its answer awaited on the event loop (identify, ping, stats).

Each query registers its future with the receiver *before* it sends (the answer comes on the I/O
thread and may beat the send's return); the receiver resolves it on the loop's thread. A query
that gets no answer in time is a DeviceError naming the port and what to check.
"""

from __future__ import annotations

import asyncio

from tvsd.errors import DeviceError, ProtocolError
from tvsd.hw.mcu.events import check_identity
from tvsd.hw.mcu.io_thread import LinkIo
from tvsd.hw.mcu.messages import Identify, McuStats
from tvsd.hw.mcu.receiving import Receiver
from tvsd.hw.mcu.sending import Sender, host_us
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import ProtocolSpec

OUTPUT_RETRY_S = 0.001  # a ping whose heartbeat the full output refused is tried again this often


class Queries:
    """The event loop's requests to one MCU, over that link's receiver, sender and I/O thread."""

    def __init__(
        self, settings: McuSettings, spec: ProtocolSpec, rx: Receiver, tx: Sender, io: LinkIo
    ) -> None:
        self.settings, self.spec = settings, spec
        self._rx, self._tx, self._io = rx, tx, io

    async def identify(self, loop: asyncio.AbstractEventLoop, attempts: int) -> Identify:
        """Ask the MCU who it is; refuse a protocol version or command table other than ours."""
        s = self.settings
        ident: Identify | None = None
        for _ in range(attempts):  # the first request may land while the MCU is resyncing
            fut: asyncio.Future[Identify] = loop.create_future()
            self._rx.identify_waiters.append(fut)
            self._tx.send("identify_req")
            try:
                ident = await asyncio.wait_for(fut, s.identify_timeout_s / attempts)
                break
            except TimeoutError:
                continue
        if ident is None:
            raise DeviceError(
                f"no answer from the MCU on {s.port} within {s.identify_timeout_s} s: is the "
                f"firmware flashed, the board powered and the baud rate ({s.baud}) the firmware's?"
            )
        check_identity(ident, self.spec, s.port)
        if ident.clock_hz == 0:
            raise ProtocolError("MCU reports a clock of 0 Hz: its identify frame is wrong")
        return ident

    async def ping(self, loop: asyncio.AbstractEventLoop, timeout_s: float) -> float:
        """One heartbeat round trip; returns the RTT in seconds."""
        port = self.settings.port
        fut: asyncio.Future[float] = loop.create_future()
        deadline = loop.time() + timeout_s
        stamp = host_us()
        self._rx.hb_waiters[stamp] = fut  # before the send: the answer comes on another thread
        try:
            while not self._tx.heartbeat(stamp):  # output full: let it drain
                if self._io.fd is None or loop.time() > deadline:
                    raise DeviceError(
                        f"cannot send to the MCU on {port}: the link is closed or "
                        f"its output stayed full for {timeout_s} s"
                    )
                await asyncio.sleep(OUTPUT_RETRY_S)
                self._io.flush()
            return await asyncio.wait_for(fut, max(0.0, deadline - loop.time()))
        except TimeoutError:
            raise DeviceError(f"the MCU on {port} did not answer a heartbeat within {timeout_s} s") from None
        finally:
            self._rx.hb_waiters.pop(stamp, None)

    async def stats(self, loop: asyncio.AbstractEventLoop, timeout_s: float) -> McuStats:
        fut: asyncio.Future[McuStats] = loop.create_future()
        self._rx.stats_waiters.append(fut)
        self._tx.send("stats_req")
        try:
            return await asyncio.wait_for(fut, timeout_s)
        except TimeoutError:
            raise DeviceError(
                f"the MCU on {self.settings.port} did not answer stats_req within {timeout_s} s"
            ) from None
