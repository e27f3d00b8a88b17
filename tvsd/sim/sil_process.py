"""The SIL devices' own process: the drive model behind the virtual MCU, and the IMU twins.

Started by tvsd.sim.sil_devices.SilDevices (the daemon with --sil, tests) as
``python -m tvsd.sim.sil_process --ctl-fd N --bus-fd M [--realtime]``; its parameters
(SilParams) come pickled on stdin, and one JSON line on stdout says where the MCU is (its pty) once
the devices run, or what stopped them ({"error": ...}). Then:
- the McuPlant (tvsd/sim/mcu_plant.py) runs paced at real time with its virtual MCU on the pty
  (this process holds the master), which the daemon opens with pyserial as a real port;
- the two MPU6050 twins, moved by the running plant (PlantMotion on PlantClock; at rest without a
  plant), answer the bus requests on the bus socket (tvsd/hw/i2c_remote.py), on their own thread;
- the control socket takes JSON lines on the main thread (`_control`): commands (beta,
  cable_cut, imu_fault) get no answer, questions ("ask": true: history, pacing) one line each.
It shares no GIL with the daemon, and it dies with it: PR_SET_PDEATHSIG (SIGKILL) when the
daemon's thread that started it ends, and the end of the control socket (the daemon closed it or
died). If the plant's thread fails, the process ends: stdout's end tells the daemon.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import math
import os
import pickle
import select
import signal
import socket
import sys
import threading
from dataclasses import dataclass
from typing import Any

from tvsd.config import Config
from tvsd.hw import i2c_remote as wire
from tvsd.sim.bus_timing import TimedBus
from tvsd.sim.sil_watch import StallWatch

PR_SET_PDEATHSIG = 1
SIL_PRIORITY = (
    30  # SCHED_FIFO with --realtime: below all of the daemon's threads (control 80, loop and I/O 40)
)
# The bus thread under --realtime: above the daemon's event loop (40), below its IMU reader (50),
# whose requests it answers (the reader waits for each reply: the twins stand in for a bus that
# does not queue behind the daemon's loop on the CPU). Light: it sleeps for the bus's bit time.
BUS_PRIORITY = 45
# The GIL's hand-over interval here, as in the daemon (tvsd.daemon.main): the plant's thread
# holds it for whole chunks of Python; at the default 5 ms, each bus request that found it
# held waited up to that long.
SWITCH_INTERVAL_S = 0.001
WATCH_S = 0.2  # how often the main thread looks at the plant's thread between control lines


@dataclass(frozen=True)
class SilParams:
    """What the daemon hands the process: its config, the scene's β (the SA angle of the laser
    spot, rad), whether the drive model runs (devices.mcu: sil), the twins' rest limit (below
    it they are still: tvsd.daemon.imu_service.STILL_RPS), the plant's history length."""

    cfg: Config
    beta: float
    plant: bool = True
    still_below_rps: float = 0.0
    history_s: float = 10.0  # the plant's history ring (tests that read it over a long wait: more)


def die_with_parent() -> None:
    """SIGKILL this process when the thread that started it ends (Linux); if the parent is
    already gone, end now. The control socket's end stops it too."""
    parent = os.getppid()
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent or parent == 1:
        os._exit(1)


class Devices:
    """The plant (or None), the twins' bus and the faults injected into it."""

    def __init__(self, p: SilParams) -> None:
        from tvsd.hw.imu_clock import Clock, MonotonicClock
        from tvsd.hw.imu_settings import SA_AXES
        from tvsd.sim.imu_motion import PlantClock, SyntheticParams, plant_pair, synthetic_pair
        from tvsd.sim.mcu_plant import McuPlant
        from tvsd.sim.mcu_wire import allowance_from_env, export_stats
        from tvsd.sim.mpu6050 import sil_pair

        cfg = p.cfg
        self.plant: McuPlant | None = None
        clock: Clock = MonotonicClock()
        self._stats_stop = threading.Event()
        if p.plant:
            plant = McuPlant(
                cfg, speed=1.0, record=False, history_s=p.history_s, wire_allowance_s=allowance_from_env()
            )
            self.plant = plant
            export_stats(plant.mcu.wire, self._stats_stop)
            plant.beta = p.beta
            for index in (0, 1):
                plant.mcu.set_limit(index, 0)  # the home switches, at step 0
            plant.step()  # loads the plant kernel before the pacing starts
            plant.start()
            motions: Any = plant_pair(
                plant, axis=SA_AXES[cfg.imu.sa_axis], still_below_rps=p.still_below_rps
            )
            clock = PlantClock(plant)
        else:  # at rest: gravity, the twins' noise and biases
            motions = synthetic_pair(SyntheticParams(rps=0.0, imbalance_rad_s2=0.0, vibration_std_rad_s2=0.0))
        self.bus, self.twins = sil_pair(cfg.imu, clock, motions, bus_hz=400e3, seed=cfg.sil_or_default.seed)
        self._injected: list[Any] = []

    @property
    def port(self) -> str:
        return self.plant.mcu.port if self.plant is not None else ""

    def failed(self) -> BaseException | None:
        """The plant thread's error once it has stopped on one."""
        plant = self.plant
        if plant is None or plant._thread is None or plant._thread.is_alive():
            return None
        return plant._error or RuntimeError("the plant's thread ended")

    def imu_fault(self, kind: str, address: int | None) -> None:
        from tvsd.sim.i2c_bus import Fault

        bus = self.bus
        if kind == "loss":
            fault = Fault("disconnect", bus.clock.now(), math.inf, address)  # on the twins' clock
            self._injected.append(fault)
            bus.faults = [*bus.faults, fault]  # a new list: the bus thread iterates the old one
        elif kind == "restore":
            bus.faults = [f for f in bus.faults if f not in self._injected]
            self._injected.clear()
        else:
            raise ValueError(f"IMU fault {kind!r}: loss or restore")

    def close(self) -> None:
        self._stats_stop.set()
        if self.plant is not None:
            self.plant.close()


