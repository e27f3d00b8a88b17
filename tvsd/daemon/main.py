"""`tvsd`: the scanner daemon's entry point.

    tvsd [--config FILE] [--socket PATH] [--data-dir DIR] [--sil] [--demo] [--status-lines]
    tvsd --check [--config FILE]

Each device runs on the backend the config's `devices:` section names (hardware or sil);
`--sil` makes every device simulated (the drive model behind a virtual MCU on a pty, MPU6050
twins behind the smbus2 calls). `--demo` spins to 25 rev/s and scans, as `make run` shows;
`--status-lines` prints one status line per second (foreground use). SIGTERM and SIGINT stop it
in order (tvsd.daemon.app).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import stat
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from tvsd import __version__
from tvsd.daemon.state import DaemonState
from tvsd.errors import EXIT_OK, EXIT_USAGE, TvsdError

if TYPE_CHECKING:
    from tvsd.config import Config
    from tvsd.daemon.app import Daemon

DEFAULT_SOCKET = Path("/run/tvsd/tvsd.sock")
DEFAULT_DATA = Path("/var/lib/tvsd")
DEMO_RPS = 25.0


def parse(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="tvsd", description="TVS scanner daemon")
    p.add_argument("--version", action="version", version=f"tvsd {__version__}")
    p.add_argument("--config", type=Path, help="scanner config (default: config/tvsd.yaml)")
    p.add_argument(
        "--check", action="store_true", help="validate the config, print the gain conditions, exit"
    )
    p.add_argument(
        "--socket", type=Path, default=DEFAULT_SOCKET, help=f"API socket (default {DEFAULT_SOCKET})"
    )
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA, help=f"recordings (default {DEFAULT_DATA})")
    p.add_argument("--sil", action="store_true", help="run on the simulated plant and devices")
    p.add_argument("--demo", action="store_true", help=f"spin to {DEMO_RPS:g} rev/s and scan after start")
    p.add_argument("--status-lines", action="store_true", help="print a status line every second")
    p.add_argument("--realtime", action="store_true", help="ask for SCHED_FIFO, affinity, mlockall")
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse(argv)
    from tvsd.config import config_dir, load_config
    from tvsd.control.conditions import check_gains

    try:
        cfg = load_config(args.config) if args.config else load_config()
    except TvsdError as exc:
        print(f"tvsd: {exc}", file=sys.stderr)
        return EXIT_USAGE
    for c in check_gains(cfg.control.gains, cfg.plant, cfg.control.disturbance_bound_rad_s2):
        if args.check or not c.holds:
            print(
                f"gain condition {c.name} {'holds' if c.holds else 'DOES NOT hold'}: {c.text}",
                file=sys.stderr,
            )
    if args.check:
        print(f"config ok: plant '{cfg.plant.name}', loop {cfg.control.rate_hz:g} Hz")
        return EXIT_OK
    if args.sil:
        from dataclasses import replace

        # the twins' calibration lives with the SIL data: a board's file must not apply to them
        from tvsd.hw.imu_calibration import SIL_FILE_NAME

        imu = replace(cfg.imu, calibration_file=args.data_dir / SIL_FILE_NAME)
        cfg = replace(cfg, devices=replace(cfg.devices, mcu="sil", imu="sil"), imu=imu)
    config_path = args.config or config_dir() / "tvsd.yaml"
    folders = ((args.data_dir, "--data-dir"), (args.socket.parent, "--socket"))
    # Every folder is judged before any is made: a start refused on the socket's folder must not
    # leave an empty data dir behind (found by branch newuser).
    problems = [p for p in (_dir_problem(folder, option) for folder, option in folders) if p]
    if problems:
        for problem in problems:
            print(f"tvsd: {problem}", file=sys.stderr)
        return EXIT_USAGE
    made: list[Path] = []
    for folder, option in folders:
        failed = _make_dir(folder, option, made)
        if failed is not None:  # a race with another process, a full disk: undo what we made
            for folder_made in reversed(made):
                folder_made.rmdir()
            print(f"tvsd: {failed}", file=sys.stderr)
            return EXIT_USAGE
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        return asyncio.run(_serve(args, cfg, config_path.read_text(encoding="utf-8")))
    except TvsdError as exc:
        print(f"tvsd: {exc}", file=sys.stderr)
        return exc.exit_status


def _dir_problem(folder: Path, option: str) -> str | None:
    """Why `folder` cannot serve (None if it can): it, or its parent when it is to be made, must
    be a directory this user may write; one level is made at most (never a whole missing path: a
    typo must not grow a tree); a symlink to a directory is allowed, anything else in the way not."""
    try:
        st = folder.lstat()
    except FileNotFoundError:
        if not folder.parent.is_dir():
            return (
                f"{option} {folder}: directory {folder.parent} does not exist; create it first "
                "(systemd's RuntimeDirectory=/StateDirectory= do) or give another path"
            )
        if not os.access(folder.parent, os.W_OK | os.X_OK):
            return f"{option}: cannot create {folder}: Permission denied; give a writable place"
        return None
    except OSError as exc:
        return f"{option} {folder}: {exc.strerror}"
    if stat.S_ISLNK(st.st_mode) and folder.is_dir():
        pass  # a symlinked directory the admin set up (e.g. /var/lib/tvsd → /data): allowed
    elif not stat.S_ISDIR(st.st_mode):
        return f"{option} {folder} exists and is not a directory: remove it or give another path"
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"{option} {folder}: not writable by this user; give a writable place"
    return None


def _make_dir(folder: Path, option: str, made: list[Path]) -> str | None:
    """Create `folder` if it is missing (said on stderr, appended to `made`); the problem or None."""
    if folder.is_dir():
        return None
    try:
        folder.mkdir(mode=0o750)
    except OSError as exc:
        return f"{option}: cannot create {folder}: {exc.strerror}; give a writable place"
    made.append(folder)
    print(f"tvsd: created {folder} ({option})", file=sys.stderr)
    return None


# What an unprivileged user lacks for --realtime, and the two ways to grant it.
RT_NEEDS = (
    "needs root, or CAP_SYS_NICE and CAP_IPC_LOCK (systemd: AmbientCapabilities=), or the limits "
    "rtprio ≥ 80 and memlock unlimited for this user (/etc/security/limits.d/, `ulimit -r -l`); "
    "tvsd runs on without them, and under load the control loop misses ticks"
)
IO_PRIORITY = 40  # SCHED_FIFO of the event loop and the threads it starts; the control thread: 80
# The GIL's hand-over interval. The MCU link's I/O thread (the heartbeat, the state frames) waits
# up to this for the GIL whenever another thread runs Python; the default 5 ms is a tenth of the
# firmware's 50 ms watchdog, 1 ms a fiftieth (`tvsctl bench --only mcu_io`: README).
SWITCH_INTERVAL_S = 0.001


def _io_side_realtime() -> None:
    """--realtime: the event loop (the API, recordings, points) and the threads started after it
    (IMU reader, recorder, SIL devices: new threads inherit the policy) on SCHED_FIFO below the
    control thread, so that normal-priority load (a browser, a compile, CPU hogs) cannot hold
    them off the CPU while they hold the GIL. The MCU link's I/O thread (heartbeats, state
    frames) asks for its own priority, above this one (tvsd.daemon.drive_link). The kernel's RT
    throttling (sched_rt_runtime_us) still leaves normal tasks 5 % of each CPU."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(IO_PRIORITY))
        print(f"tvsd: event loop, I/O threads SCHED_FIFO granted (priority {IO_PRIORITY})", file=sys.stderr)
    except OSError as exc:
        print(
            f"tvsd: event loop SCHED_FIFO refused: {exc.strerror or exc} ({RT_NEEDS})",
            file=sys.stderr,
        )


