"""The SIL pty's host-write -> virtual-MCU-read delay under CPU hogs (tvsd.sim.mcu_wire's G).

    flock /work/wt/soak.lock .venv/bin/python scripts/pty_wire_delay.py [--seconds 20] [--hogs 0,1,2]

For each hog count: the SIL's side as `tvsd --sil --realtime` runs it (a paced McuPlant and its
virtual MCU in a child process at SCHED_FIFO 30, SIL_PRIORITY) and the daemon's side in this
process (a writer thread at SCHED_FIFO 80, the control kernel's, sending a heartbeat every
12.5 ms and a pwm_set every 1 ms through pyserial; a reader thread at FIFO 60, the link's I/O
thread's, draining the 1 kHz state frames), beside `n` normal-priority CPU hogs (the soak's,
tvsd.daemon.soak_load). The delay is each heartbeat's `host_us` stamp to the virtual MCU's pump
reading it (the WireStats histogram). One JSON line per hog count. Refused FIFO: said, and run
as it is (the figures then include this process's own starvation).

Under the soak's 50 RPC clients: `TVSD_SIL_WIRE_STATS=/tmp/wire.json tvsctl bench --only soak`
(the SIL process writes the same histogram there; docs/measurements/soak-and-load.md, the pty's kernel
worker).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import threading
import time

CHILD = """
import json, os, sys
from tvsd.config import load_config
from tvsd.sim.mcu_plant import McuPlant
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(30))
except OSError as exc:
    print("fifo refused:", exc, file=sys.stderr)
plant = McuPlant(load_config(), speed=1.0, record=False, wire_allowance_s=0.0)
plant.step()
plant.start()
print(plant.mcu.port, flush=True)
sys.stdin.readline()
print(json.dumps(plant.mcu.wire.as_dict()), flush=True)
plant.close()
"""


def _fifo(priority: int) -> None:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        print(f"pty_wire_delay: SCHED_FIFO {priority} refused ({exc.strerror})", file=sys.stderr)


def run_case(hogs: int, seconds: float) -> dict[str, object]:
    import serial

    from tvsd.daemon.soak_load import start_hogs
    from tvsd.hw.mcu.framing import encode_frame
    from tvsd.hw.mcu.spec import load_spec

    spec = load_spec()
    hb, pwm, cfg = spec.by_name("heartbeat"), spec.by_name("pwm_set"), spec.by_name("config_set")
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert child.stdin is not None and child.stdout is not None
    procs: list[subprocess.Popen[bytes]] = []
    stop = threading.Event()
    try:
        port = serial.Serial(child.stdout.readline().strip(), timeout=0.05)
        seq = 0

        def frame(msg: object, **values: int) -> bytes:
            nonlocal seq
            seq += 1
            return encode_frame(seq, msg.id, msg.pack(values))  # type: ignore[attr-defined]

        def reader() -> None:
            _fifo(60)
            with contextlib.suppress(serial.SerialException):  # the child closed the pty: the end
                while not stop.is_set():
                    port.read(max(1, port.in_waiting))

        def writer() -> None:
            _fifo(80)
            port.write(frame(cfg, watchdog_ms=1000, state_div=10, max_on_ms=0))
            next_hb = time.monotonic()
            while not stop.is_set():
                now = time.monotonic()
                if now >= next_hb:
                    port.write(frame(hb, host_us=int(now * 1e6) & 0xFFFF_FFFF))
                    next_hb += 0.0125
                port.write(frame(pwm, duty=0))
                time.sleep(0.001)

        threads = [threading.Thread(target=f, daemon=True) for f in (reader, writer)]
        for th in threads:
            th.start()
        time.sleep(1.0)  # the plant's first steps compile the model
        procs = start_hogs(hogs)
        time.sleep(seconds)
    finally:
        stop.set()
        for p in procs:
            p.kill()
            p.wait()
        with contextlib.suppress(BrokenPipeError):
            child.stdin.write("\n")
            child.stdin.flush()
        stats = json.loads(child.stdout.readline() or "{}")
        child.wait(10)
    return {"hogs": hogs, "seconds": seconds, **stats}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--hogs", default="0,1,2", help="comma-separated hog counts (default 0,1,2)")
    args = ap.parse_args()
    try:
        counts = [int(x) for x in args.hogs.split(",")]
    except ValueError:
        print(f"pty_wire_delay: --hogs {args.hogs!r}: comma-separated integers expected", file=sys.stderr)
        return 2
    for n in counts:
        print(json.dumps(run_case(n, args.seconds)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
