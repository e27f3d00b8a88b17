"""The daemon's handle on the SIL devices' process (tvsd/sim/sil_process.py).

``SilDevices.spawn(params)`` starts the process — from the thread that outlives it (the event
loop's): the child's PR_SET_PDEATHSIG fires when the thread that forked it ends —, then
``wait_ready()`` (blocking: run it off the loop) waits for its MCU pty, DeviceError if the process
ends or does not answer. Then:
- ``port``: the virtual MCU's pty, opened with pyserial exactly as a serial port;
- ``imu_bus()``: a RemoteI2CBus (smbus2's calls) to the IMU twins;
- ``set_beta``, ``cable_cut``, ``imu_fault``: the scene and fault injection, one JSON line each on
  the control socket, never waited for (the event loop does not wait for the other process);
- ``history()``, ``host_to_sim()``, ``covered_host()``: the plant's history ring and pacing line
  (tests, the SA gyro's truth), each a question and its answer (blocking: not on the loop);
- ``exit_fd``: readable once the process has ended (its stdout's end), for the daemon's watch;
- ``close()``: the control socket closes (the process stops its plant and exits), a bounded wait,
  then SIGKILL. If the daemon dies first, the process dies with it.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import pickle
import select
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from tvsd.errors import DeviceError
from tvsd.hw.i2c_remote import RemoteI2CBus
from tvsd.sim.mcu_plant import PlantHistory
from tvsd.sim.sil_process import SilParams

# The child imports numpy, scipy and numba's cached kernels and builds the plant: ~3 s alone,
# tens of s on this loaded 2-core machine. Past this it is stuck, not slow.
READY_TIMEOUT_S = 90.0
STOP_TIMEOUT_S = 5.0
ASK_TIMEOUT_S = 10.0


def _own_path() -> str:
    """PYTHONPATH with the directory this tvsd package is in first."""
    import tvsd

    here = str(Path(tvsd.__file__).resolve().parent.parent)
    return os.pathsep.join([here, *filter(None, [os.environ.get("PYTHONPATH")])])


class SilDevices:
    """The SIL devices' process, seen from the daemon."""

    def __init__(self, proc: subprocess.Popen[bytes], ctl: socket.socket, bus: socket.socket) -> None:
        self.proc, self._ctl, self._bus_sock = proc, ctl, bus
        self._ctl.settimeout(ASK_TIMEOUT_S)
        self._ctl_in = ctl.makefile("rb")
        self._lock = threading.Lock()
        self.port = ""
        self._bus: RemoteI2CBus | None = None
        self._watching: asyncio.AbstractEventLoop | None = None

    @classmethod
    def spawn(
        cls, params: SilParams, *, realtime: bool = False, env: Mapping[str, str] | None = None
    ) -> SilDevices:
        """Start the process; `realtime`: SCHED_FIFO for it (tvsd --realtime): the devices stand
        in for hardware, which has its own CPU. `env`: variables added to its environment (a
        benchmark's $TVSD_SIL_STALLS)."""
        ctl_parent, ctl_child = socket.socketpair()
        bus_parent, bus_child = socket.socketpair()
        try:
            # -P and PYTHONPATH: this very tvsd, never one in the working directory (python -m
            # would put it first: a daemon started inside another checkout ran that one's code)
            argv = [sys.executable, "-P", "-m", "tvsd.sim.sil_process", "--ctl-fd", str(ctl_child.fileno())]
            argv += ["--bus-fd", str(bus_child.fileno()), *(["--realtime"] if realtime else [])]
            proc = subprocess.Popen(
                argv,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                # OpenBLAS's worker threads spin-wait: beside SCHED_FIFO threads and CPU hogs they
                # stall for 100s of ms; nothing in the devices needs a parallel BLAS
                env={
                    **os.environ,
                    "OPENBLAS_NUM_THREADS": "1",
                    "OMP_NUM_THREADS": "1",
                    **(env or {}),
                    "PYTHONPATH": _own_path(),
                },
                pass_fds=(ctl_child.fileno(), bus_child.fileno()),
            )
        except OSError as exc:
            for s in (ctl_parent, bus_parent):
                s.close()
            raise DeviceError(
                f"cannot start the SIL devices' process ({exc}): check {sys.executable}"
            ) from exc
        finally:
            ctl_child.close()
            bus_child.close()
        assert proc.stdin is not None
        with contextlib.suppress(OSError):  # it died at once: wait_ready says so
            proc.stdin.write(pickle.dumps(params))
        with contextlib.suppress(OSError):
            proc.stdin.close()
        return cls(proc, ctl_parent, bus_parent)

    @classmethod
    async def start(cls, params: SilParams, *, realtime: bool = False) -> SilDevices:
        """spawn (on this, the loop's thread) and wait_ready (off it)."""
        sil = cls.spawn(params, realtime=realtime)
        await asyncio.to_thread(sil.wait_ready)
        return sil

    def watch(self, on_exit: Callable[[str], None]) -> None:
        """Call `on_exit(why)` on the running loop's thread when the process ends (unless
        close() ended it)."""
        loop = asyncio.get_running_loop()

        def ended() -> None:
            with contextlib.suppress(OSError):
                if os.read(self.exit_fd, 4096):  # a stray line: still running
                    return
            loop.remove_reader(self.exit_fd)
            self._watching = None
            status = self.proc.poll()
            if status is None:  # its stdout closed a moment before its status is there
                with contextlib.suppress(subprocess.TimeoutExpired):
                    status = self.proc.wait(0.2)
            on_exit(f"status {status}" if status is not None else "its output closed")

        loop.add_reader(self.exit_fd, ended)
        self._watching = loop

    async def aclose(self) -> None:
        """close(), off the loop's thread (it waits for the process to end)."""
        if self._watching is not None:
            self._watching.remove_reader(self.exit_fd)
            self._watching = None
        await asyncio.to_thread(self.close)

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def exit_fd(self) -> int:
        """Readable (end of file) once the process has ended."""
        assert self.proc.stdout is not None
        return self.proc.stdout.fileno()

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Until the process reports its MCU pty; DeviceError (the process ended) if it reports
        an error, ends, or says nothing within timeout_s."""
        line = b""
        deadline = time.monotonic() + timeout_s
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            ready, _, _ = select.select([self.exit_fd], [], [], max(0.0, left))
            if not ready:
                break
            chunk = os.read(self.exit_fd, 4096)
            if not chunk:
                break
            line += chunk
        try:
            info = json.loads(line) if line.endswith(b"\n") else {}
        except ValueError:
            info = {"error": f"it said {line[:200]!r}"}
        if "port" in info:
            self.port = str(info["port"])
            return
        status = self.proc.poll()
        if status is None:  # stuck: of no use, and it must not outlive this call
            self.proc.kill()
        self.close()
        if "error" in info:
            why = str(info["error"])
        elif status is not None:
            why = f"it ended with status {status}; its error is in the log above"
        else:
            why = f"no answer within {timeout_s:g} s"
        raise DeviceError(
            f"the SIL devices' process did not start ({why}): check that `{sys.executable} -m "
            "tvsd.sim.sil_process --help` runs, and the SIL profile (sil.yaml)"
        )

    # --- devices ------------------------------------------------------------------------------------
    def imu_bus(self, timeout_s: float | None = None) -> RemoteI2CBus:
        """The twins' bus (one per process: the IMU reader thread owns it)."""
        if self._bus is None:
            self._bus = (
                RemoteI2CBus(self._bus_sock) if timeout_s is None else RemoteI2CBus(self._bus_sock, timeout_s)
            )
        return self._bus

    def _send(self, req: dict[str, Any]) -> None:
        try:
            self._ctl.sendall(json.dumps(req).encode() + b"\n")
        except OSError as exc:
            raise DeviceError(f"the SIL devices' process is gone ({exc}): restart tvsd --sil") from None

    def _tell(self, op: str, **kw: Any) -> None:
        with self._lock:
            self._send({"op": op, **kw})

    def _ask(self, op: str, **kw: Any) -> dict[str, Any]:
        with self._lock:
            self._send({"op": op, "ask": True, **kw})
            try:
                line = self._ctl_in.readline()
            except OSError as exc:
                raise DeviceError(f"the SIL devices' process did not answer ({exc})") from None
        if not line:
            raise DeviceError("the SIL devices' process is gone (its control socket closed)")
        reply: dict[str, Any] = json.loads(line)
        if "error" in reply:
            raise DeviceError(f"SIL devices: {reply['error']}")
        return reply

    def set_beta(self, beta: float) -> None:
        """Where the scene puts the optical pulse: the SA angle of the laser spot, rad."""
        self._tell("beta", value=beta)

    def cable_cut(self, cut: bool) -> None:
        """MCU fault injection: the line cut both ways (True) or mended."""
        self._tell("cable_cut", value=cut)

    def imu_fault(self, kind: str, address: int | None) -> None:
        """IMU fault injection: "loss" (the twin at `address`, or every one, stops answering the
        bus; it keeps sampling), "restore" (every injected loss ends)."""
        self._tell("imu_fault", kind=kind, address=address)

    def history(self) -> PlantHistory:
        h = self._ask("history")
        return PlantHistory(
            np.asarray(h["t"]), np.asarray(h["disturbance"]), np.asarray(h["omega"]), np.asarray(h["phi"])
        )

    def host_to_sim(self, t_host: ArrayLike) -> np.ndarray:
        """Sim times of host times (time.monotonic: one clock for both processes)."""
        p = self._ask("pacing")
        t = np.asarray(t_host, dtype=np.float64)
        return float(p["sim0"]) + (t - float(p["wall0"])) * float(p["speed"])

    def covered_host(self) -> float:
        return float(self._ask("pacing")["covered_host"])

    # --- lifetime -------------------------------------------------------------------------------------
    def close(self) -> None:
        """End the process: its control socket closes, it stops the plant and exits; SIGKILL if
        it has not within STOP_TIMEOUT_S."""
        if self._bus is not None:
            self._bus.close()
        for f in (self._ctl_in, self._ctl, self._bus_sock):
            with contextlib.suppress(OSError):
                f.close()
        try:
            self.proc.wait(STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(STOP_TIMEOUT_S)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
