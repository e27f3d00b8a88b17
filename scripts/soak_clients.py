"""API load for scripts/soak.sh: N clients polling `status` back to back over the daemon's socket,
plus one oversized batch (500 calls in one line) every few seconds, for a given time.

usage: python scripts/soak_clients.py SOCKET SECONDS [CLIENTS]
Prints one JSON line: replies received, errors, oversized batches sent and how they were answered.
"""

from __future__ import annotations

import json
import socket
import sys
import threading
import time


def main() -> int:
    sock, seconds = sys.argv[1], float(sys.argv[2])
    clients = int(sys.argv[3]) if len(sys.argv) > 3 else 50
    stop = time.monotonic() + seconds
    counts = {"replies": 0, "errors": 0, "batches": 0, "batch_codes": []}
    lock = threading.Lock()

    def poll() -> None:
        while time.monotonic() < stop:
            try:
                with socket.socket(socket.AF_UNIX) as s:
                    s.settimeout(10)
                    s.connect(sock)
                    f = s.makefile("rwb")
                    while time.monotonic() < stop:
                        f.write(b'{"jsonrpc":"2.0","id":1,"method":"status"}\n')
                        f.flush()
                        reply = json.loads(f.readline())
                        with lock:
                            counts["replies" if "result" in reply else "errors"] += 1
            except (OSError, ValueError):
                time.sleep(0.1)  # refused (client limit) or the daemon went away: try again

    def oversized() -> None:
        line = json.dumps([{"jsonrpc": "2.0", "id": i, "method": "status"} for i in range(500)]).encode()
        while time.monotonic() < stop:
            try:
                with socket.socket(socket.AF_UNIX) as s:
                    s.settimeout(10)
                    s.connect(sock)
                    f = s.makefile("rwb")
                    f.write(line + b"\n")
                    f.flush()
                    reply = json.loads(f.readline())
                    code = reply.get("error", {}).get("code") if isinstance(reply, dict) else "batch"
                    with lock:
                        counts["batches"] += 1
                        counts["batch_codes"].append(code)
            except (OSError, ValueError):
                pass
            time.sleep(3.0)

    threads = [threading.Thread(target=poll) for _ in range(clients)] + [threading.Thread(target=oversized)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    counts["batch_codes"] = sorted(set(map(str, counts["batch_codes"])))
    print(json.dumps(counts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
