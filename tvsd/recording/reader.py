"""Reading a recording the daemon wrote: `open_recording` and what it returns, `RecordingFile`.

It owns getting the data back out of ``.tvsrec`` segments (format: `tvsd.recording.format`),
including damage: the reader checks every record's CRC; a damaged record is skipped by searching
for the next sync whose record checks out, and counted (``corrupt_records``); bytes after the last
good record of the last segment are a torn tail (``torn_tail_bytes``), reported, not raised.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.errors import DataFileError
from tvsd.recording.format import (
    CHANNEL,
    CONFIG,
    DATA,
    HEADER,
    MAGIC,
    MARK,
    SEGMENT_GLOB,
    STATS,
    SYNC,
    record_at,
)


@dataclass
class RecordingFile:
    """What open_recording() found: channels as structured arrays, and what was damaged."""

    path: Path
    segments: list[Path]
    config_text: str
    header: dict[str, Any]
    channels: dict[str, np.ndarray]
    marks: list[dict[str, Any]]
    stats: dict[str, Any] | None  # the last STATS record; stats["final"] only after close()
    corrupt_records: int = 0  # damaged regions skipped inside the recording
    corrupt_bytes: int = 0
    torn_tail_bytes: int = 0  # partial record at the very end (the writer was killed mid-write)
    problems: list[str] = field(default_factory=list)

    @property
    def closed_cleanly(self) -> bool:
        return bool(self.stats and self.stats.get("final"))


def open_recording(path: str | Path) -> RecordingFile:
    """Read a recording directory (or one segment file). Damage is counted, never raised."""
    path = Path(path)
    try:
        path.stat()
    except PermissionError:  # a parent this user may not search: is_dir() raises it
        raise DataFileError(
            f"{path}: cannot reach the recording: permission denied on a directory above it; "
            "run as a user who may read it"
        ) from None
    except OSError:
        pass  # is_dir()/is_file() below say no such recording
    if path.is_dir():
        if not os.access(path, os.R_OK | os.X_OK):  # glob() would see nothing and blame the files
            raise DataFileError(
                f"{path}: cannot read the recording: permission denied (the daemon makes them 0750); "
                "run as its user or a member of the directory's group"
            )
        segments = sorted(path.glob(SEGMENT_GLOB))
        if not segments:
            raise DataFileError(f"{path}: not a tvsd recording (no {SEGMENT_GLOB} segment files in it)")
    elif path.is_file():
        segments = [path]
    else:
        raise DataFileError(f"{path}: no such recording (expected a directory written by the recorder)")
    rec = RecordingFile(path, segments, "", {}, {}, [], None)
    parts: dict[str, list[np.ndarray]] = {}
    for k, seg in enumerate(segments):
        _read_segment(seg, rec, parts, last=k == len(segments) - 1)
    for name, chunks in parts.items():
        rec.channels[name] = np.concatenate(chunks) if len(chunks) > 1 else chunks[0]
    return rec


def _read_segment(seg: Path, rec: RecordingFile, parts: dict[str, list[np.ndarray]], last: bool) -> None:
    try:
        data = seg.read_bytes()
    except OSError as exc:
        raise DataFileError(f"{seg}: cannot read: {exc.strerror}") from exc
    if not data.startswith(MAGIC):
        raise DataFileError(f"{seg}: not a tvsd recording segment (does not start with {MAGIC!r})")
    dtypes: dict[int, tuple[str, np.dtype[Any]]] = {}
    pos = len(MAGIC)
    while pos < len(data):
        found = record_at(data, pos)
        if found is None:
            nxt = _resync(data, pos + 1)
            if nxt is None and last:
                rec.torn_tail_bytes = len(data) - pos
                rec.problems.append(f"{seg.name}: torn tail of {len(data) - pos} bytes at offset {pos}")
                return
            end = len(data) if nxt is None else nxt
            rec.corrupt_records += 1
            rec.corrupt_bytes += end - pos
            rec.problems.append(f"{seg.name}: {end - pos} damaged bytes skipped at offset {pos}")
            pos = end
            continue
        kind, cid, payload, pos = found
        _apply(kind, cid, payload, rec, dtypes, parts, seg)


def _apply(
    kind: int,
    cid: int,
    payload: bytes,
    rec: RecordingFile,
    dtypes: dict[int, tuple[str, np.dtype[Any]]],
    parts: dict[str, list[np.ndarray]],
    seg: Path,
) -> None:
    if kind == HEADER:
        rec.header = rec.header or json.loads(payload)
    elif kind == CONFIG:
        rec.config_text = rec.config_text or payload.decode("utf-8", "replace")
    elif kind == CHANNEL:
        decl = json.loads(payload)
        fields = [tuple(f) if len(f) == 2 else (f[0], f[1], tuple(f[2])) for f in decl["fields"]]
        dtypes[decl["id"]] = (decl["name"], np.dtype(fields))
    elif kind == DATA:
        if cid not in dtypes:  # its declaration was in a damaged record
            rec.problems.append(f"{seg.name}: data of undeclared channel {cid} skipped")
            return
        name, dtype = dtypes[cid]
        parts.setdefault(name, []).append(np.frombuffer(payload, dtype))
    elif kind == MARK:
        rec.marks.append(json.loads(payload))
    elif kind == STATS and payload:
        rec.stats = json.loads(payload)


def _resync(data: bytes, start: int) -> int | None:
    """Offset of the next whole, CRC-valid record at or after start (a false sync fails its CRC)."""
    pos = data.find(SYNC, start)
    while pos >= 0:
        if record_at(data, pos) is not None:
            return pos
        pos = data.find(SYNC, pos + 1)
    return None


def flatten_config(config_text: str, sections: Sequence[str]) -> dict[str, str]:
    """Scalar leaves of the YAML config's given sections as "section.key" -> value (one line each)."""
    import yaml

    try:
        doc = yaml.safe_load(config_text)
    except yaml.YAMLError:
        return {}
    out: dict[str, str] = {}

    def walk(prefix: str, node: object) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(f"{prefix}.{k}", v)
        elif isinstance(node, (int, float, str, bool)):
            out[prefix] = " ".join(str(node).split())  # metadata values are single lines

    if isinstance(doc, dict):
        for s in sections:
            walk(s, doc.get(s))
    return out
