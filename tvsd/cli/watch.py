"""`tvsctl watch`: the daemon's state at a glance in the terminal, refreshing until q or Ctrl-C.

A plain-terminal view (rich Live, no mouse, no alternate screen: it works over SSH and leaves the
last frame in the scroll-back): state and faults, rev/s against the reference with the last 60 s
as a sparkline, the control loop's lateness beside this machine's own floor (a bare absolute-
deadline sleep loop measured here once, in the background, as `tvsctl latency` does), the IMU,
the link and the point rate. `--once` / `--frames N` print frames and exit (scripts, tests); when
stdout is not a terminal every frame is printed one after the other.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import select
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from tvsd.cli.human import local_time
from tvsd.errors import EXIT_OK, DaemonUnavailable, TvsdError, UsageError
from tvsd.rpc.client import DEFAULT_SOCKET, ENV_SOCKET, RpcClient, socket_path

HISTORY_S = 60.0
SPARK = "▁▂▃▄▅▆▇█"
STATE_STYLE = {"scanning": "bold green", "spinning": "green", "idle": "cyan", "fault": "bold red",
               "starting": "yellow", "stopping": "yellow"}  # fmt: skip


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "watch",
        help="the daemon's state at a glance, refreshing (q or Ctrl-C quits)",
        description="A live view of the running daemon in the terminal: state, faults, speed against "
        "its reference, loop lateness beside the machine's floor, IMU, link, points. q or Ctrl-C quits.",
    )
    p.add_argument("--socket", type=Path, metavar="PATH", help=f"daemon socket (default: ${ENV_SOCKET}, "
                   f"else {DEFAULT_SOCKET})")  # fmt: skip
    p.add_argument("--period", type=float, default=0.5, metavar="S", help="refresh period (default 0.5 s)")
    p.add_argument("--once", action="store_true", help="print one frame and exit")
    p.add_argument("--frames", type=int, metavar="N", help="print N frames and exit")
    p.add_argument(
        "--floor-seconds",
        type=float,
        default=2.0,
        metavar="S",
        help="measure this machine's wake-up floor for S s at start (default 2; 0: do not)",
    )
    p.set_defaults(func=_run)


class Floor:
    """The machine's own wake-up lateness (p99, max µs), measured once in a background thread."""

    def __init__(self, seconds: float, period_s: float) -> None:
        self.p99_us: float | None = None
        self.max_us: float | None = None
        self.error: str | None = None if seconds > 0 else "--floor-seconds 0"
        if seconds > 0:
            threading.Thread(target=self._measure, args=(seconds, period_s), daemon=True).start()

    def _measure(self, seconds: float, period_s: float) -> None:
        try:
            from tvsd.control.latency import jitter, run_floor

            j = jitter(*run_floor(seconds, period_s))
            self.p99_us, self.max_us = j.p99_us, j.max_us
        except Exception as exc:  # the view goes on without it, saying why
            self.error = f"{type(exc).__name__}: {exc}"

    def text(self) -> str:
        if self.p99_us is not None:
            return f"p99 {self.p99_us:.1f} µs, max {self.max_us:.0f} µs (bare sleep loop, this machine)"
        return f"not measured ({self.error})" if self.error else "measuring…"


def sparkline(values: list[float], lo: float, hi: float, width: int = 60) -> str:
    """The last `width` values as block characters between lo and hi."""
    values = values[-width:]
    if not values:
        return ""
    span = hi - lo if hi > lo else 1.0
    out = []
    for v in values:
        k = 0 if not math.isfinite(v) else round((min(max(v, lo), hi) - lo) / span * (len(SPARK) - 1))
        out.append(SPARK[k])
    return "".join(out)


