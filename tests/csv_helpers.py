"""Small recording CSVs for tests of the header lines (tvsd.recording.csvfile)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def square_wave_csv(path: Path, meta: str) -> None:
    """3 s at 1 kHz of a ±5 V square wave (1 Hz) and its running integral as the speed, with one
    extra header line `meta`: enough rows for the reader and the doctor's own checks."""
    t = np.arange(3000) / 1000
    u = np.where((t % 1) < 0.5, 5.0, -5.0)
    lines = ["# tvs-recording: 1", "# sample_rate_hz: 1000", meta, "t,u,omega"]
    lines += [
        f"{a:.4f},{b!r},{c!r}"
        for a, b, c in zip(map(float, t), map(float, u), map(float, np.cumsum(u) / 1000), strict=True)
    ]
    path.write_text("\n".join(lines) + "\n")