async def _serve(args: argparse.Namespace, cfg: Config, config_text: str) -> int:
    from tvsd.control.realtime import not_realtime_warning
    from tvsd.daemon.app import Daemon
    from tvsd.hw import heap

    if args.realtime:
        _io_side_realtime()
        # the threads' heaps kept once grown: no memory-map calls under the GIL (tvsd.hw.heap)
        print(f"tvsd: malloc: {heap.tune()}", file=sys.stderr)
    else:
        print(not_realtime_warning("without --realtime"), file=sys.stderr)
    daemon = Daemon(
        cfg,
        args.socket,
        args.data_dir,
        realtime=args.realtime,
        out=(lambda line: print(line, flush=True)) if args.status_lines else None,
        config_text=config_text,
    )
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, daemon.request_stop)
    demo = loop.create_task(_demo(daemon)) if args.demo else None
    await daemon.run()
    if demo is not None:
        demo.cancel()
    print("tvsd: stopped (motor ramped down, recorder closed, socket removed)", file=sys.stderr)
    return EXIT_OK


async def _demo(daemon: Daemon) -> None:
    while daemon.state == DaemonState.STARTING:
        await asyncio.sleep(0.1)
    await daemon.api.api_speed(DEMO_RPS)
    while abs(daemon.measured_rps - DEMO_RPS) > 0.5:
        await asyncio.sleep(0.2)
    await daemon.api.api_scan_start()


if __name__ == "__main__":
    sys.exit(main())
