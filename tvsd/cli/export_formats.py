"""`tvsctl export --format parquet | mcap`: hands the reader's data to the writers of
tvsd.recording.parquet_out / mcap_out (pyarrow, mcap: imported only for these formats)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tvsd.errors import EXIT_OK
from tvsd.recording.reader import RecordingFile
from tvsd.recording.table import Table


def export_parquet(out: Path, table: Table, meta: dict[str, object]) -> None:
    """The recording CSV's table and metadata, as Parquet."""
    from tvsd.recording.parquet_out import write_parquet

    columns = {"t": table.t, **{k: np.asarray(v) for k, v in table.columns.items()}}
    write_parquet(out, columns, {"sample_rate_hz": f"{table.rate_hz:g}", **meta})


def export_mcap(rec: RecordingFile, src: Path, out: Path) -> int:
    from tvsd.cli.progress import progress_bar
    from tvsd.recording.mcap_out import write_mcap

    total = sum(len(v) for v in rec.channels.values())
    started = float(rec.header.get("started_unix", 0.0))
    meta = {"recording": str(src.resolve()), "started_utc": str(rec.header.get("started_utc", "unknown"))}
    with progress_bar(f"writing {out.name}", total) as advance:
        counts = write_mcap(out, rec.channels, rec.marks, started, meta, progress=advance)
    topics = ", ".join(f"{k} {v}" for k, v in counts.items()) or "nothing"
    print(f"{out}: MCAP, {topics} messages from {src}")
    return EXIT_OK
