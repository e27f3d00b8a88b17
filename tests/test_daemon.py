"""tvsd end to end: a real daemon process on the SIL plant, driven over its real socket.

No timing is asserted (docs/architecture.md): waits are bounded generously (the first start compiles the
numba kernels, ≈ 3–10 s on a loaded 2-core machine) and only outcomes are checked.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from conftest import RELAXED_FAILSAFE, daemon_config, wait_for

from tvsd.config import load_config
from tvsd.recording.csvfile import read as read_recording

pytestmark = pytest.mark.slow  # each test starts a SIL daemon (6-12 s of start-up on this machine)

START_S = 60.0  # first start compiles the control kernel; later starts load it from the cache
POLL_S = 0.2
CONTROL_HZ = load_config().control.rate_hz  # the config `tvsd --sil` runs


def tvsctl(
    sock: Path, *argv: str, check: bool = True, timeout: float = 60.0
) -> subprocess.CompletedProcess[str]:
    """`timeout`: the subprocess's own; a command given a longer --timeout (identify's 180 s)
    needs a longer one, or the test dies first while the daemon is still within its bound."""
    proc = subprocess.run(
        [sys.executable, "-m", "tvsd.cli.main", *argv, "--socket", str(sock)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def rpc(sock: Path, method: str, **params: object) -> dict:
    """One JSON-RPC call over the socket; the reply object (result or error)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.connect(str(sock))
        s.settimeout(10)
        f = s.makefile("rwb")
        f.write(json.dumps({"jsonrpc": "2.0", "id": 1, "method": method, "params": params}).encode() + b"\n")
        f.flush()
        return json.loads(f.readline())


def status(sock: Path) -> dict:
    """`tvsctl status --json`'s object, asked from this process: a tvsctl per poll would cost
    ~80 ms of CPU (interpreter start), 0.4 of a core at 5 polls/s, taken from the SIL devices."""
    return rpc(sock, "status")["result"]


def _faulted(s: dict) -> str | None:
    """Why waiting is pointless: the daemon went to its safe state (on a loaded machine: which stall)."""
    return f"safe state: faults {s['faults']}, loop {s['loop']}" if s["state"] == "fault" else None


def wait_status(
    sock: Path, ok: Callable[[dict], object], timeout: float, what: str, *, fault_ends: bool = False
) -> dict:
    """Poll the status until `ok(status)` and return that status; `fault_ends`: a daemon gone to its
    safe state fails the wait at once, naming the faults, rather than at the timeout. Every
    0.2 s: each poll costs the SIL devices CPU."""
    return wait_for(
        lambda: status(sock), timeout, what, ok=ok, interval=POLL_S, abort=_faulted if fault_ends else None
    )


def wait_ticks(sock: Path, seconds: float) -> None:
    """Until the control thread has run `seconds` more of its ticks: time as the drive lives it,
    however late this process or the daemon gets the CPU."""
    loop = status(sock)["loop"]
    ticks = loop["ticks"] + round(seconds * CONTROL_HZ)
    wait_status(
        sock, lambda s: s["loop"]["ticks"] >= ticks, seconds * 10 + 10, f"{seconds:g} s of control ticks"
    )


def clock_sync_s(config: Path) -> float:
    """The longest wait for the MCU clock sync to become ready: one full window of its heartbeat
    round trips (mcu.clock.window × the heartbeat period, 64 s with the widened watchdog of
    RELAXED_FAILSAFE). It is ready once `min_samples` round trips lie within `rtt_margin_s` of the
    window's fastest: on a quiet machine after 8 heartbeats; beside CPU hogs the round trips
    spread (measured: fastest 1.3 ms, median 2-7 ms, p90 0.25-0.85 s) and it takes tens of them.
    Past one window the oldest round trips leave it: waiting longer would not help."""
    mcu = load_config(config).mcu
    return mcu.clock.window * mcu.heartbeat_period_s


