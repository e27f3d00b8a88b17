"""The JSON-RPC 2.0 server: a Unix socket, newline-delimited JSON, one object (or batch array) per line.

One owner a module: `server` the transport (the socket file: stale ones replaced, a running daemon
refused; the connections, their framing and the subscriptions), `dispatch` what one line means (the
method table, batches, the reply's size), `limits` the bounds and the rate's token bucket, `bench`
the round-trip benchmark. What one message must look like — the request checks, method lookup,
params binding and the error codes — is `tvsd.rpc.protocol` (its names are re-exported here). The
daemon hands `RpcServer` a table of ``async def`` methods.

Built-in methods: ``subscribe(topic)`` and ``unsubscribe(topic)``. `RpcServer.publish` pushes
``{"jsonrpc": "2.0", "method": topic, "params": ...}`` to every client subscribed to ``topic``. It
never blocks: each client has a bounded queue drained by its own task, and a notification that
finds the queue full is dropped and counted (``stats["dropped_notifications"]``) — a slow
``tvsctl points`` must not slow the scanner. Call ``publish`` from the event-loop thread; from the
control thread use ``server.publish_threadsafe(topic, params)``.

Requests of one connection are handled in order; a batch's requests run concurrently, at most
``Limits.max_concurrent`` at a time, the event loop served between groups.

Bounds (`Limits`, from the config's ``daemon:`` section; README "Daemon API limits"): a client
sending faster than ``rate_per_s`` requests (a batch counts each member) is slowed down — its next
line is read only when its token bucket allows — so no client can hog the event loop; a batch
longer than ``max_batch``, a reply longer than ``max_reply_bytes`` and a connection beyond
``max_clients`` get a -32003 LIMIT_ERROR naming the limit (``error.data``: limit, value, seen).
"""

from tvsd.config import SOCKET_PATH_MAX
from tvsd.daemon.rpc.bench import bench_rpc
from tvsd.daemon.rpc.limits import UNLIMITED, Limits
from tvsd.daemon.rpc.server import DaemonAlreadyRunning, RpcServer, SocketPathError, ThreadedRpcServer
from tvsd.rpc.protocol import (
    DEVICE_ERROR,
    INTERNAL_ERROR,
    INVALID_PARAMS,
    INVALID_REQUEST,
    LIMIT_ERROR,
    METHOD_NOT_FOUND,
    PARSE_ERROR,
    STATE_ERROR,
    Encoded,
    Method,
    RpcError,
)

__all__ = [
    "DEVICE_ERROR",
    "INTERNAL_ERROR",
    "INVALID_PARAMS",
    "INVALID_REQUEST",
    "LIMIT_ERROR",
    "METHOD_NOT_FOUND",
    "PARSE_ERROR",
    "SOCKET_PATH_MAX",
    "STATE_ERROR",
    "UNLIMITED",
    "DaemonAlreadyRunning",
    "Encoded",
    "Limits",
    "Method",
    "RpcError",
    "RpcServer",
    "SocketPathError",
    "ThreadedRpcServer",
    "bench_rpc",
]
