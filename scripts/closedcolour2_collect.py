"""SIL daemon identify null runs (white `sde` plant, nothing hidden) for the closed-loop colour rule.

One daemon per batch (`--runs` identify runs of 20 s at 25 rev/s, as tests/test_identify_hidden.py
runs them, without the hidden effect), so a batch run under `flock /work/wt/soak.lock` holds the
lock ≈ 1 min per run and no longer. The recordings stay in OUT/bNN/data; their paths are appended to
OUT/runs.jsonl, and `tvsctl export` is run on them afterwards (outside the lock: it is no realtime
work). Run from the repository's root: it uses the tests' daemon helpers.

    flock /work/wt/soak.lock nice -n 0 .venv/bin/python scripts/closedcolour2_collect.py OUT BATCH --runs 2
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from conftest import RELAXED_FAILSAFE, daemon_config  # noqa: E402
from test_daemon import _daemon, spin_to, tvsctl, wait_status  # noqa: E402

RPS = 25.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("batch", type=int)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument(
        "--scan", type=float, metavar="S", help="instead: one recording of the spin-up and S s of scanning (make run's)"
    )
    a = ap.parse_args()
    where = a.out / f"b{a.batch:02d}"
    where.mkdir(parents=True, exist_ok=True)
    sil = (ROOT / "config" / "sil.yaml").read_text()
    assert "\neffects: []" in sil, "config/sil.yaml's effects line changed"
    (where / "sil.yaml").write_text(sil)  # white plant: nothing hidden
    changes = {
        **RELAXED_FAILSAFE,
        "  identify_timeout_ms: 500 ": "  identify_timeout_ms: 10000 ",
        "  abort_error_rps: 3.0 ": "  abort_error_rps: 10.0 ",
        "sil_profile: sil.yaml": f"sil_profile: {where / 'sil.yaml'}",
    }
    gen = _daemon(where, daemon_config(where, changes), realtime=True)
    _, sock, _ = next(gen)
    try:
        if a.scan is not None:
            scan(sock, a.out, a.batch, a.scan)
            return 0
        spin_to(sock, RPS, timeout=60)
        for k in range(a.runs):
            cmd = [sys.executable, "-m", "tvsd.cli.main", "identify", "--seconds", "20", "--json"]
            proc = subprocess.run(
                [*cmd, "--timeout", "120", "--socket", str(sock)], capture_output=True, text=True, timeout=150
            )
            run = json.loads(proc.stdout) if proc.stdout.strip() else {"refused": proc.stderr[-300:]}
            row = {"batch": a.batch, "k": k, "outcome": run.get("outcome"), "reason": run.get("reason"),
                   "recording": run.get("recording")}
            with (a.out / "runs.jsonl").open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps(row), flush=True)
            if k + 1 < a.runs:
                wait_status(sock, lambda s: abs(s["rps"] - RPS) < 0.5, 60, "25 again", fault_ends=True)
    finally:
        try:
            next(gen)
        except StopIteration:
            pass
    return 0


def scan(sock: Path, out: Path, batch: int, seconds: float) -> None:
    """A `make run` walk-through's recording: from standstill, spin-up to 25 rev/s, then scanning."""
    import time

    tvsctl(sock, "record", "start")
    spin_to(sock, RPS, timeout=60)
    tvsctl(sock, "scan", "start")
    time.sleep(seconds)
    stopped = tvsctl(sock, "record", "stop", "--json").stdout
    row = {"batch": batch, "k": 0, "outcome": "done", "scan_s": seconds, "stop": stopped[-300:]}
    with (out / "scans.jsonl").open("a") as f:
        f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    sys.exit(main())
