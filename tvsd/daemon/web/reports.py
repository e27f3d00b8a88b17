"""The model doctor's reports in the data directory, found and served read-only.

A report is a folder holding `report.md` (`tvsctl analyze --report DIR`, tvsd.analysis.report),
its figures beside it. `find_reports` lists those up to `MAX_DEPTH` folders below the data
directory; `resolve` turns a requested relative path into a file that may be served, or None:
only a file of a known kind, inside a report folder, inside the data directory once every
symbolic link is resolved (no `..`, no absolute path, no link out).
"""

from __future__ import annotations

import os
import time
from pathlib import Path, PurePosixPath
from typing import Any

REPORT_PAGE = "report.md"
MAX_DEPTH = 3
MAX_REPORTS = 200
CONTENT_TYPES = {
    ".md": "text/markdown; charset=utf-8",
    ".png": "image/png",
    ".svg": "image/svg+xml",
    ".json": "application/json",
    ".txt": "text/plain; charset=utf-8",
}


def find_reports(data_dir: Path) -> list[dict[str, Any]]:
    """{"path" (relative, /-separated), "title", "mtime_unix"} of each report.md, newest first.
    Blocking file-system work: call it off the event loop."""
    root = data_dir.resolve()
    found: list[dict[str, Any]] = []
    if not root.is_dir():
        return found
    for dirpath, dirnames, filenames in os.walk(root):
        depth = len(Path(dirpath).relative_to(root).parts)
        if depth >= MAX_DEPTH:
            dirnames.clear()
        dirnames.sort()
        if REPORT_PAGE not in filenames:
            continue
        page = Path(dirpath) / REPORT_PAGE
        if resolve(root, page.relative_to(root).as_posix()) is None:
            continue
        try:
            mtime = page.stat().st_mtime
            with page.open(encoding="utf-8", errors="replace") as fh:
                first = fh.readline().strip()
        except OSError:
            continue
        found.append(
            {
                "path": page.relative_to(root).as_posix(),
                "title": first.lstrip("# ").strip() or page.parent.name,
                "mtime_unix": mtime,
                "age_s": time.time() - mtime,
            }
        )
    found.sort(key=lambda r: -float(r["mtime_unix"]))
    return found[:MAX_REPORTS]


def resolve(data_dir: Path, rel: str) -> Path | None:
    """The file `rel` names inside a report folder of `data_dir`, or None if it may not be served."""
    if not rel or "\\" in rel or "\0" in rel:
        return None
    parts = rel.split("/")  # as written: PurePosixPath would fold "a/./b" and "a//b" away
    if any(p in ("..", ".", "") for p in parts):  # an absolute path starts with ""
        return None
    if PurePosixPath(rel).suffix.lower() not in CONTENT_TYPES:
        return None
    root = data_dir.resolve()
    try:
        path = (root / Path(*parts)).resolve(strict=True)
    except (OSError, RuntimeError):
        return None
    if not path.is_relative_to(root) or not path.is_file():
        return None
    # inside a report folder: its own folder or one above it, below the data dir, has report.md
    for folder in (path.parent, *path.parent.parents):
        if folder == root or not folder.is_relative_to(root):
            break
        if (folder / REPORT_PAGE).is_file():
            return path
    return None


def content_type(path: Path) -> str:
    return CONTENT_TYPES[path.suffix.lower()]
