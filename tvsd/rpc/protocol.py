"""JSON-RPC 2.0 messages: what a request must look like, and the replies to it.

This module owns everything about one message, with no socket in sight: decoding a line, checking
that it is a request, finding its method, binding its params to the method's signature and type
hints (float/int/str/bool/list/dict) so a method body only sees well-typed arguments, and shaping
results and errors into replies. Params may come by name (object) or by position (array). The
server that carries these messages is `tvsd.daemon.rpc`.

Error codes (``error.code`` of a reply):

====== ================ =====================================================================
code   name             meaning
====== ================ =====================================================================
-32700 PARSE_ERROR      the line is not JSON (NaN/Infinity are refused too); id is null
-32600 INVALID_REQUEST  valid JSON but not a request, or a line longer than ``max_message``
                        (that connection is then closed; the daemon keeps serving the others)
-32601 METHOD_NOT_FOUND ``error.data`` lists the methods offered
-32602 INVALID_PARAMS   the message names the parameter, what was seen and what is expected
-32603 INTERNAL_ERROR   a method raised something unexpected: a bug, logged with its traceback
-32001 DEVICE_ERROR     the scanner (MCU, motor, IMU, laser) refused or failed the request
-32002 STATE_ERROR      the request does not fit the daemon's state (e.g. aim while not scanning)
-32003 LIMIT_ERROR      a bound of the server: a batch too long, a reply too large, too many
                        connections (``error.data`` names the limit and its value)
====== ================ =====================================================================

Numbers: a parameter typed float must be finite and within ±``MAX_FLOAT`` (1e300: a 400-digit
integer is refused as -32602, not a float overflow); one typed int within ±2**53 (what every
JSON reader keeps exactly). An ``id`` must be finite too (``1e999`` parses to infinity).
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import types
import typing
from collections.abc import Awaitable, Callable, Collection, Mapping
from pathlib import Path
from typing import Any, NamedTuple

PARSE_ERROR = -32700
INVALID_REQUEST = -32600
METHOD_NOT_FOUND = -32601
INVALID_PARAMS = -32602
INTERNAL_ERROR = -32603
DEVICE_ERROR = -32001
STATE_ERROR = -32002
LIMIT_ERROR = -32003

MAX_INT = 2**53  # JSON's safe integers: beyond them readers disagree
MAX_FLOAT = 1e300  # far beyond any physical parameter, well inside a double
MAX_ID_CHARS = 256  # an id is echoed in the reply: a long one must not multiply a batch's reply

Method = Callable[..., Awaitable[object]]


MAX_ERROR_MESSAGE = 400  # characters: a message names what it saw, it does not repeat a whole line


class RpcError(Exception):
    """Raised by a method to reply with a JSON-RPC error instead of a result."""

    def __init__(self, code: int, message: str, data: object | None = None) -> None:
        if len(message) > MAX_ERROR_MESSAGE:  # it echoed a 50 KB method or parameter name back
            message = f"{message[: MAX_ERROR_MESSAGE - 40]}… ({len(message)} characters, cut)"
        super().__init__(message)
        self.code = code
        self.message = message
        self.data = data

    def to_json(self) -> dict[str, object]:
        err: dict[str, object] = {"code": self.code, "message": self.message}
        if self.data is not None:
            err["data"] = self.data
        return err


# --- params --------------------------------------------------------------------------------------

_KINDS: dict[type, tuple[str, tuple[type, ...]]] = {
    float: ("a number", (int, float)),
    int: ("an integer", (int,)),
    str: ("a string", (str,)),
    bool: ("true or false", (bool,)),
    list: ("an array", (list,)),
    dict: ("an object", (dict,)),
}


def _number_problem(value: object, allowed: tuple[type, ...]) -> str | None:
    """Why a number is out of the bounds every parameter has (module docstring), or None."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        if float in allowed and int not in allowed:
            return None if abs(value) <= MAX_FLOAT else f"must be a number within ±{MAX_FLOAT:g}"
        return None if abs(value) <= MAX_INT else f"must be an integer within ±2**53 ({MAX_INT})"
    if isinstance(value, float):
        ok = math.isfinite(value) and abs(value) <= MAX_FLOAT
        return None if ok else f"must be a finite number within ±{MAX_FLOAT:g}"
    return None


def _json_type(value: object) -> str:
    names = {bool: "boolean", int: "integer", float: "number", str: "string", list: "array", dict: "object"}
    return "null" if value is None else names.get(type(value), type(value).__name__)


def _seen(value: object) -> str:
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_INT:
        return f"integer of about {int(value.bit_length() * 0.30103) + 1} digits"  # not its 400 digits
    text = json.dumps(value)
    return f"{_json_type(value)} {text if len(text) <= 40 else text[:37] + '...'}"


@dataclasses.dataclass(frozen=True)
class _Param:
    name: str
    hint: object  # a type, a union of types, or None when not checkable
    required: bool

    def describe(self) -> str:
        return f"{self.name}: {_hint_name(self.hint)}" if self.hint is not None else self.name


