"""A recording's `# encoder_counts_per_rev:` is validated when read (one line, exit 2)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

TVSCTL = str(Path(sys.executable).parent / "tvsctl")


def test_bad_counts_header_is_one_line(tmp_path: Path) -> None:
    """A count that is not a whole number ≥ 4: one line naming file, row and value, exit 2."""
    path = tmp_path / "bad.csv"
    rows = "\n".join(f"{k / 1000:.3f},0.1,1.0,{k / 1000:.4f}" for k in range(50))
    path.write_text(
        "# tvs-recording: 1\n# sample_rate_hz: 1000\n# encoder_counts_per_rev: 25.5\nt,u,omega,phi\n"
        + rows
        + "\n"
    )
    p = subprocess.run([TVSCTL, "analyze", str(path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0
    assert "row 3" in p.stderr and "25.5" in p.stderr and "Traceback" not in p.stderr
