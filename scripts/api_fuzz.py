"""Bad input to a running daemon's JSON-RPC socket, as a stranger would send it.

    python scripts/api_fuzz.py --socket PATH [--json]

Each case sends one line (or a few) on a fresh connection and reads the reply. A case fails when the
reply is not one JSON line within the timeout, when it is an internal error (-32603), or when its
error code is not the one the case expects (docs/architecture.md, "Daemon API"). The daemon must
still answer `status` after every case. Exit 0 when every case passes, 1 otherwise.

Cases that change the daemon's state (speed, aim, gains, record, calibrate) are sent only with
values it must refuse, except the record start/stop/start race (issue 13), which leaves no
recording running. Run it against a SIL daemon (`tvsd --sil`), never the scanner. A bad parameter
is -32602 whatever the daemon's state: the same cases pass against a daemon with `devices.imu: off`.
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import time
from dataclasses import dataclass

BIG = "9" * 400  # a 400-digit integer (issue 13)


@dataclass
class Case:
    name: str
    lines: list[bytes]
    expect: set[int | None]  # error codes accepted (None: a result)


def _req(method: str, params: object = None, rid: object = 1) -> bytes:
    msg: dict[str, object] = {"jsonrpc": "2.0", "id": rid, "method": method}
    if params is not None:
        msg["params"] = params
    return json.dumps(msg).encode()


def _raw(text: str) -> bytes:
    return text.encode()


def _params(method: str, params_text: str, rid: str = "1") -> bytes:
    """A request whose params (and id) are JSON text as written, not as json.dumps would write it."""
    return _raw(f'{{"jsonrpc":"2.0","id":{rid},"method":"{method}","params":{params_text}}}')


def _batch(n: int) -> bytes:
    return _raw("[" + ",".join(_req("status", rid=i).decode() for i in range(n)) + "]")


P = -32602  # INVALID_PARAMS
R = -32600  # INVALID_REQUEST
J = -32700  # PARSE_ERROR
L = -32003  # LIMIT_ERROR
S = -32002  # STATE_ERROR


def cases() -> list[Case]:
    out = [
        Case("speed 400-digit int", [_params("speed", f'{{"rps":{BIG}}}')], {P}),
        Case("speed -400-digit int", [_params("speed", f"[-{BIG}]")], {P}),
        Case("aim 400-digit int", [_params("aim", f'{{"phi_deg":{BIG},"gamma_deg":0}}')], {P}),
        Case("aim_xyz 1e400", [_params("aim_xyz", '{"x":1e400,"y":0,"z":0}')], {P, J}),
        Case("gains_set 400-digit int", [_params("gains_set", f"[{BIG},1,1,1]")], {P}),
        Case("record_window 400-digit", [_params("record_window", f'{{"seconds":{BIG}}}')], {P}),
        Case("id 1e999", [_raw('{"jsonrpc":"2.0","id":1e999,"method":"status"}')], {R, J}),
        Case("id NaN", [_raw('{"jsonrpc":"2.0","id":NaN,"method":"status"}')], {J}),
        Case("id 400-digit", [_raw(f'{{"jsonrpc":"2.0","id":{BIG},"method":"status"}}')], {R}),
        Case("id object", [_req("status", rid={"a": 1})], {R}),
        Case("id 10k string", [_req("status", rid="x" * 10000)], {R}),
        Case("params NaN", [_params("speed", '{"rps":NaN}')], {J}),
        Case("params Infinity", [_params("speed", '{"rps":-Infinity}')], {J}),
        Case("speed string", [_req("speed", {"rps": "25"})], {P}),
        Case("speed bool", [_req("speed", {"rps": True})], {P}),
        Case("speed null", [_req("speed", {"rps": None})], {P}),
        Case("speed list", [_req("speed", {"rps": [25]})], {P}),
        Case("speed out of range", [_req("speed", {"rps": 1e6})], {P}),
        Case("speed missing", [_req("speed", {})], {P}),
        Case("speed extra", [_req("speed", {"rps": 0, "x": 1})], {P}),
        Case("params string", [_req("speed", "25")], {R, P}),
        Case("params number", [_req("speed", 25)], {R, P}),
        Case("params 5 positional", [_req("aim", [1, 2, 3, 4, 5])], {P}),
        Case("aim NaN-free but unreachable", [_req("aim", {"phi_deg": 1e300, "gamma_deg": 0})], {P}),
        Case("gains negative", [_req("gains_set", [-1, -1, -1, -1])], {P}),
        # -32602 in every state: with no IMU (devices.imu: off) or the aperture turning too
        Case("imu_calibrate negative", [_req("imu_calibrate", {"seconds": -1})], {P}),
        Case("imu_calibrate 1e300", [_req("imu_calibrate", {"seconds": 1e300})], {P}),
        Case("imu_calibrate 0.5 s", [_req("imu_calibrate", {"seconds": 0.5})], {P}),
        Case("imu_calibrate 400-digit", [_params("imu_calibrate", f'{{"seconds":{BIG}}}')], {P}),
        Case("record_window negative", [_req("record_window", {"seconds": -1})], {P, S}),
        Case("record_window 0", [_req("record_window", {"seconds": 0})], {P, S}),
        Case("identify negative seconds", [_req("identify", {"seconds": -5})], {P, S}),
        Case("identify bad kinds", [_req("identify", {"kinds": ["nope"]})], {P, S}),
        Case("identify kinds string", [_req("identify", {"kinds": "steps"})], {P, S}),
        Case("identify kinds nested", [_req("identify", {"kinds": [["steps"]]})], {P, S}),
        Case("identify seed negative", [_req("identify", {"seed": -1})], {P, S}),
        Case("identify seed float", [_req("identify", {"seed": 1.5})], {P, S}),
        Case("inject unknown device", [_req("inject_fault", {"device": "toaster", "fault": "x"})], {P}),
        Case("inject unicode", [_req("inject_fault", {"device": "mcu\u0000", "fault": "ℓink_loss"})], {P}),
        Case("subscribe unknown topic", [_req("subscribe", {"topic": "x" * 5000})], {P}),
        Case("method unicode", [_req("stätus\u202e")], {-32601}),
        Case("method dunder", [_req("__init__")], {-32601}),
        Case("method number", [_raw('{"jsonrpc":"2.0","id":1,"method":5}')], {R}),
        Case("jsonrpc 1.0", [_raw('{"jsonrpc":"1.0","id":1,"method":"status"}')], {R}),
        Case("not an object", [_raw("42")], {R}),
        Case("invalid UTF-8", [b'{"jsonrpc":"2.0","id":1,"method":"st\xff\xfeus"}'], {J}),
        Case("deep nesting", [_params("speed", "[" * 20000 + "]" * 20000)], {J, P, R}),
        Case("empty batch", [_raw("[]")], {R}),
        Case("batch of 300", [_batch(300)], {L}),
        Case("batch of 500", [_batch(500)], {L}),
        Case("batch of junk", [_raw("[1,2,3]")], {R}),
        Case("too long a line", [_params("status", '{"x":"' + "y" * 70000 + '"}')], {R}),
    ]
    return out


def _exchange(path: str, lines: list[bytes], timeout: float) -> tuple[list[object], float]:
    t0 = time.monotonic()
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout)
        s.connect(path)
        replies: list[object] = []
        buf = b""
        for line in lines:
            s.sendall(line + b"\n")
            while b"\n" not in buf:
                chunk = s.recv(1 << 20)
                if not chunk:
                    raise ConnectionError("the daemon closed the connection with no reply")
                buf += chunk
            head, buf = buf.split(b"\n", 1)
            replies.append(json.loads(head))
    return replies, time.monotonic() - t0


def _codes(reply: object) -> list[int | None]:
    items = reply if isinstance(reply, list) else [reply]
    return [it["error"].get("code") if isinstance(it, dict) and "error" in it else None for it in items]


def run_case(path: str, case: Case, timeout: float) -> dict[str, object]:
    try:
        replies, dt = _exchange(path, case.lines, timeout)
    except (OSError, ValueError, ConnectionError) as exc:
        return {"case": case.name, "ok": False, "why": f"{type(exc).__name__}: {exc}"}
    codes = [c for r in replies for c in _codes(r)]
    first = replies[0]
    msg = first.get("error", {}).get("message", "") if isinstance(first, dict) else ""
    ok = all(c in case.expect for c in codes) and -32603 not in codes
    return {"case": case.name, "ok": ok, "codes": codes[:3], "ms": round(dt * 1e3, 1), "message": msg[:160]}


def record_race(path: str, timeout: float) -> dict[str, object]:
    """record start / stop / start / stop within a second (issue 13: an internal error leaked)."""
    lines = [_req(m, rid=i) for i, m in enumerate(["record_start", "record_stop"] * 2)]
    try:
        replies, dt = _exchange(path, lines, timeout)
    except (OSError, ValueError, ConnectionError) as exc:
        return {"case": "record start/stop/start/stop", "ok": False, "why": str(exc)}
    codes = [c for r in replies for c in _codes(r)]
    results = [r.get("result") if isinstance(r, dict) else None for r in replies]
    names = [r.get("recording") if isinstance(r, dict) else None for r in results]
    ok = codes == [None] * 4 and dt < 5 and names[0] != names[2]
    ms = round(dt * 1e3, 1)
    return {"case": "record start/stop/start/stop", "ok": ok, "codes": codes, "ms": ms, "message": str(names)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--socket", required=True)
    ap.add_argument("--timeout", type=float, default=10.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for case in cases():
        rows.append(run_case(args.socket, case, args.timeout))
        alive = run_case(args.socket, Case("status after", [_req("status")], {None}), args.timeout)
        if not alive["ok"]:
            rows.append({**alive, "case": f"status after {case.name!r}"})
    rows.append(record_race(args.socket, args.timeout))
    for row in rows:
        if args.json:
            print(json.dumps(row))
        else:
            mark = "ok  " if row["ok"] else "FAIL"
            said = row.get("message") or row.get("why", "")
            print(f"{mark} {row['case']:<34} {row.get('codes', '')!s:<18} {row.get('ms', '')!s:>7} {said}")
    bad = sum(not r["ok"] for r in rows)
    print(f"{len(rows) - bad} of {len(rows)} cases passed", file=sys.stderr)
    return 0 if bad == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