def wait_compensated(sock: Path, config: Path) -> dict:
    """While scanning: until the points are IMU-compensated (IMU ok and the MCU clock synced);
    before that the daemon makes them from the zero pulses alone, flagged no_imu."""
    return wait_status(
        sock,
        lambda s: s["points"].get("compensated"),
        clock_sync_s(config),
        "compensated points (the IMU ok and the MCU clock sync ready)",
        fault_ends=True,
    )


def spin_to(sock: Path, rps: float, timeout: float = 30.0, tol: float = 0.5) -> None:
    tvsctl(sock, "speed", f"{rps:g}")
    wait_status(sock, lambda s: abs(s["rps"] - rps) < tol, timeout, f"{rps:g} rev/s", fault_ends=True)


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], Path, Path]]:
    """A SIL daemon with the fail-safe times widened (conftest.RELAXED_FAILSAFE): these tests are
    about what the daemon does, not about its fail-safe's timing."""
    yield from _daemon(tmp_path, daemon_config(tmp_path))


@pytest.fixture
def daemon_40ms_stale(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], Path, Path]]:
    """The scanner's own 40 ms stale-frame limit (the subject of the link-loss test); the firmware
    watchdog and the link's loss report widened, as they are not what that test measures. With
    --realtime, as the scanner runs it (the systemd unit, make run): the 40 ms promise is made for
    a daemon whose link thread and control thread are on SCHED_FIFO; at normal priority beside a
    CPU hog the link's I/O thread was kept off the CPU past 40 ms while spinning up."""
    changes = {k: v for k, v in RELAXED_FAILSAFE.items() if "link_timeout_ms" not in k}
    yield from _daemon(tmp_path, daemon_config(tmp_path, changes), realtime=True)


def _daemon(
    tmp_path: Path, config: Path, realtime: bool = False
) -> Iterator[tuple[subprocess.Popen[str], Path, Path]]:
    sock, data = tmp_path / "run" / "tvsd.sock", tmp_path / "data"
    argv = ["--sil", "--config", str(config), "--socket", str(sock), "--data-dir", str(data)]
    argv += ["--realtime"] if realtime else []
    # The daemon's log goes to a file: a pipe nobody reads would block its logging once full.
    log = tmp_path / "tvsd.log"
    with log.open("w") as log_file:
        proc = subprocess.Popen(
            [sys.executable, "-m", "tvsd.daemon.main", *argv], stdout=log_file, stderr=log_file, text=True
        )
    try:
        wait_for(
            lambda: sock.exists() or proc.poll() is not None, START_S, "the daemon's socket", interval=POLL_S
        )
        assert proc.poll() is None, log.read_text()
        # the socket answers from the start; the devices come up behind it ("starting")
        wait_status(sock, lambda s: s["state"] != "starting", START_S, "the devices to come up")
        yield proc, sock, data
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)
        print("tvsd's log (its tail):\n" + "".join(log.read_text().splitlines(keepends=True)[-40:]))


def test_status_has_the_promised_shape_and_the_socket_is_0660(daemon):
    _, sock, _ = daemon
    s = json.loads(tvsctl(sock, "status", "--json").stdout)
    assert {"state", "rps", "loop", "imu", "link", "faults"} <= s.keys()
    assert {"rate_hz", "missed_ticks", "jitter_p99_us"} <= s["loop"].keys()
    assert s["state"] == "idle" and s["faults"] == [], s
    assert oct(sock.stat().st_mode & 0o777) == "0o660"


