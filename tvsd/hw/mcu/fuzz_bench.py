"""`tvsctl bench --only fuzz`: the protocol fuzz as bench figures, per decoder.

The host side is :func:`tvsd.hw.mcu.fuzz.fuzz_decoder` (needs only the spec the wheel ships). The
firmware side is the C harness (firmware/tests/fuzz.c through core/frame.c), which is built from
a source checkout's firmware/ tree: there it is built with ``make`` and run; from an installed
wheel it is reported as not run (``make -C firmware fuzz`` in a checkout runs both).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

from tvsd.hw.mcu.fuzz import fuzz_decoder

FIRMWARE_DIR = Path(__file__).resolve().parents[3] / "firmware"
FUZZ_BIN = "build/fuzz_frames"  # the Makefile's $(FUZZ_BIN)

# CRC-32 lets other damage through with probability 2^-32 per candidate window, about 2 windows
# per damaged frame (firmware/PROTOCOL.md, "Integrity"): the expected false-accept rate.
THEORETICAL_PER_DAMAGED_FRAME = 2 * 2.0**-32


def _c_side(frames: int, seed: int) -> dict[str, Any]:
    """Build and run the C harness; the reason instead when there is no checkout or compiler."""
    if not (FIRMWARE_DIR / "Makefile").is_file():
        return {"fuzz_c": "not run: needs a source checkout's firmware/ (make -C firmware fuzz)"}
    if shutil.which("make") is None or shutil.which("cc") is None:
        return {"fuzz_c": "not run: needs make and a C compiler (make -C firmware fuzz)"}
    built = subprocess.run(
        ["make", "-s", "-C", str(FIRMWARE_DIR), FUZZ_BIN], capture_output=True, text=True, check=False
    )
    if built.returncode != 0:
        last = (built.stderr.strip().splitlines() or ["?"])[-1]
        return {"fuzz_c": f"not run: make -C firmware {FUZZ_BIN} failed: {last}"}
    t0 = time.perf_counter()
    ran = subprocess.run(
        [str(FIRMWARE_DIR / FUZZ_BIN), str(frames), str(seed)], capture_output=True, text=True, check=False
    )
    wall = time.perf_counter() - t0
    m = re.search(r"FALSE ACCEPTS (\d+), duplicates executed (\d+)", ran.stdout)
    if m is None:  # the harness exits 1 on a false accept, so the status alone says little
        return {"fuzz_c": f"not run: unexpected output from {FUZZ_BIN} (status {ran.returncode})"}
    return {
        "fuzz_c_false_accepts": int(m.group(1)),
        "fuzz_c_duplicates_executed": int(m.group(2)),
        "fuzz_c_wall_s": round(wall, 2),
    }


def bench_fuzz(frames: int = 1_000_000, seed: int = 1) -> dict[str, Any]:
    """``frames`` damaged frames through each decoder (about as many intact ones between them)."""
    out: dict[str, Any] = {
        "fuzz_damaged_frames_per_side": frames,
        "fuzz_seed": seed,
        "fuzz_theoretical_false_accepts_per_damaged_frame": f"{THEORETICAL_PER_DAMAGED_FRAME:.1e}",
        "fuzz_expected_false_accepts_per_side": f"{frames * THEORETICAL_PER_DAMAGED_FRAME:.1e}",
    }
    out.update(_c_side(frames, seed))
    t0 = time.perf_counter()
    py = fuzz_decoder(frames, seed)
    out["fuzz_py_false_accepts"] = py.false_accepts
    out["fuzz_py_duplicates_executed"] = py.duplicates_run
    out["fuzz_py_wall_s"] = round(time.perf_counter() - t0, 2)
    return out