def _hint_name(hint: object) -> str:
    if isinstance(hint, type):
        return hint.__name__
    return str(hint).replace("typing.", "")


def _plain_types(hint: object) -> tuple[type, ...] | None:
    """The checkable base types of a hint (``float | None`` → (float, NoneType)), or None."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        parts = [_plain_types(a) for a in typing.get_args(hint)]
        if any(p is None for p in parts):
            return None
        return tuple(t for p in parts if p is not None for t in p)
    if hint is type(None):
        return (type(None),)
    base = origin if origin is not None else hint
    return (base,) if base in _KINDS else None


class Signature:
    """What a method accepts, read once from its signature and type hints."""

    def __init__(self, name: str, fn: Method) -> None:
        self.name = name
        sig = inspect.signature(fn)
        try:
            hints = typing.get_type_hints(fn)
        except Exception:  # unresolvable annotations: check arity only
            hints = {}
        self.params: list[_Param] = []
        self.var_kw = False
        for p in sig.parameters.values():
            if p.kind in (p.VAR_POSITIONAL, p.POSITIONAL_ONLY):
                raise ValueError(
                    f"method {name!r}: parameter {p.name!r} cannot be given by name; use plain parameters"
                )
            if p.kind is p.VAR_KEYWORD:
                self.var_kw = True
            else:
                types_ = _plain_types(hints.get(p.name))
                self.params.append(
                    _Param(p.name, hints.get(p.name) if types_ else None, p.default is p.empty)
                )

    def expected(self) -> str:
        return ", ".join(p.describe() for p in self.params) or "no parameters"

    def bind(self, params: object) -> dict[str, Any]:
        """Keyword arguments for the method, or RpcError(INVALID_PARAMS) naming the bad parameter."""
        by_name = {p.name: p for p in self.params}
        if params is None:
            given: dict[str, Any] = {}
        elif isinstance(params, list):
            if len(params) > len(self.params):
                raise self._error(
                    f"takes {len(self.params)} parameter(s) ({self.expected()}), got {len(params)}"
                )
            given = {p.name: v for p, v in zip(self.params, params, strict=False)}
        else:
            assert isinstance(params, dict)
            given = dict(params)
            unknown = [k for k in given if k not in by_name]
            if unknown and not self.var_kw:
                raise self._error(f"unknown parameter {unknown[0]!r}; expected {self.expected()}")
        for p in self.params:
            if p.name not in given:
                if p.required:
                    raise self._error(f"missing parameter {p.describe()}")
                continue
            given[p.name] = self._check(p, given[p.name])
        return given

    def _check(self, p: _Param, value: object) -> object:
        allowed = _plain_types(p.hint) if p.hint is not None else None
        if allowed is None:
            return value
        ok = any(
            isinstance(value, _KINDS[t][1]) and not (isinstance(value, bool) and t is not bool)
            if t in _KINDS
            else isinstance(value, t)
            for t in allowed
        )
        if not ok:
            want = " or ".join("null" if t is type(None) else _KINDS[t][0] for t in allowed)
            raise self._error(
                f"parameter {p.name!r} must be {want} ({_hint_name(p.hint)}), got {_seen(value)}"
            )
        problem = _number_problem(value, allowed)
        if problem is not None:
            raise self._error(f"parameter {p.name!r} {problem}, got {_seen(value)}")
        if float in allowed and int not in allowed and type(value) is int:
            return float(value)
        return value

    def _error(self, text: str) -> RpcError:
        return RpcError(INVALID_PARAMS, f"{self.name}: {text}")


class MethodTable:
    """Methods by name, each with its `Signature`; binds a request's params to one of them.

    ``also_offered`` names methods served elsewhere (the server's built-ins), listed when a
    method is not found.
    """

    def __init__(self, methods: Mapping[str, Method], *, also_offered: Collection[str] = ()) -> None:
        self._methods = dict(methods)
        self._sigs = {name: Signature(name, fn) for name, fn in methods.items()}
        self._also_offered = tuple(also_offered)

    def bind(self, method: str, params: object) -> tuple[Method, dict[str, Any]]:
        """The method and its keyword arguments; RpcError if unknown or the params do not fit."""
        fn = self._methods.get(method)
        if fn is None:
            offered = sorted([*self._methods, *self._also_offered])
            raise RpcError(
                METHOD_NOT_FOUND, f"unknown method {method!r}; tvsd offers: {', '.join(offered)}", offered
            )
        return fn, self._sigs[method].bind(params)


# --- requests ------------------------------------------------------------------------------------


class Request(NamedTuple):
    method: str
    params: object  # a list, a dict or None (absent)
    id: object
    notify: bool  # no "id": no reply, not even an error (unless the request is invalid)


def _refuse_constant(name: str) -> object:
    raise ValueError(f"{name} is not JSON")


def decode(line: bytes) -> object:
    """One line's JSON (NaN/Infinity refused), or RpcError(PARSE_ERROR)."""
    try:
        return json.loads(line, parse_constant=_refuse_constant)
    except (ValueError, RecursionError) as exc:
        text = f"not JSON ({exc}); send one JSON-RPC 2.0 object per line"
        raise RpcError(PARSE_ERROR, text) from exc


def valid_id(req: Mapping[str, object]) -> object:
    """The request's id if it is one a reply can carry (a string, or a finite number), else None."""
    rid = req.get("id")
    if isinstance(rid, bool) or not isinstance(rid, (str, int, float)):
        return None
    if isinstance(rid, float) and not math.isfinite(rid):
        return None  # 1e999 parses to infinity, which no JSON reply can hold
    if isinstance(rid, int) and abs(rid) > MAX_INT:
        return None
    if isinstance(rid, str) and len(rid) > MAX_ID_CHARS:
        return None
    return rid


def parse_request(msg: object) -> Request:
    """The request in a decoded message, or RpcError(INVALID_REQUEST) saying what is wrong."""

    def bad(text: str) -> RpcError:
        return RpcError(INVALID_REQUEST, f"not a JSON-RPC 2.0 request: {text}")

    if not isinstance(msg, dict):
        raise bad(f"expected an object, got {_seen(msg)}")
    if msg.get("jsonrpc") != "2.0":
        raise bad(f'"jsonrpc" must be "2.0", got {_seen(msg.get("jsonrpc"))}')
    method = msg.get("method")
    if not isinstance(method, str):
        raise bad(f'"method" must be a string, got {_seen(method)}')
    params = msg.get("params")
    if "params" in msg and not isinstance(params, (list, dict)):
        raise bad(f'"params" must be an array or an object, got {_seen(params)}')
    if "id" in msg and msg["id"] is not None and valid_id(msg) is None:
        raise bad(
            f'"id" must be a string (at most {MAX_ID_CHARS} characters), a finite number within '
            f"±2**53 or null, got {_seen(msg['id'])}"
        )
    return Request(method, params, msg.get("id"), "id" not in msg)


# --- replies -------------------------------------------------------------------------------------


class Encoded:
    """A result checked and encoded once, answered as it is: `dumps` splices its text into each
    reply. For what many requests share (the status: 350 calls/s in the soak, one build per 20 ms),
    `clean` and the JSON encoder then run once per build instead of once per reply (they held the
    event loop ~0.3 ms a reply, ~13 % of it in the soak)."""

    __slots__ = ("text",)

    def __init__(self, obj: object) -> None:
        self.text: bytes = _compact(clean(obj))

    def decoded(self) -> Any:
        """The value again (tests, in-process callers)."""
        return json.loads(self.text)


def clean(obj: Any) -> Any:
    """Something json.dumps can write: non-finite floats → null, dataclasses, numpy scalars/arrays."""
    if isinstance(obj, Encoded):
        return obj  # checked when it was made
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (str, int, bool)) or obj is None:
        return obj
    if isinstance(obj, Mapping):
        return {str(k): clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean(v) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return clean(dataclasses.asdict(obj))
    if hasattr(obj, "tolist"):  # numpy scalars and arrays
        return clean(obj.tolist())
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _compact(obj: object) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()


def _spliced(reply: object) -> bool:
    return isinstance(reply, dict) and isinstance(reply.get("result"), Encoded)


def _encode(obj: object) -> bytes:
    """Compact JSON with any `Encoded` result of a reply (or of a batch's replies) spliced in."""
    if isinstance(obj, Encoded):
        return obj.text
    if _spliced(obj):
        assert isinstance(obj, dict)
        head = _compact({k: v for k, v in obj.items() if k != "result"})
        return head[:-1] + (b"," if len(head) > 2 else b"") + b'"result":' + obj["result"].text + b"}"
    if isinstance(obj, list) and any(_spliced(r) for r in obj):
        return b"[" + b",".join(_encode(r) for r in obj) + b"]"
    return _compact(obj)


def dumps(obj: object) -> bytes:
    """One line of compact JSON (NaN refused: `clean` first; `Encoded` results spliced in)."""
    return _encode(obj) + b"\n"


def result_reply(req_id: object, result: object) -> dict[str, object]:
    return {"jsonrpc": "2.0", "id": req_id, "result": result}


def error_reply(req_id: object, err: RpcError) -> dict[str, object]:
    return {"jsonrpc": "2.0", "id": req_id, "error": err.to_json()}


def reply_to_error(msg: object, err: RpcError) -> dict[str, object] | None:
    """The error reply to a decoded message, or None for a notification (no "id") unless the
    message is not a valid request at all."""
    if isinstance(msg, dict) and "id" not in msg and err.code != INVALID_REQUEST:
        return None
    return error_reply(valid_id(msg) if isinstance(msg, dict) else None, err)
