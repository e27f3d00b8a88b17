"""`tvsctl identify`: a bounded excitation on top of spinning/scanning, recorded for `tvsctl analyze`.

A thin client of the daemon's `identify`, `identify_status` and `identify_abort` methods
(tvsd/daemon/identify.py): it starts the run, shows its progress on stderr (a bar on a terminal, a
line every LOG_EVERY_S otherwise), aborts it on Ctrl-C or when --timeout passes, and at the end
prints the recording and the next command: `tvsctl export REC --csv OUT && tvsctl analyze OUT`.
Exit 0 done, 1 aborted (a fault, the speed strayed, a timeout: the reason is printed, the recording
so far kept), 2 bad parameters, 3 no daemon.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from tvsd.cli.output import print_json, print_pairs
from tvsd.config import EXCITATION_KINDS
from tvsd.errors import EXIT_FAILURE, EXIT_OK, UsageError
from tvsd.rpc.client import DEFAULT_SOCKET, ENV_SOCKET, RpcClient, socket_path

POLL_S = 0.25
LOG_EVERY_S = 5.0
TIMEOUT_MARGIN_S = 30.0  # past the excitation: settling, closing the recording, a loaded machine


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "identify",
        help="excite the spinning aperture (steps, multisine, PRBS) and record it for analyze",
        description="Add a bounded excitation on top of spinning or scanning (amplitudes and limits "
        "from the config's identify: section), record it, and print the recording and the command "
        "that analyses it. Aborts on any fault.",
    )
    p.add_argument("--seconds", type=float, metavar="S", help="excitation length (default: identify.seconds)")
    p.add_argument(
        "--kinds", metavar="K,K", help=f"any of {','.join(EXCITATION_KINDS)} (default: identify.kinds)"
    )
    p.add_argument("--seed", type=int, metavar="N", help="random seed (default: identify.seed)")
    timeout_help = f"give up after S (default: seconds + {TIMEOUT_MARGIN_S:g})"
    p.add_argument("--timeout", type=float, metavar="S", help=timeout_help)
    p.add_argument("--abort", action="store_true", help="abort the identify that is running")
    socket_help = f"daemon socket (default: ${ENV_SOCKET}, else {DEFAULT_SOCKET})"
    p.add_argument("--socket", type=Path, metavar="PATH", help=socket_help)
    p.add_argument("--json", action="store_true", help="print one JSON object at the end")
    p.set_defaults(func=_run)


def _params(args: argparse.Namespace) -> dict[str, Any]:
    params: dict[str, Any] = {}
    if args.seconds is not None:
        if not (math.isfinite(args.seconds) and args.seconds > 0):
            raise UsageError(f"--seconds {args.seconds:g}: give a positive duration")
        params["seconds"] = args.seconds
    if args.kinds is not None:
        kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
        bad = [k for k in kinds if k not in EXCITATION_KINDS]
        if bad or not kinds:
            raise UsageError(f"--kinds {args.kinds!r}: give any of {','.join(EXCITATION_KINDS)}")
        params["kinds"] = kinds
    if args.seed is not None:
        if args.seed < 0:
            raise UsageError(f"--seed {args.seed}: give 0 or more")
        params["seed"] = args.seed
    if args.timeout is not None and not (math.isfinite(args.timeout) and args.timeout > 0):
        raise UsageError(f"--timeout {args.timeout:g}: give a positive number of seconds")
    return params


def _call(client: RpcClient, method: str, **params: Any) -> dict[str, Any]:
    result = client.call(method, **params)
    if not isinstance(result, dict):  # the daemon's methods answer objects; anything else is a bug
        raise TypeError(f"{method} answered {result!r}")
    return result


def _run(args: argparse.Namespace) -> int:
    params = _params(args)
    with RpcClient(socket_path(args.socket)) as client:
        if args.abort:
            result = _call(client, "identify_abort")
            print_json(result) if args.json else print(f"identify aborted; recording {result['recording']}")
            return EXIT_OK
        run = _call(client, "identify", **params)
        exc = run["excitation"]
        say(
            f"identify: {', '.join(exc['kinds'])} for {exc['seconds']:g} s on top of "
            f"{run['rps_setpoint']:g} rev/s (±{exc['peak_rps']:.3g} rev/s, ±{exc['peak_volts']:.3g} V); "
            f"recording {run['recording']}"
        )
        timeout = args.timeout if args.timeout is not None else exc["seconds"] + TIMEOUT_MARGIN_S
        try:
            final = _follow(client, timeout)
        except KeyboardInterrupt:
            _call(client, "identify_abort")
            say("\nidentify: aborted (Ctrl-C); the excitation is off")
            raise
    return _report(final, as_json=args.json)


def _follow(client: RpcClient, timeout: float) -> dict[str, Any]:
    """Poll until the run is over (its recording closed) or `timeout`; then abort it."""
    tty = sys.stderr.isatty()
    deadline = time.monotonic() + timeout
    last_log = -math.inf
    while True:
        st = _call(client, "identify_status")
        if st["state"] in ("done", "aborted"):
            if tty:
                sys.stderr.write("\n")
            return st
        now = time.monotonic()
        if now > deadline:
            if st["state"] == "running":
                _call(client, "identify_abort")
            st = _call(client, "identify_status")
            st["outcome"], st["reason"] = "aborted", f"no outcome within --timeout {timeout:g} s"
            return st
        line = f"{100 * st['progress']:5.1f} %  {st['elapsed_s']:6.1f} / {st['seconds']:g} s  ({st['state']})"
        if tty:
            bar = "#" * round(30 * st["progress"])
            sys.stderr.write(f"\r  [{bar:<30}] {line}")
            sys.stderr.flush()
        elif now - last_log >= LOG_EVERY_S:
            say(f"  {line}")
            last_log = now
        time.sleep(POLL_S)


def _report(st: dict[str, Any], *, as_json: bool) -> int:
    rec = st.get("recording")
    out = Path(rec).name + ".csv" if rec else "rec.csv"
    nxt = f"tvsctl export {rec} --csv {out} && tvsctl analyze {out}"
    done = st.get("outcome") == "done"
    result = {**st, "next": nxt if rec else None}
    if as_json:
        print_json(result)
    elif done:
        print_pairs({"outcome": "done", "seconds": st["seconds"], "recording": rec, "next": nxt})
    if not done:
        say(f"tvsctl: identify aborted: {st.get('reason') or 'unknown'}; the recording so far: {rec}")
        return EXIT_FAILURE
    return EXIT_OK


def say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)
