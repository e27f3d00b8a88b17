"""`tvsd`: the scanner daemon's entry point.

The asyncio daemon (control thread, JSON-RPC socket, recorder, systemd notify) is issue 6. Until it
lands, `tvsd --check` validates a config and prints the gain conditions, which is what an operator
needs before starting the scanner; without --check it says plainly that the daemon is not built yet.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from tvsd import __version__
from tvsd.errors import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, TvsdError


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tvsd", description="TVS scanner daemon")
    parser.add_argument("--version", action="version", version=f"tvsd {__version__}")
    parser.add_argument("--config", type=Path, help="scanner config (default: config/tvsd.yaml)")
    parser.add_argument("--check", action="store_true", help="validate the config and exit")
    args = parser.parse_args(argv)
    from tvsd.config import load_config
    from tvsd.control.conditions import check_gains

    try:
        cfg = load_config(args.config) if args.config else load_config()
    except TvsdError as exc:
        print(f"tvsd: {exc}", file=sys.stderr)
        return EXIT_USAGE
    conds = check_gains(cfg.control.gains, cfg.plant, cfg.control.disturbance_bound_rad_s2)
    for c in conds:
        print(f"gain condition {c.name} {'holds' if c.holds else 'DOES NOT hold'}: {c.text}")
    if args.check:
        print(f"config ok: plant '{cfg.plant.name}', loop {cfg.control.rate_hz:g} Hz")
        return EXIT_OK
    print(
        "tvsd: the daemon itself is not built yet (issue 6); use `tvsctl sim` for the simulator",
        file=sys.stderr,
    )
    return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
