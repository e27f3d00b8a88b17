"""A recording's table as Apache Parquet (pandas, polars, DuckDB, Spark read it directly).

The columns are the recording CSV's (t, u, omega, phi and the extra columns, float64, SI units);
the CSV's `# key: value` metadata lines become the file's key-value metadata (bytes), under the
same keys, with `tvs-recording` naming the contract version.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from tvsd.errors import UsageError


def write_parquet(path: Path, columns: Mapping[str, np.ndarray], meta: Mapping[str, object]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table({name: pa.array(np.asarray(v)) for name, v in columns.items()})
    kv = {"tvs-recording": "1", **{str(k): str(v) for k, v in meta.items()}}
    table = table.replace_schema_metadata({k.encode(): v.encode() for k, v in kv.items()})
    try:
        pq.write_table(table, path, compression="zstd")
    except OSError as exc:
        raise UsageError(f"{path}: cannot write the Parquet file: {exc}") from exc
