"""A whole recording as MCAP with a JSON schema per channel, so Foxglove and the robotics log tools
(mcap CLI, rosbags-style readers) open it.

Each channel of the recording becomes topic `/tvsd/<channel>` (JSON messages, one per row, with a
JSON Schema naming its fields, units where known); the marks (state changes, faults, gains) become
`/tvsd/marks`. Times: a mark carries the wall clock (`t_unix`), exact. A channel's rows carry their
own clock (the loop's seconds since it started, the host's monotonic clock for points and pulses);
they are placed on the wall clock at the recording's start (`started_unix`), channel by channel, and
the row's own time is kept in the message. So within a channel times are exact; between channels
they agree to the start-up offset of their clocks (ms).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.errors import UsageError

TIME_FIELDS = ("t", "t_mono", "t_host")  # a channel's own clock, in this order of preference
UNITS = {"t": "s", "t_mono": "s", "t_host": "s", "u": "V", "omega": "rad/s", "phi": "rad",
         "omega_ref": "rad/s", "phi_ref": "rad", "u_ff": "V", "x": "m", "y": "m", "z": "m",
         "sigma_x": "m", "sigma_y": "m", "sigma_z": "m", "beta": "rad", "late_us": "µs", "dt": "s",
         "ax": "m/s²", "ay": "m/s²", "az": "m/s²", "gx": "rad/s", "gy": "rad/s", "gz": "rad/s"}  # fmt: skip


def json_schema(name: str, dtype: np.dtype[Any]) -> dict[str, Any]:
    """A JSON Schema for one row of a structured dtype (numbers and integers, units described)."""
    props: dict[str, Any] = {}
    for field in dtype.names or ():
        sub = dtype[field]
        kind = "integer" if sub.kind in "iub" else "number"
        prop: dict[str, Any] = {"type": kind}
        if sub.shape:
            prop = {"type": "array", "items": {"type": kind}}
        if field in UNITS:
            prop["description"] = UNITS[field]
        props[field] = prop
    return {"title": f"tvsd.{name}", "type": "object", "properties": props, "required": list(props)}


def _rows_json(rows: np.ndarray) -> Iterable[dict[str, Any]]:
    names = rows.dtype.names or ()
    cols = {n: rows[n].tolist() for n in names}
    for i in range(len(rows)):
        yield {n: _finite(cols[n][i]) for n in names}


def _finite(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None  # JSON has no NaN
    if isinstance(v, list):
        return [_finite(x) for x in v]
    return v


def write_mcap(
    path: Path,
    channels: Mapping[str, np.ndarray],
    marks: list[dict[str, Any]],
    started_unix: float,
    metadata: Mapping[str, str],
    progress: Callable[[int], None] | None = None,
) -> dict[str, int]:
    """Write the MCAP file; returns messages per topic. `progress(n)` is told of every n rows."""
    from mcap.writer import CompressionType, Writer

    counts: dict[str, int] = {}
    try:
        stream = path.open("wb")
    except OSError as exc:
        raise UsageError(f"{path}: cannot write the MCAP file: {exc.strerror}") from exc
    with stream:
        w = Writer(stream, compression=CompressionType.ZSTD)
        w.start(profile="", library="tvsd")
        w.add_metadata("tvsd", {str(k): str(v) for k, v in metadata.items()})
        for name, rows in channels.items():
            if not rows.dtype.names or len(rows) == 0:
                continue
            schema = w.register_schema(
                f"tvsd.{name}", "jsonschema", json.dumps(json_schema(name, rows.dtype)).encode()
            )
            topic = f"/tvsd/{name}"
            cid = w.register_channel(topic, "json", schema)
            tf = next((f for f in TIME_FIELDS if f in rows.dtype.names), None)
            t = rows[tf].astype(float) if tf else np.arange(len(rows), dtype=float) * 1e-3
            # integer ns from the start: (started_unix + dt)·1e9 in float64 would lose ~100 ns
            t_ns = round(started_unix * 1e9) + np.round((t - t[0]) * 1e9).astype(np.int64)
            for seq, (ns, row) in enumerate(zip(t_ns.tolist(), _rows_json(rows), strict=True)):
                w.add_message(cid, log_time=ns, data=json.dumps(row).encode(), publish_time=ns, sequence=seq)
                if progress is not None and seq % 10_000 == 9_999:
                    progress(10_000)
            if progress is not None:
                progress(len(rows) % 10_000)
            counts[topic] = len(rows)
        if marks:
            schema = w.register_schema(
                "tvsd.mark",
                "jsonschema",
                json.dumps(
                    {
                        "title": "tvsd.mark",
                        "type": "object",
                        "properties": {
                            "t_unix": {"type": "number", "description": "s, wall clock"},
                            "event": {"type": "string"},
                        },
                        "required": ["t_unix", "event"],
                    }
                ).encode(),
            )
            cid = w.register_channel("/tvsd/marks", "json", schema)
            for seq, m in enumerate(sorted(marks, key=lambda m: float(m.get("t_unix", 0.0)))):
                ns = round(float(m.get("t_unix", started_unix)) * 1e9)
                w.add_message(
                    cid, log_time=ns, data=json.dumps(m, default=str).encode(), publish_time=ns, sequence=seq
                )
            counts["/tvsd/marks"] = len(marks)
        w.finish()
    return counts
