"""`tvsctl points`: the point stream, saying what it waits for and giving up after a timeout.

The stream is read in a thread into a queue, so that the main thread can look at the daemon's
state while no point comes (a faulted drive makes no point: the operator is told so, and why),
and stop at the timeout with exit status 1 and the reason.
"""

from __future__ import annotations

import queue
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from typing import Any

from tvsd.errors import DaemonUnavailable, TvsdError
from tvsd.rpc.client import RpcClient

POLL_S = 1.0  # how often the state is looked at while no point comes


class NoPoints(TvsdError):
    """No point within --timeout (exit status 1: the command ran, the result is a failure)."""


def why_no_points(status: Mapping[str, Any]) -> str:
    """What a point stream is waiting for, from the daemon's status: one line with the fix."""
    state = status.get("state")
    if state == "fault":
        faults = status.get("faults", [])  # the first since the last clear is the one that latched
        cause = str(faults[0].get("cause")) if faults else "see `tvsctl faults`"
        more = f" and {len(faults) - 1} more" if len(faults) > 1 else ""
        return f"the drive is faulted ({cause}{more}): `tvsctl faults --clear`, then `tvsctl scan start`"
    if state == "starting":
        return "the daemon is still starting (its devices are coming up)"
    if state in ("idle", "spinning"):
        return f"the daemon is {state}, not scanning: `tvsctl speed 25` and `tvsctl scan start`"
    if state == "stopping":
        return "the daemon is stopping"
    if state == "scanning":
        return (
            "scanning, but no optical pulse has made a point yet "
            f"(points/s {status.get('points', {}).get('per_s', 0):g}, laser aimed at a target?)"
        )
    return f"the daemon is {state!r}"


def stream_points(client: RpcClient, count: int, timeout_s: float | None) -> Iterator[object]:
    """Yield `count` points; while none comes, say on stderr what is awaited (each change of it)."""
    items: queue.Queue[object] = queue.Queue()
    done = object()

    def reader() -> None:
        try:
            for params in client.subscribe("points"):
                for point in params if isinstance(params, list) else [params]:  # one point or a batch
                    items.put(point)
        except TvsdError as exc:
            items.put(exc)
        except OSError as exc:  # the socket closed under the read (tvsctl leaving): no traceback
            items.put(DaemonUnavailable(f"the points stream ended: {exc.strerror or exc}"))
        items.put(done)

    threading.Thread(target=reader, name="tvsctl-points", daemon=True).start()
    last_point = time.monotonic()
    said: str | None = None
    left = count
    while left:
        try:
            item = items.get(timeout=POLL_S)
        except queue.Empty:
            waited = time.monotonic() - last_point
            reason = _reason(client)
            if reason.split("(")[0] != said:  # once per kind of wait, not per new fault entry
                print(f"tvsctl: waiting for points: {reason}", file=sys.stderr, flush=True)
                said = reason.split("(")[0]
            if timeout_s is not None and waited >= timeout_s:
                raise NoPoints(f"no point within {timeout_s:g} s: {reason}") from None
            continue
        if item is done:
            return
        if isinstance(item, TvsdError):
            raise item
        last_point = time.monotonic()
        yield item
        left -= 1


def _reason(client: RpcClient) -> str:
    """Asked over a second connection: the first one is busy with the stream."""
    try:
        with RpcClient(client.path, timeout=client.timeout) as other:
            status = other.call("status")
    except TvsdError as exc:
        return f"cannot ask the daemon's state ({exc})"
    return why_no_points(status) if isinstance(status, Mapping) else "unknown state"
