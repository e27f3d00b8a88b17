"""What the server does with one line: decode it, run a request or a batch through the method
table (a batch at most ``Limits.max_concurrent`` at a time, the event loop served between groups),
and encode the reply within ``Limits.max_reply_bytes``. The message rules and codes are
`tvsd.rpc.protocol`'s; the built-in ``subscribe``/``unsubscribe`` change the calling connection's
topics. Knows nothing of sockets."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Collection, Mapping

from tvsd.daemon.rpc.limits import Limits, limit_error
from tvsd.rpc.protocol import (
    INTERNAL_ERROR,
    INVALID_PARAMS,
    INVALID_REQUEST,
    Method,
    MethodTable,
    RpcError,
    clean,
    decode,
    dumps,
    error_reply,
    parse_request,
    reply_to_error,
    result_reply,
)

log = logging.getLogger("tvsd.daemon.rpc")

BUILTINS = ("subscribe", "unsubscribe")


async def _topic_method(topic: str) -> None:
    """Signature of the built-in subscribe/unsubscribe (the dispatcher implements them itself)."""


class Dispatcher:
    """The method table, the batch and reply bounds, and the counts of requests and errors."""

    def __init__(
        self, methods: Mapping[str, Method], limits: Limits, topics: Collection[str] | None = None
    ) -> None:
        clash = [name for name in BUILTINS if name in methods]
        if clash:
            raise ValueError(f"method {clash[0]!r} is built into RpcServer; rename it")
        self.limits = limits
        self.topics = frozenset(topics) if topics is not None else None
        self.counts = {"requests": 0, "errors": 0}
        self._methods = MethodTable(methods, also_offered=BUILTINS)
        self._builtins = MethodTable(dict.fromkeys(BUILTINS, _topic_method))

    def error(self, err: RpcError) -> bytes:
        """A counted error reply without an id (the line could not be read as a request)."""
        self.counts["errors"] += 1
        return dumps(error_reply(None, err))

    async def handle_line(self, line: bytes, subscribed: set[str]) -> bytes | None:
        """The reply line to one request line (None: nothing to send); `subscribed` is the
        connection's topics."""
        if not line.strip():
            return None
        try:
            msg = decode(line)
        except RpcError as err:
            return self.error(err)
        if isinstance(msg, list):
            if not msg:
                return self.error(RpcError(INVALID_REQUEST, "empty batch []: send at least one request"))
            if len(msg) > self.limits.max_batch:
                n = self.limits.max_batch
                return self.error(
                    limit_error(
                        "max_batch", n, len(msg),
                        f"batch of {len(msg)} requests; tvsd takes at most {n} in one line "
                        "(daemon.rpc_max_batch): split it",
                    )
                )  # fmt: skip
            replies: list[dict[str, object] | None] = []
            step = self.limits.max_concurrent
            for k in range(0, len(msg), step):
                if k:
                    await asyncio.sleep(0)  # the event loop's other work between groups
                replies += await asyncio.gather(*(self._handle(m, subscribed) for m in msg[k : k + step]))
            done = [r for r in replies if r is not None]
            return self._encode(done) if done else None
        reply = await self._handle(msg, subscribed)
        return None if reply is None else self._encode(reply)

    def _encode(self, reply: object) -> bytes:
        try:
            data = dumps(reply)
        except (TypeError, ValueError) as exc:  # unreachable for replies built from clean'd results
            return self.error(RpcError(INTERNAL_ERROR, f"reply is not JSON: {exc}"))
        n = self.limits.max_reply_bytes
        if len(data) <= n:
            return data
        self.counts["errors"] += 1
        rid = reply.get("id") if isinstance(reply, dict) else None
        err = limit_error(
            "max_reply_bytes", n, len(data),
            f"the reply would be {len(data)} bytes; tvsd sends at most {n} in one line "
            "(daemon.rpc_max_reply_bytes): ask for less in one request or batch",
        )  # fmt: skip
        return dumps(error_reply(rid, err))

    async def _handle(self, msg: object, subscribed: set[str]) -> dict[str, object] | None:
        self.counts["requests"] += 1
        try:
            req = parse_request(msg)
            result = clean(await self._call(req.method, req.params, subscribed))
        except RpcError as err:
            self.counts["errors"] += 1
            return reply_to_error(msg, err)
        except Exception as exc:
            self.counts["errors"] += 1
            name = msg.get("method") if isinstance(msg, dict) else None
            log.exception("JSON-RPC method %r failed", name)
            bug = RpcError(INTERNAL_ERROR, f"{name}: internal error ({type(exc).__name__}: {exc})")
            return reply_to_error(msg, bug)
        return None if req.notify else result_reply(req.id, result)

    async def _call(self, method: str, params: object, subscribed: set[str]) -> object:
        if method in BUILTINS:
            _, kwargs = self._builtins.bind(method, params)
            return self._subscribe(subscribed, kwargs["topic"], on=method == "subscribe")
        fn, kwargs = self._methods.bind(method, params)
        return await fn(**kwargs)

    def _subscribe(self, subscribed: set[str], topic: str, on: bool = True) -> dict[str, object]:
        if self.topics is not None and topic not in self.topics:
            raise RpcError(
                INVALID_PARAMS,
                f"unknown topic {topic!r}; topics: {', '.join(sorted(self.topics))}",
                sorted(self.topics),
            )
        (subscribed.add if on else subscribed.discard)(topic)
        return {"topic": topic, "subscribed": on}
