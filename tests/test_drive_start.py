"""The daemon's drive link starts without a refusal from the firmware (issue 13, branch ttyrestore).

The MCU streams state frames from its boot; DriveLink answers each batch of them with a PWM frame.
During the handshake (identify, then the heartbeat round trip that arms the firmware's watchdog)
those answers reached a firmware not yet armed, which refuses every output until a heartbeat
(ack no_heartbeat): `MCU refused pwm_set(0,): no_heartbeat` in the daemon's log at every start
(seen by branch newuser). The firmware is right; the host now sends no PWM before the round trip.
Here against the real firmware core (the virtual MCU on a pty).
"""

from __future__ import annotations

import asyncio
import logging
import time

import numpy as np
import pytest
from conftest import until

from tvsd.config import load_config
from tvsd.control.words import TICK_DTYPE
from tvsd.daemon.drive_link import DriveLink
from tvsd.sim import virtual_mcu as vm


class _Runner:
    """A control loop that ticks (so the link's heartbeats go) and commands 0 V."""

    def __init__(self) -> None:
        self.t0 = time.monotonic()

    @property
    def ticks(self) -> int:
        return int((time.monotonic() - self.t0) * 10_000)

    command = 0.0
    omega = 0.0

    def recent_ticks(self, n: int) -> np.ndarray:
        return np.zeros(n, dtype=TICK_DTYPE)

    def measured(self, *args: object, **kwargs: object) -> None:
        pass

    def stale_after(self, *args: float) -> None:
        pass


def test_the_drive_link_starts_without_a_pwm_refusal(
    vmcu: vm.VirtualMcu, caplog: pytest.LogCaptureFixture
) -> None:
    """Start, then PWM frames answering the states for 0.3 s: no refusal reached the link, none
    was logged, and PWM frames did go (the check is not empty). Before: pwm_set refused at start."""
    cfg = load_config()

    class _Sil:  # the SIL devices' process, as much of it as the link uses: its MCU's pty
        port = vmcu.port
        pid = 0

    async def main() -> None:
        drive = DriveLink(cfg, _Runner(), "sil", on_pulse=print, on_link=print, on_fault=print)  # type: ignore[arg-type]
        await drive.start(_Sil())  # type: ignore[arg-type]
        try:
            assert drive.link is not None
            await until(lambda: drive._sent > 100, 5.0, "PWM frames answering the states")
            await asyncio.sleep(0.1)  # a refusal's ack comes back within a round trip
            assert drive.link.refusals == [], drive.link.refusals
        finally:
            await drive.close()

    with caplog.at_level(logging.WARNING, logger="tvsd.hw.mcu"):
        asyncio.run(main())
    assert not [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
