"""A child's memory over time, sampled from the parent every ~1 ms (memflake.md, table 1).

    python scripts/memflake_traj.py OUT.jsonl PY -m tvsd.cli.main analyze REC --json --quiet

prints the peaks of RssAnon, RssFile and the final VmHWM (MiB); OUT.jsonl gets every sample.
"""

import json
import subprocess
import sys
import time

KEYS = ("VmRSS", "VmHWM", "RssAnon", "RssFile")


def status(pid: int) -> dict[str, float]:
    out: dict[str, float] = {}
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key in KEYS:
                    out[key] = int(value.split()[0]) / 1024
    except OSError:
        pass
    return out


def main() -> None:
    out_path, cmd = sys.argv[1], sys.argv[2:]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
    rows = []
    while proc.poll() is None:
        if s := status(proc.pid):
            rows.append((round(time.perf_counter() - t0, 3), s))
        time.sleep(0.001)
    with open(out_path, "w") as f:
        for row in rows:
            f.write(json.dumps(row) + "\n")
    peak = {k: round(max(r[1].get(k, 0.0) for r in rows), 1) for k in ("RssAnon", "RssFile")}
    print(
        json.dumps(
            {
                "samples": len(rows),
                "peak_anon": peak["RssAnon"],
                "peak_file": peak["RssFile"],
                "hwm": round(rows[-1][1].get("VmHWM", 0.0), 1),
            }
        )
    )


if __name__ == "__main__":
    main()