def test_spin_scan_points_record_export_and_orderly_stop(daemon, tmp_path):
    proc, sock, data = daemon
    spin_to(sock, 20)
    tvsctl(sock, "record", "start")
    tvsctl(sock, "scan", "start")
    points = tvsctl(sock, "points", "--count", "3", "--json")
    rows = [json.loads(line) for line in points.stdout.splitlines() if line.strip()]
    assert len(rows) == 3 and all({"x", "y", "z", "sigma_x", "flags", "t_mono"} <= r.keys() for r in rows)
    # t_mono is the optical pulse on this machine's monotonic clock: it lies in the past (null
    # until the MCU clock sync is ready: points are made from the pulses before it is).
    assert all(r["t_mono"] is None or r["t_mono"] < time.monotonic() for r in rows)
    wait_status(
        sock, lambda s: s["points"]["per_s"] > 5, 15, "a point stream at the rotation rate", fault_ends=True
    )
    tvsctl(sock, "record", "stop")
    recs = list(data.iterdir())
    assert len(recs) == 1
    out = tmp_path / "rec.csv"
    exported = subprocess.run(
        [sys.executable, "-m", "tvsd.cli.main", "export", str(recs[0]), "--csv", str(out)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    if exported.returncode == 0:
        rec = read_recording(out)
        # the speed held over the recording, not one 1 kHz sample: the SIL drive's ripple beside a
        # loaded machine spans 18.1-20.7 rev/s within 0.8 s (measured, load 6); spin_to waited
        # for 20 within 0.5 on the status's 100-tick mean
        speed = float(sum(rec.omega)) / len(rec.omega) / 6.2832
        assert rec.sample_rate_hz == pytest.approx(1000, rel=0.01) and abs(speed - 20) < 1, speed
    else:
        # A stall of the shared machine longer than a 1 ms bin leaves a gap (docs/architecture.md: ms stalls
        # happen); export then refuses with its documented one-line message, exit 2.
        assert exported.returncode == 2 and "samples missing" in exported.stderr
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(20) == 0
    assert not sock.exists()
    assert "stopped" in (tmp_path / "tvsd.log").read_text()


def test_bad_requests_get_errors_and_the_daemon_stays_up(daemon):
    _, sock, _ = daemon
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.connect(str(sock))
        s.settimeout(10)
        f = s.makefile("rwb")
        for line, code in (
            (b"{not json\n", -32700),
            (b'{"jsonrpc":"2.0","id":1,"method":"frobnicate"}\n', -32601),
            (b'{"jsonrpc":"2.0","id":2,"method":"speed","params":{"rps":"fast"}}\n', -32602),
            (b'{"jsonrpc":"2.0","id":3,"method":"speed","params":{"rps":1e9}}\n', -32602),
        ):
            f.write(line)
            f.flush()
            reply = json.loads(f.readline())
            assert reply["error"]["code"] == code
    assert status(sock)["state"] == "idle"
    refused = tvsctl(sock, "scan", "start", check=False)  # not spinning: refused with the fix
    assert refused.returncode != 0 and "set a speed first" in refused.stderr


def test_gains_set_are_the_gains_the_loop_runs_and_bad_ones_are_refused(daemon):
    _, sock, _ = daemon
    before = rpc(sock, "gains_get")["result"]
    new = {"Gp": 5.5, "Gd": 0.25, "Gr": 17.0, "G0": 90.0}
    assert rpc(sock, "gains_set", **new)["result"]["gains"] == new
    assert rpc(sock, "gains_get")["result"] == new != before
    refused = rpc(sock, "gains_set", **{**new, "G0": 0.0})["error"]
    assert refused["code"] == -32602 and "G0: must be above 0" in refused["message"]
    assert rpc(sock, "gains_get")["result"] == new


def test_shutdown_over_the_api(daemon):
    proc, sock, _ = daemon
    tvsctl(sock, "shutdown")
    assert proc.wait(20) == 0 and not sock.exists()


def test_tvsctl_without_a_daemon_says_so_with_exit_3(tmp_path):
    proc = tvsctl(tmp_path / "none.sock", "status", check=False)
    assert proc.returncode == 3 and "not running" in proc.stderr and proc.stderr.count("\n") == 1


def test_kill_9_during_recording_reads_back(daemon, tmp_path):
    proc, sock, data = daemon
    tvsctl(sock, "speed", "10")
    tvsctl(sock, "record", "start")
    wait_ticks(sock, 3.0)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    from tvsd.recording.format import LOOP_CHANNEL
    from tvsd.recording.reader import open_recording

    rec = open_recording(next(data.iterdir()))
    loop = rec.channels[LOOP_CHANNEL]
    # 3 s recorded at 1 kHz; the recorder loses at most its 0.2 s flush interval and the daemon's
    # 0.1 s drain period: at least 2 s of samples must be there.
    assert len(loop) >= 2000


def test_mcu_link_loss_holds_pwm_0_within_50_ms_of_the_last_frame(daemon_40ms_stale):
    _, sock, _ = daemon_40ms_stale
    # Before the loss is injected, a stall of this shared machine past 40 ms can latch the same
    # safe state (issue 13); that is not the loss under test: clear it and spin up again (3 tries).
    for attempt in range(3):
        try:
            spin_to(sock, 15)
            break
        except AssertionError:
            if status(sock)["state"] != "fault" or attempt == 2:
                raise
            tvsctl(sock, "faults", "--clear")
    assert "result" in rpc(sock, "inject_fault", device="mcu", fault="link_loss")
    wait_status(sock, lambda s: s["state"] == "fault", 10, "the safe state")
    s = status(sock)
    stale = [f for f in s["faults"] if f["cause"].startswith("MCU state frames stopped")]
    assert len(stale) == 1 and "safe state" in stale[0]["action"]
    # The control thread checks every 0.1 ms tick against the 40 ms limit: the bound is
    # 50 ms after the last frame, which leaves 10 ms for a late wake-up of the control thread.
    assert 40.0 <= stale[0]["safe_after_ms"] <= 50.0
    wait_status(sock, lambda s: any("link lost" in f["cause"] for f in s["faults"]), 5, "the link's report")
    assert status(sock)["link"]["state"] == "lost"
    # Refused while in the safe state; back to work after the cable is mended and faults cleared.
    assert "safe state" in tvsctl(sock, "speed", "10", check=False).stderr
    rpc(sock, "inject_fault", device="mcu", fault="link_restore")
    wait_status(sock, lambda s: s["link"]["state"] == "ok", 10, "the link back")
    tvsctl(sock, "faults", "--clear")
    spin_to(sock, 10)


def test_overrun_streak_puts_the_drive_in_its_safe_state(daemon):
    _, sock, _ = daemon
    tvsctl(sock, "speed", "5")
    assert "result" in rpc(sock, "inject_fault", device="control", fault="overrun")
    wait_status(sock, lambda s: s["state"] == "fault", 10, "the safe state")
    faults = status(sock)["faults"]
    assert any("overran" in f["cause"] for f in faults), faults


def test_fault_injection_names_what_it_accepts(daemon):
    _, sock, _ = daemon
    reply = rpc(sock, "inject_fault", device="mcu", fault="meteor")
    assert reply["error"]["code"] == -32602 and "link_loss" in reply["error"]["message"]
    reply = rpc(sock, "inject_fault", device="toaster", fault="loss")
    assert reply["error"]["code"] == -32602 and "use mcu, imu or control" in reply["error"]["message"]


def test_imu_loss_flags_points_and_scanning_goes_on(daemon, tmp_path):
    _, sock, _ = daemon
    spin_to(sock, 20)
    tvsctl(sock, "scan", "start")
    wait_compensated(sock, tmp_path / "tvsd.yaml")
    before = wait_status(sock, lambda s: s["points"]["total"] >= 10, 20, "points", fault_ends=True)["points"]
    assert "result" in rpc(sock, "inject_fault", device="imu", fault="loss")
    wait_status(sock, lambda s: s["imu"]["state"] in ("lost", "degraded"), 10, "the IMU loss")
    n = before["no_imu"] + 10
    wait_status(sock, lambda s: s["points"]["no_imu"] >= n, 20, "flagged points", fault_ends=True)
    s = status(sock)
    assert s["state"] == "scanning" and any(f["cause"].startswith("IMU") for f in s["faults"])
    assert s["points"]["compensated"] is False and s["points"]["uncompensated_why"].startswith("IMU")
    # calibration needs the aperture at rest: refused while it turns, with the fix
    refused = rpc(sock, "imu_calibrate", seconds=1.0)
    assert refused["error"]["code"] == -32002 and "speed 0" in refused["error"]["message"]