def _control(dev: Devices, req: dict[str, Any]) -> dict[str, Any] | None:
    """One control line: None for a command, the answer to a question."""
    op, plant = req.get("op"), dev.plant
    if op == "imu_fault":
        dev.imu_fault(str(req["kind"]), req.get("address"))
        return None
    if plant is None:
        raise ValueError(f"{op!r} needs the drive model (devices.mcu: sil)")
    if op == "beta":
        plant.beta = float(req["value"])
    elif op == "cable_cut":
        plant.mcu.cable_cut = bool(req["value"])
    elif op == "history":
        h = plant.history(float(req.get("since", -math.inf)))
        return {"t": h.t.tolist(), "disturbance": h.disturbance.tolist(), "omega": h.omega.tolist(),
                "phi": h.phi.tolist(), "chunk_s": plant.chunk_s}  # fmt: skip
    elif op == "pacing":
        p = plant.pacing
        return {"wall0": p.wall0, "sim0": p.sim0, "speed": plant.speed, "covered_host": plant.covered_host()}
    else:
        raise ValueError(f"unknown op {op!r}")
    return None


def _serve_control(ctl: socket.socket, dev: Devices) -> str:
    """JSON lines until the daemon closes the socket (or dies), or the plant fails; the reason."""
    f = ctl.makefile("rwb")
    while True:
        ready, _, _ = select.select([ctl], [], [], WATCH_S)
        failed = dev.failed()
        if failed is not None:
            return f"the drive model's thread failed: {type(failed).__name__}: {failed}"
        if not ready:
            continue
        line = f.readline()
        if not line:
            return ""
        req: Any = None
        try:
            req = json.loads(line)
            reply = _control(dev, req)
        except Exception as exc:  # a bad request is answered (or logged), never the end of the devices
            reply = {"error": f"{type(exc).__name__}: {exc}"}
        if not (isinstance(req, dict) and req.get("ask")):  # a command: the daemon waits for nothing
            if reply is not None and "error" in reply:
                print(
                    f"tvsd-sil: {line.decode(errors='replace').strip()}: {reply['error']}",
                    file=sys.stderr,
                    flush=True,
                )
            continue
        with contextlib.suppress(OSError):
            f.write(json.dumps(reply if reply is not None else {}).encode() + b"\n")
            f.flush()


def _serve_bus(sock: socket.socket, handler: wire.Handler, realtime: bool) -> None:
    if realtime:
        with contextlib.suppress(OSError):  # refused: it keeps the process's priority
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(BUS_PRIORITY))  # this thread
    wire.serve(sock, handler)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="tvsd-sil", description="the SIL devices of a tvsd --sil daemon")
    p.add_argument("--ctl-fd", type=int, required=True)
    p.add_argument("--bus-fd", type=int, required=True)
    p.add_argument("--realtime", action="store_true", help=f"SCHED_FIFO {SIL_PRIORITY} for the process")
    args = p.parse_args(argv)
    die_with_parent()
    # A Ctrl-C at the terminal, `systemctl stop` (SIGTERM to the whole cgroup) and `timeout` (to the
    # process group) reach this process too: the daemon's to handle. It ramps the motor down and
    # closes the devices in order; this process ends with it (the control socket's end, or
    # PR_SET_PDEATHSIG). Ending here first made the daemon's orderly stop raise link and IMU faults.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    if args.realtime:
        # The devices stand in for hardware, which has its own CPU: a CPU hog must not slow the
        # simulated world. Below the daemon's threads: at 60 (above its loop) the soak's daemon
        # was starved (2 of 3 runs never reached scanning in 6 min). Set before any thread
        # starts (the plant's and the bus's inherit it).
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(SIL_PRIORITY))
        except OSError as exc:
            print(
                f"tvsd-sil: SCHED_FIFO refused ({exc.strerror}): the SIL devices share the CPU",
                file=sys.stderr,
            )
    ctl = socket.socket(fileno=args.ctl_fd)
    bus_sock = socket.socket(fileno=args.bus_fd)
    try:
        params: SilParams = pickle.loads(sys.stdin.buffer.read())
        dev = Devices(params)
    except Exception as exc:
        print(json.dumps({"error": f"{type(exc).__name__}: {exc}"}), flush=True)
        return 1
    bus = TimedBus(wire.BusHandler(dev.bus))
    watch = StallWatch(dev.plant, extra=lambda: {"bus": bus.report()})
    watch.start(args.realtime)
    try:
        threading.Thread(
            target=_serve_bus, args=(bus_sock, bus, args.realtime), name="sil-i2c", daemon=True
        ).start()
        print(json.dumps({"port": dev.port, "pid": os.getpid()}), flush=True)
        why = _serve_control(ctl, dev)
    finally:
        watch.stop()
        dev.close()
    if why:
        print(f"tvsd-sil: {why}", file=sys.stderr, flush=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
