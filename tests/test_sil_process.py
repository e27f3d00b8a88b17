"""The SIL devices in their own process (issue 13 item 2): the bus across the boundary fails as a
real bus does, the driver's FIFO read costs one round trip, the process never outlives the daemon,
and its death is a clear fault, not a hang."""

from __future__ import annotations

import errno
import os
import signal
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import daemon_config, wait_for
from test_daemon import _daemon, rpc, status, wait_status

from tvsd.config import load_config
from tvsd.errors import DeviceError
from tvsd.hw import i2c_remote as wire
from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.i2c_remote import RemoteI2CBus
from tvsd.hw.imu_clock import ManualClock
from tvsd.hw.imu_settings import ImuSettings
from tvsd.hw.mpu6050 import Mpu6050
from tvsd.sim.i2c_bus import SimI2CBus
from tvsd.sim.mpu6050 import SimMpu6050, decode_counter
from tvsd.sim.sil_devices import SilDevices
from tvsd.sim.sil_process import SilParams


@pytest.fixture
def twin_over_socket() -> Iterator[tuple[RemoteI2CBus, SimI2CBus, ManualClock]]:
    """A counter twin on a manual clock, served (tvsd.hw.i2c_remote.serve) on a thread at one end
    of a socket pair; the remote bus at the other."""
    clock = ManualClock()
    sim = SimI2CBus(clock, {0x68: SimMpu6050(None, clock, signal="counter")})
    near, far = socket.socketpair()
    server = threading.Thread(target=wire.serve, args=(far, wire.BusHandler(sim)), daemon=True)
    server.start()
    bus = RemoteI2CBus(near)
    yield bus, sim, clock
    bus.close()
    server.join(5)
    far.close()


