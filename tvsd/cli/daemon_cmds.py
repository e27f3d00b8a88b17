"""tvsctl commands that talk to the running daemon: thin clients of its JSON-RPC socket.

Each command maps to the daemon method of the same name (``scan start`` → ``scan_start``, ...),
takes --socket PATH (else $TVSD_SOCKET, else /run/tvsd/tvsd.sock) and --json, and prints an aligned
table by default: clock times as local ISO time with ms, point flags as words (tvsd.cli.human).

The JSON rule, the same for every tvsctl command: ``--json`` prints one JSON object, the answer
itself, never wrapped; an answer that is a list is given the name of what it lists
(``{"faults": [...]}``). A stream (``points``) prints one such object per line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from tvsd.cli.human import humanize
from tvsd.cli.output import print_json, print_pairs, print_table
from tvsd.cli.progress import on_terminal
from tvsd.errors import EXIT_OK, UsageError
from tvsd.rpc.client import DEFAULT_SOCKET, ENV_SOCKET, RemoteError, RpcClient, socket_path

GAIN_NAMES = ("Gp", "Gd", "Gr", "G0")
CALL_TIMEOUT_S = 5.0  # an answer the daemon owes at once (status, speed, ...)
POINTS_TIMEOUT_S = 10.0  # the point stream: a scanning daemon makes ~20 points/s

_SOCKET_HELP = f"daemon socket (default: ${ENV_SOCKET}, else {DEFAULT_SOCKET})"

Runner = Callable[[argparse.Namespace, RpcClient], object]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--socket", type=Path, metavar="PATH", help=_SOCKET_HELP)
    common.add_argument("--json", action="store_true", help="print one JSON object")
    common.add_argument(
        "--timeout",
        type=float,
        metavar="S",
        help=f"give up after S s without the daemon's answer (default {CALL_TIMEOUT_S:g}; "
        f"points: S s without a point, default {POINTS_TIMEOUT_S:g}, 0 waits forever)",
    )

    def add(name: str, help_: str, run: Runner) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_, parents=[common])
        p.set_defaults(func=lambda args: _run(args, run))
        return p

    add("status", "state of the running daemon", lambda a, c: c.call("status"))
    p = add("speed", "set the motor speed", lambda a, c: c.call("speed", rps=a.rps))
    p.add_argument("rps", type=float, help="rev/s")
    p = add("scan", "start or stop scanning", lambda a, c: c.call(f"scan_{a.action}"))
    p.add_argument("action", choices=("start", "stop"))
    p = add("aim", "aim the laser at angles or at a point", _aim)
    p.add_argument("--phi-deg", type=float, metavar="DEG", help="azimuth φ, degrees (with --gamma-deg)")
    p.add_argument("--gamma-deg", type=float, metavar="DEG", help="elevation γ, degrees (with --phi-deg)")
    p.add_argument("--xyz", type=float, nargs=3, metavar=("X", "Y", "Z"), help="target point, m")
    p = add("gains", "show the controller gains, or set them", _gains)
    p.add_argument("--set", metavar="Gp,Gd,Gr,G0", help="four numbers separated by commas")
    p = add("record", "start or stop recording", lambda a, c: c.call(f"record_{a.action}"))
    p.add_argument("action", choices=("start", "stop"))
    p = add("faults", "list the faults, or clear them", _faults)
    p.add_argument("--clear", action="store_true", help="clear the faults")
    p = add("points", "print points of the live point stream", _points)
    p.add_argument("--count", type=int, default=10, metavar="N", help="points to print (default 10)")
    p = add("calibrate-imu", "IMU gyro bias at rest: the daemon saves and applies it", _calibrate_imu)
    p.add_argument("--seconds", type=float, default=2.0, metavar="S", help="capture at rest (default 2)")
    add("shutdown", "stop the daemon", lambda a, c: c.call("shutdown"))


def _run(args: argparse.Namespace, run: Runner) -> int:
    timeout = args.timeout
    if timeout is not None and not (timeout > 0 or (timeout == 0 and args.command == "points")):
        raise UsageError(f"--timeout {timeout:g}: give seconds > 0")
    call_timeout = CALL_TIMEOUT_S if timeout is None or args.command == "points" else timeout
    with RpcClient(socket_path(args.socket), timeout=call_timeout) as client:
        result = run(args, client)
    if result is not None:
        show(result, as_json=args.json, name=args.command)
    return EXIT_OK


def _aim(args: argparse.Namespace, client: RpcClient) -> object:
    angles = (args.phi_deg, args.gamma_deg)
    if args.xyz is not None and angles == (None, None):
        x, y, z = args.xyz
        return client.call("aim_xyz", x=x, y=y, z=z)
    if args.xyz is None and None not in angles:
        return client.call("aim", phi_deg=args.phi_deg, gamma_deg=args.gamma_deg)
    raise UsageError("aim: give --phi-deg DEG and --gamma-deg DEG together, or --xyz X Y Z (not both)")


def parse_gains(text: str) -> dict[str, float]:
    """'Gp,Gd,Gr,G0' → the four gains by name; UsageError saying what was wrong."""
    parts = [s.strip() for s in text.split(",")]
    if len(parts) != len(GAIN_NAMES):
        raise UsageError(
            f"--set {text!r}: give four numbers Gp,Gd,Gr,G0 (e.g. --set 40,1.2,0.5,0), got {len(parts)}"
        )
    gains: dict[str, float] = {}
    for name, part in zip(GAIN_NAMES, parts, strict=True):
        try:
            value = float(part)
        except ValueError:
            raise UsageError(f"--set {text!r}: {name} is {part!r}, not a number") from None
        if not math.isfinite(value):
            raise UsageError(f"--set {text!r}: {name} is {part!r}; give a finite number")
        gains[name] = value
    return gains


def _gains(args: argparse.Namespace, client: RpcClient) -> object:
    if args.set is None:
        return client.call("gains_get")
    return client.call("gains_set", **parse_gains(args.set))


def _calibrate_imu(args: argparse.Namespace, client: RpcClient) -> object:
    if not 0 < args.seconds <= 60:
        raise UsageError(f"--seconds {args.seconds:g}: give a duration up to 60 s (the scanner at rest)")
    if args.timeout is None:  # the answer comes after the capture
        client.timeout = args.seconds + CALL_TIMEOUT_S
    _wait_for_rest(client)
    if on_terminal():
        print(f"tvsctl: capturing {args.seconds:g} s at rest, then the answer", file=sys.stderr, flush=True)
    return client.call("imu_calibrate", seconds=args.seconds)


# `speed 0` then `calibrate-imu`: the rotor ramps down (10 rev/s² from at most 60 rev/s, plus
# control.stop_margin_s 1 s: 7 s) while the daemon refuses a calibration above 0.05 rev/s.
REST_RPS = 0.05  # the daemon's limit (tvsd.daemon.api.api_imu_calibrate)
REST_WAIT_S = 15.0  # twice the longest ramp down; then the daemon's refusal is the answer
REST_POLL_S = 0.2


def _wait_for_rest(client: RpcClient, wait_s: float = REST_WAIT_S, poll_s: float = REST_POLL_S) -> None:
    """Wait, up to `wait_s`, for a rotor commanded to 0 to stop; never for one still driven (the
    daemon's refusal says to stop it)."""
    deadline = time.monotonic() + wait_s
    said = False
    while True:
        try:
            status = client.call("status")
        except RemoteError:  # a daemon without status (a stand-in): it judges the rest itself
            return
        if not isinstance(status, Mapping):
            return
        rps, setpoint = status.get("rps"), status.get("rps_setpoint")
        if not isinstance(rps, int | float) or abs(rps) <= REST_RPS or setpoint != 0:
            return
        if time.monotonic() > deadline:
            return
        if not said:
            print(f"tvsctl: waiting for the rotor to stop ({rps:.2f} rev/s)", file=sys.stderr, flush=True)
            said = True
        time.sleep(poll_s)


def _faults(args: argparse.Namespace, client: RpcClient) -> object:
    return client.call("faults_clear" if args.clear else "faults_list")


def _points(args: argparse.Namespace, client: RpcClient) -> None:
    if args.count < 1:
        raise UsageError(f"--count {args.count}: give at least 1")
    from tvsd.cli.point_wait import stream_points

    timeout = POINTS_TIMEOUT_S if args.timeout is None else args.timeout
    for point in stream_points(client, args.count, timeout or None):
        _show_line(point, as_json=args.json)


def _show_line(item: object, *, as_json: bool) -> None:
    if as_json or not isinstance(item, Mapping):
        print(json.dumps(item), flush=True)
    else:
        print("  ".join(f"{k}={_fmt(v)}" for k, v in humanize(item).items()), flush=True)


def _fmt(value: object) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def flatten(obj: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested objects as dotted keys, for a two-column table."""
    out: dict[str, Any] = {}
    for k, v in obj.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping) and v:
            out.update(flatten(v, key + "."))
        elif isinstance(v, list) and v and all(isinstance(i, Mapping) for i in v):
            out[key] = list(v)  # one line per item (faults): print_pairs
        else:
            out[key] = json.dumps(v) if isinstance(v, (list, Mapping)) else v
    return out


def as_object(result: object, name: str) -> Mapping[str, Any]:
    """The JSON rule (module doc): an object as it is, anything else named by the command."""
    return result if isinstance(result, Mapping) else {name: result}


def show(result: object, *, as_json: bool, name: str = "result") -> None:
    """Print a method's result: as one JSON object with --json, else as a table."""
    if as_json:
        print_json(as_object(result, name))
    elif isinstance(result, Mapping):
        if result:
            print_pairs(flatten(humanize(result)))
    elif isinstance(result, list) and result and all(isinstance(r, Mapping) for r in result):
        result = [humanize(r) for r in result]
        keys = list(dict.fromkeys(k for r in result for k in r))
        print_table([[r.get(k, "") for k in keys] for r in result], keys)
    elif isinstance(result, list) and not result:
        print("(none)")
    else:
        print(result)
