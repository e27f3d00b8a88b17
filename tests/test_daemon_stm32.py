"""The SIL daemon with the STM32F405's protocol settings: mcu.board: stm32f405, so the control loop
exchanges state + PWM with the virtual MCU (the same C core, built for the host) at 10 kHz.

As in test_daemon.py no timing is asserted, only outcomes: the status says 10 kHz and which board,
the MCU sends a state frame per control tick (≥ 90 % of them reach the daemon: a loaded host may
lose some at the pty, the loop counts them), and the drive spins up on them.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import wait_for
from test_daemon import POLL_S, START_S, spin_to, status, wait_status

from tvsd.config import config_dir

pytestmark = pytest.mark.slow


@pytest.fixture
def stm32_daemon(tmp_path: Path) -> Iterator[Path]:
    for f in config_dir().glob("*.yaml"):
        (tmp_path / f.name).write_text(f.read_text())
    cfg = tmp_path / "tvsd.yaml"
    text = cfg.read_text()
    assert "  board: atmega328p" in text
    cfg.write_text(text.replace("  board: atmega328p", "  board: stm32f405", 1))
    sock, log = tmp_path / "run" / "tvsd.sock", tmp_path / "tvsd.log"
    argv = ["--sil", "--config", str(cfg), "--socket", str(sock), "--data-dir", str(tmp_path / "data")]
    with log.open("w") as log_file:
        proc = subprocess.Popen(
            [sys.executable, "-m", "tvsd.daemon.main", *argv], stdout=log_file, stderr=log_file
        )
    try:
        wait_for(
            lambda: sock.exists() or proc.poll() is not None, START_S, "the daemon's socket", interval=POLL_S
        )
        assert proc.poll() is None, log.read_text()
        wait_status(sock, lambda s: s["state"] != "starting", START_S, "the devices to come up")
        yield sock
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)
        print("tvsd's log (its tail):\n" + "".join(log.read_text().splitlines(keepends=True)[-40:]))


def test_sil_daemon_exchanges_at_10_khz_with_the_stm32_settings(stm32_daemon: Path) -> None:
    sock = stm32_daemon
    s = status(sock)
    assert s["state"] == "idle", s
    assert (s["link"]["board"], s["link"]["exchange_hz"]) == ("stm32f405", 10000.0), s["link"]
    spin_to(sock, 10.0)
    a = status(sock)
    wait_status(sock, lambda s: s["loop"]["ticks"] >= a["loop"]["ticks"] + 10_000, 60, "1 s of control ticks")
    b = status(sock)
    frames = b["link"]["frames_rx"] - a["link"]["frames_rx"]
    ticks = b["loop"]["ticks"] - a["loop"]["ticks"]
    assert frames >= 0.9 * ticks, f"{frames} frames from the MCU in {ticks} control ticks"
    assert abs(b["rps"] - 10.0) < 0.5, b
    # the safety path's figures (issue 13): the kernel writes the heartbeats, and the status
    # carries the firmware's own counters from its stats (a watchdog expiry among them)
    link = wait_status(sock, lambda s: s["link"]["firmware"] is not None, 10, "the firmware's stats")["link"]
    assert link["kernel_heartbeats"] > 0 and link["kernel_tx_errors"] == 0, link
    assert set(link["firmware"]) == {"rx_overflows", "ticks_dropped", "watchdog_expiries", "age_s"}
    assert link["firmware"]["watchdog_expiries"] == 0, link