def test_the_driver_runs_its_code_path_across_the_socket(twin_over_socket) -> None:
    """Bring-up, configuration read-back and a FIFO read: every smbus2 call the driver makes,
    answered by the twin behind the socket. The FIFO read of 40 frames (20 block reads of 24
    bytes on the wire, the twin's transaction count) is one round trip: one i2c_rdwr."""
    bus, sim, clock = twin_over_socket
    drv = Mpu6050(bus, "pl", ImuSettings(), clock.sleep)
    assert drv.start() == "MPU-6050/6000"
    clock.sleep(0.04)
    frames = drv.fifo_count() // reg.FRAME_BYTES
    assert frames >= 40
    requests, transactions = bus.requests, sim.transactions
    got: list[np.ndarray] = []
    drv.read_frames(frames, got)
    assert bus.requests - requests == 1 + (frames - 1) // (2 * reg.RDWR_PAIRS)
    assert sim.transactions - transactions == -(-frames // reg.FRAMES_PER_READ)  # the same wire traffic
    n, ok = decode_counter(np.concatenate(got))
    assert ok.all() and len(n) == frames and np.all(np.diff(n) == 1)


def test_a_nack_across_the_socket_is_the_kernels_errno(twin_over_socket) -> None:
    bus, _, clock = twin_over_socket
    with pytest.raises(OSError) as exc:
        bus.read_byte_data(0x69, reg.WHO_AM_I)  # no twin at 0x69
    assert exc.value.errno == errno.ENXIO
    with pytest.raises(DeviceError, match="no ACK") as derr:
        Mpu6050(bus, "sa", ImuSettings(), clock.sleep).probe()
    assert derr.value.errno == errno.ENXIO


def test_a_bus_that_does_not_answer_times_out_as_etimedout() -> None:
    """The far end reads the request and says nothing: ETIMEDOUT after the bus's timeout, as a
    kernel adapter reports a transfer that never completed (the driver's hint names it); its
    late reply, when it comes, is not taken for the next request's."""
    near, far = socket.socketpair()
    bus = RemoteI2CBus(near, timeout_s=0.05)
    try:
        t0 = time.monotonic()
        with pytest.raises(OSError) as exc:
            bus.read_byte_data(0x68, reg.WHO_AM_I)
        assert exc.value.errno == errno.ETIMEDOUT and time.monotonic() - t0 >= 0.05
        with pytest.raises(DeviceError, match="timed out") as derr:
            Mpu6050(bus, "pl", ImuSettings(), time.sleep).probe()
        assert derr.value.errno == errno.ETIMEDOUT
        # the far end wakes up: answers both stale requests late, then the next one
        for _ in range(2):
            seq, _op, n = wire.REQUEST.unpack(wire.recv_exact(far, wire.REQUEST.size))
            wire.recv_exact(far, n)
            far.sendall(wire.REPLY.pack(seq, 0, 1) + b"\x00")
        answer = threading.Thread(target=_answer_once, args=(far, 0x68))
        answer.start()
        assert bus.read_byte_data(0x68, reg.WHO_AM_I) == 0x68
        answer.join(5)
    finally:
        bus.close()
        far.close()


def _answer_once(sock: socket.socket, value: int) -> None:
    seq, _op, n = wire.REQUEST.unpack(wire.recv_exact(sock, wire.REQUEST.size))
    wire.recv_exact(sock, n)
    sock.sendall(wire.REPLY.pack(seq, 0, 1) + bytes([value]))


def test_a_bus_whose_process_is_gone_fails_with_eio() -> None:
    near, far = socket.socketpair()
    far.close()
    bus = RemoteI2CBus(near)
    with pytest.raises(OSError) as exc:
        bus.write_byte_data(0x68, reg.PWR_MGMT_1, 0)
    assert exc.value.errno == errno.EIO and "gone" in str(exc.value)
    bus.close()


def test_a_process_that_cannot_start_its_devices_says_so_in_one_line() -> None:
    """Parameters the devices cannot run on: DeviceError naming the error, the process ended."""
    sil = SilDevices.spawn(SilParams(None, 0.0))  # type: ignore[arg-type]
    with pytest.raises(DeviceError) as exc:
        sil.wait_ready()
    msg = str(exc.value)
    assert "did not start" in msg and "AttributeError" in msg and "\n" not in msg
    assert sil.proc.returncode is not None


def test_a_process_that_does_not_answer_in_time_is_ended() -> None:
    sil = SilDevices.spawn(SilParams(load_config(), 0.0))
    with pytest.raises(DeviceError, match=r"no answer within 0\.01 s"):
        sil.wait_ready(timeout_s=0.01)
    assert sil.proc.returncode is not None  # killed, not left behind


def _gone(pid: int) -> bool:
    """No such process, or a zombie (dead, waiting for whoever inherited it to reap it)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] == "Z"


@pytest.fixture
def sil_daemon(tmp_path: Path):
    yield from _daemon(tmp_path, daemon_config(tmp_path))


@pytest.mark.slow
def test_the_devices_process_dies_with_a_killed_daemon(sil_daemon) -> None:
    """SIGKILL the daemon (nothing of it runs after): PR_SET_PDEATHSIG ends the devices' process.
    Bound 10 s: the kernel sends the signal as the daemon exits; the rest is the kill's delivery
    and this poll on a loaded machine."""
    proc, sock, _ = sil_daemon
    pid = status(sock)["link"]["sil_pid"]
    assert pid != proc.pid and not _gone(pid)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    wait_for(lambda: _gone(pid), 10.0, "the SIL devices' process to end with the daemon")


@pytest.mark.slow
def test_a_crashed_devices_process_is_a_link_fault_and_an_imu_fault(sil_daemon) -> None:
    """SIGKILL the devices' process: the daemon goes to its safe state with a fault naming it,
    its link reports the loss, the IMU (its bus now fails with EIO) goes lost or degraded, and
    the daemon keeps answering and stops in order."""
    proc, sock, _ = sil_daemon
    pid = status(sock)["link"]["sil_pid"]
    os.kill(pid, signal.SIGKILL)
    s = wait_status(sock, lambda s: s["state"] == "fault", 10, "the safe state")
    causes = [f["cause"] for f in s["faults"]]
    assert any("SIL devices' process ended (status -9)" in c for c in causes), causes
    s = wait_status(
        sock,
        lambda s: s["link"]["state"] == "lost" and s["imu"]["state"] in ("lost", "degraded"),
        10,
        "losses",
    )
    assert any(f["cause"].startswith("IMU") for f in s["faults"]), s["faults"]
    assert "result" in rpc(sock, "shutdown")
    assert proc.wait(30) == 0


@pytest.mark.slow
def test_the_process_runs_this_tvsd_whatever_the_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A daemon started inside another checkout: `python -m` would import that tvsd first (it
    did: /work/main's, without this module). The twins alone (devices.mcu hardware, imu sil) at
    rest, read across the boundary."""
    (tmp_path / "tvsd").mkdir()
    (tmp_path / "tvsd" / "__init__.py").write_text("raise ImportError('the wrong tvsd')\n")
    monkeypatch.chdir(tmp_path)
    sil = SilDevices.spawn(SilParams(load_config(), 0.0, plant=False))
    try:
        sil.wait_ready()
        assert sil.port == ""  # no MCU without the drive model
        assert sil.imu_bus().read_byte_data(0x68, reg.WHO_AM_I) == 0x68
    finally:
        sil.close()
    assert sil.proc.returncode == 0  # ended by its control socket's end, not killed