def render(status: Mapping[str, Any] | None, history: list[tuple[float, float, float]], floor: Floor,
           error: str | None = None) -> Any:  # fmt: skip
    """One frame: a rich Table (pure function of its inputs, so tests can render it to text)."""
    from rich.table import Table
    from rich.text import Text

    grid = Table.grid(padding=(0, 2))
    grid.add_column(style="bold", no_wrap=True)
    grid.add_column()
    grid.title = f"tvsd — {local_time(time.time())}"
    if status is None:
        grid.add_row("daemon", Text(error or "no answer yet", style="bold red"))
        return grid
    state = str(status.get("state"))
    grid.add_row("state", Text(state, style=STATE_STYLE.get(state, "")))
    rps, ref = float(status.get("rps", math.nan)), float(status.get("rps_setpoint", math.nan))
    grid.add_row("rev/s", f"{rps:7.2f}  reference {ref:6.2f}  error {rps - ref:+.2f}")
    speeds = [h[1] for h in history]
    if speeds:
        hi = max(max(speeds), ref if math.isfinite(ref) else 0.0, 1.0)
        grid.add_row(f"last {HISTORY_S:.0f} s", f"{sparkline(speeds, 0.0, hi)}  (0 … {hi:.1f} rev/s)")
    loop = status.get("loop", {})
    grid.add_row(
        "loop",
        f"{loop.get('rate_hz', math.nan):.0f} Hz, missed {loop.get('missed_ticks', 0)} of "
        f"{loop.get('ticks', 0)} ticks, lateness p99 {loop.get('jitter_p99_us', math.nan):.1f} µs, "
        f"max {loop.get('jitter_max_us', math.nan):.0f} µs",
    )
    grid.add_row("floor", floor.text())
    imu = status.get("imu", {})
    grid.add_row("imu", f"{imu.get('state')}" + (f" ({imu['detail']})" if imu.get("detail") else ""))
    link = status.get("link", {})
    # a late-input hold: PWM 0, not latched, while the MCU's frames are late (tvsd.control.hold)
    held = Text(" HELD: PWM 0, input late", style="bold yellow") if link.get("input_held") else ""
    holds = f", {link['late_input_holds']} late-input holds" if link.get("late_input_holds") else ""
    grid.add_row("link", Text.assemble(f"{link.get('state')} ({link.get('source', '?')}){holds}", held))
    pts = status.get("points", {})
    lat = f", latency p50 {pts['latency_p50_ms']:.0f} ms" if "latency_p50_ms" in pts else ""
    counts = f"{pts.get('total', 0)} total, {pts.get('no_imu', 0)} no_imu"
    grid.add_row("points", f"{pts.get('per_s', 0):.1f}/s, {counts}{lat}")
    aim = status.get("aim_deg", {})
    grid.add_row("aim", f"φ {aim.get('phi', math.nan):.2f}°, γ {aim.get('gamma', math.nan):.2f}°")
    grid.add_row("recording", str(status.get("recording") or "off"))
    faults = list(status.get("faults", []))
    if not faults:
        grid.add_row("faults", Text("none", style="green"))
    # The first since the last clear is the one that latched a fault state; then the newest two.
    shown: list[Any] = faults
    if len(faults) > 3:
        shown = [faults[0], f"… {len(faults) - 3} more …", *faults[-2:]]
    for n, f in enumerate(shown):
        label = f"faults ({len(faults)})" if n == 0 else ""
        if isinstance(f, str):
            grid.add_row(label, Text(f, style="red"))
            continue
        when = local_time(f["t_unix"]) if isinstance(f.get("t_unix"), (int, float)) else "?"
        line = f"{when}  {f.get('kind')}: {f.get('cause')} → {f.get('action')}"
        grid.add_row(label, Text(line, style="red"))
    if error:
        grid.add_row("", Text(error, style="bold red"))
    grid.caption = "q or Ctrl-C quits"
    return grid


@contextlib.contextmanager
def _keys() -> Iterator[Any]:
    """A function waiting up to t s for a key, True on q; the terminal in cbreak mode meanwhile."""
    fd = sys.stdin.fileno() if sys.stdin is not None and sys.stdin.isatty() else None
    if fd is None:

        def sleep(t: float) -> bool:
            time.sleep(t)
            return False

        yield sleep
        return
    import termios
    import tty

    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)

        def wait(t: float) -> bool:
            end = time.monotonic() + t
            while (left := end - time.monotonic()) > 0:
                ready, _, _ = select.select([fd], [], [], left)
                if ready and sys.stdin.read(1).lower() == "q":
                    return True
            return False

        yield wait
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


class _Poller:
    def __init__(self, path: Path) -> None:
        self.client = RpcClient(path, timeout=2.0)
        self.history: deque[tuple[float, float, float]] = deque()

    def poll(self) -> tuple[Mapping[str, Any] | None, str | None]:
        try:
            s = self.client.call("status")
        except DaemonUnavailable as exc:
            self.client.close()
            return None, str(exc)
        if not isinstance(s, Mapping):
            raise TvsdError(f"tvsd's status is not an object: {s!r}")
        now = time.monotonic()
        self.history.append((now, float(s.get("rps", math.nan)), float(s.get("rps_setpoint", math.nan))))
        while self.history and self.history[0][0] < now - HISTORY_S:
            self.history.popleft()
        return s, None


def _run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    if not 0.05 <= args.period <= 60:
        raise UsageError(f"--period {args.period:g}: give 0.05 to 60 s")
    if args.frames is not None and args.frames < 1:
        raise UsageError(f"--frames {args.frames}: give at least 1")
    frames = 1 if args.once else args.frames
    poller = _Poller(socket_path(args.socket))
    console = Console()
    status, error = poller.poll()
    if status is None and frames is not None:
        raise DaemonUnavailable(error or "tvsd did not answer")
    floor = Floor(args.floor_seconds if frames is None else 0.0, 1e-4)

    def frame() -> Any:
        return render(status, list(poller.history), floor, error)

    try:
        if frames is not None or not console.is_terminal:  # one frame after the other
            for n in range(frames or sys.maxsize):
                if n:
                    time.sleep(args.period)
                    status, error = poller.poll()
                console.print(frame())
            return EXIT_OK
        with _keys() as wait, Live(frame(), console=console, auto_refresh=False, screen=False) as live:
            while not wait(args.period):
                status, error = poller.poll()
                live.update(frame(), refresh=True)
    except KeyboardInterrupt:
        pass  # a clean quit, as q
    finally:
        poller.client.close()
    return EXIT_OK
