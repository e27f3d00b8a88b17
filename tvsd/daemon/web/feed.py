"""What the live view shows, kept as bounded series that each browser reads from its own cursor.

`LiveFeed` is fed on the event loop's thread: `sample(status)` at the push rate (the daemon's
`Status`, the object the RPC `status` method returns), `point(p)` for each published point,
`spectra` and `floor` results when they are new. Every series is bounded (the last `history_s`
of samples, the newest `cloud_points` points), and a browser's frame holds what is new since its
`Cursor`: a browser that skipped frames gets the rows it missed (up to those bounds) in the next
one, and nothing piles up for it anywhere.
"""

from __future__ import annotations

import base64
import json
import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from tvsd.rpc.protocol import clean
from tvsd.scan.points import FLAG_NAMES, Point

POINT_COLS = ("x_m", "y_m", "z_m", "sigma_mm", "flags")


@dataclass
class Cursor:
    """What one browser has been sent: the sequence number of each series."""

    samples: int = 0
    points: int = 0
    spectra: int = 0
    floor: int = 0
    faults: tuple[int, float] = (0, 0.0)  # count, newest t_unix
    reports: int = 0


class Series:
    """The newest `maxlen` rows, numbered from 1."""

    def __init__(self, maxlen: int) -> None:
        self.rows: deque[Any] = deque(maxlen=maxlen)
        self.seq = 0

    def add(self, row: Any) -> None:
        self.rows.append(row)
        self.seq += 1

    def since(self, seq: int) -> list[Any]:
        n = min(self.seq - seq, len(self.rows))
        return list(self.rows)[len(self.rows) - n :] if n > 0 else []


class PointRing:
    """The newest `size` points as (x, y, z m, σ mm, flags), preallocated."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.rows = np.zeros((size, len(POINT_COLS)))
        self.seq = 0

    def add(self, p: Point) -> None:
        sigma_m = math.sqrt(p.sigma_x**2 + p.sigma_y**2 + p.sigma_z**2)
        if not all(math.isfinite(v) for v in (p.x, p.y, p.z, sigma_m)):
            return  # a point without a position has nothing to draw
        row = self.rows[self.seq % self.size]
        row[0], row[1], row[2], row[3], row[4] = p.x, p.y, p.z, sigma_m * 1e3, p.flags
        self.seq += 1

    def since(self, seq: int) -> str:
        """The points after `seq`, oldest first, as base64 of little-endian float32 rows
        (POINT_COLS): 0.1 µm at 1 m, and 20 B a point where JSON numbers took ~45 and 30× the
        time to write (17 ms for 5000 on the event loop; this is < 1 ms)."""
        n = min(self.seq - seq, self.size)
        if n <= 0:
            return ""
        idx = np.arange(self.seq - n, self.seq) % self.size
        return base64.b64encode(self.rows[idx].astype("<f4").tobytes()).decode("ascii")


class LiveFeed:
    def __init__(self, history_s: float, push_hz: float, cloud_points: int) -> None:
        self.samples = Series(max(2, math.ceil(history_s * push_hz)))
        self.points = PointRing(cloud_points)
        self.status: dict[str, Any] = {}
        self.faults: list[dict[str, Any]] = []
        self.spectra_json: str | None = None  # encoded once, not once per browser
        self.spectra_seq = 0
        self.floor: dict[str, Any] | None = None
        self.floor_seq = 0
        self.reports: list[dict[str, Any]] = []
        self.reports_seq = 0
        self._last_ticks: int | None = None
        self._last_missed = 0
        self.config = {
            "history_s": history_s,
            "push_hz": push_hz,
            "cloud_points": cloud_points,
            "flag_names": {str(k): v for k, v in FLAG_NAMES.items()},
            "point_cols": POINT_COLS,
        }

    # --- fed by the server on the event loop --------------------------------------------------------
    def sample(self, status: dict[str, Any], now: float | None = None) -> None:
        """One status snapshot (Status.to_json(), cleaned): the speed and lateness rows, faults."""
        status = clean(status)
        self.faults = status.pop("faults", [])
        self.status = status
        loop = status.get("loop") or {}
        missed = int(loop.get("missed_ticks") or 0)
        ticks = int(loop.get("ticks") or 0)
        new_missed = missed - self._last_missed if self._last_ticks is not None else 0
        self._last_ticks, self._last_missed = ticks, missed
        t = time.time() if now is None else now
        self.samples.add(
            [
                round(t, 3),
                _num(status.get("rps")),
                _num(status.get("rps_setpoint")),
                _num(loop.get("jitter_p99_us")),
                _num(loop.get("jitter_max_us")),
                new_missed,
            ]
        )

    def point(self, p: Point) -> None:
        self.points.add(p)

    def set_spectra(self, spectra_json: str | None) -> None:
        """A new spectrum (tvsd.daemon.web.spectra.ImuWindow.spectra, as JSON text)."""
        if spectra_json is not None:
            self.spectra_json = spectra_json
            self.spectra_seq += 1

    def set_floor(self, floor: dict[str, Any] | None, seq: int) -> None:
        if floor is not None and seq != self.floor_seq:
            self.floor, self.floor_seq = clean(floor), seq

    def set_reports(self, reports: list[dict[str, Any]]) -> None:
        if [r["path"] for r in reports] != [r["path"] for r in self.reports] or any(
            a["mtime_unix"] != b["mtime_unix"] for a, b in zip(reports, self.reports, strict=False)
        ):
            self.reports_seq += 1
        self.reports = reports

    # --- read by each browser -------------------------------------------------------------------------
    def frame(self, cur: Cursor, *, hello: bool = False) -> dict[str, Any]:
        """What is new for the browser at `cur` (everything kept, for `hello`); advances `cur`.
        Parts already encoded as JSON text are under "_raw" (see `encode`)."""
        out: dict[str, Any] = {"type": "hello" if hello else "frame", "t_unix": round(time.time(), 3)}
        if hello:
            out["config"] = self.config
        out["status"] = self.status
        out["samples"] = self.samples.since(cur.samples)
        out["points"] = self.points.since(cur.points)
        out["points_total"] = self.points.seq
        cur.samples, cur.points = self.samples.seq, self.points.seq
        faults_key = (len(self.faults), self.faults[-1]["t_unix"] if self.faults else 0.0)
        if hello or faults_key != cur.faults:
            out["faults"] = self.faults
            cur.faults = faults_key
        if self.spectra_json is not None and cur.spectra != self.spectra_seq:
            out["_raw"] = {"spectra": self.spectra_json}
            cur.spectra = self.spectra_seq
        if self.floor is not None and cur.floor != self.floor_seq:
            out["floor"] = self.floor
            cur.floor = self.floor_seq
        if hello or cur.reports != self.reports_seq:
            out["reports"] = self.reports
            cur.reports = self.reports_seq
        return out


def encode(frame: dict[str, Any]) -> str:
    """A frame as one JSON object, its pre-encoded parts spliced in as they are."""
    raw = frame.pop("_raw", None)
    text = json.dumps(frame, separators=(",", ":"), allow_nan=False)
    if raw:
        text = text[:-1] + "".join(f",{json.dumps(k)}:{v}" for k, v in raw.items()) + "}"
    return text


def decode_points(b64: str) -> np.ndarray:
    """The rows `PointRing.since` encoded: (n, len(POINT_COLS)) float32."""
    return np.frombuffer(base64.b64decode(b64), dtype="<f4").reshape(-1, len(POINT_COLS))


def _num(x: Any) -> float | None:
    return float(x) if isinstance(x, (int, float)) and math.isfinite(x) else None
