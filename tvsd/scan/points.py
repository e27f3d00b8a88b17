"""Points of a scan with their uncertainty and flags; CSV and PLY writers.

`FIELDS` is the one list of per-point fields: the CSV columns, the PLY vertex properties, and the
fields of each `Point` on the daemon's point stream (`PointCloud.points()`), in that order.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tvsd.errors import UsageError

F64 = NDArray[np.float64]

FLAG_VIBRATION = 1  # measured vibration intensity above the configured threshold (paper eq. 12 aim)
FLAG_COMPENSATED = 2  # β corrected with the IMU and the drive model
FLAG_NO_IMU = 4  # no IMU data: σ from the zero pulses alone (tvsd.scan.uncertainty: less reliable)
FLAG_ENCODER = 8  # β read from the motor encoder
FLAG_NAMES = {
    FLAG_VIBRATION: "vibration",
    FLAG_COMPENSATED: "compensated",
    FLAG_NO_IMU: "no_imu",
    FLAG_ENCODER: "encoder",
}


@dataclass(frozen=True)
class PointCloud:
    t: F64  # s, time of the optical pulse (MCU clock)
    phi: F64  # rad, PL mirror (stepper position)
    gamma: F64  # rad, rod tilt (stepper position)
    beta: F64  # rad, estimated
    x: F64  # m
    y: F64
    z: F64
    sigma_x: F64  # m, 1σ
    sigma_y: F64
    sigma_z: F64
    sigma_beta: F64  # rad
    vibration: F64  # rad/s^1.5, measured intensity √q (NaN without IMU)
    flags: NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.t)

    def points(self) -> Iterator[Point]:
        """One Point per point: the daemon's point stream carries these."""
        cols = [getattr(self, f) for f in FIELDS]
        for row in zip(*cols, strict=True):
            values: dict[str, Any] = {f: float(v) for f, v in zip(FIELDS, row, strict=True)}
            values["flags"] = int(row[-1])
            yield Point(**values)

    def select(self, mask: NDArray[np.bool_]) -> PointCloud:
        return PointCloud(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})


FIELDS: tuple[str, ...] = tuple(f.name for f in fields(PointCloud))


@dataclass(frozen=True, slots=True)
class Point:
    """One point of PointCloud (its FIELDS, in order), and when it happened on the host's clock.

    `to_json()` is the record of the daemon's point stream (`tvsctl points --json`): a contract,
    fields only ever added."""

    t: float  # s, time of the optical pulse (MCU clock)
    phi: float
    gamma: float
    beta: float
    x: float
    y: float
    z: float
    sigma_x: float
    sigma_y: float
    sigma_z: float
    sigma_beta: float
    vibration: float
    flags: int
    t_mono: float = math.nan  # the optical pulse on the host's CLOCK_MONOTONIC (the daemon's clock sync)

    def to_json(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


assert tuple(f.name for f in fields(Point))[: len(FIELDS)] == FIELDS  # one field list, in order
_UNITS = {
    "t": "s",
    "phi": "rad",
    "gamma": "rad",
    "beta": "rad",
    "sigma_beta": "rad",
    "vibration": "rad/s^1.5",
}


def _open(path: Path) -> Any:
    try:
        return path.open("w", encoding="ascii", newline="\n")
    except OSError as exc:
        raise UsageError(f"cannot write {path}: {exc.strerror}") from exc


def write_csv(cloud: PointCloud, path: Path) -> None:
    """CSV: '#' metadata lines (units, flag bits), a header row, one row per point."""
    data = np.column_stack([getattr(cloud, f) for f in FIELDS]) if len(cloud) else np.zeros((0, len(FIELDS)))
    with _open(path) as fh:
        fh.write("# tvs-points: 1\n")
        fh.write("# units: " + ", ".join(f"{f} {_UNITS.get(f, 'm')}" for f in FIELDS[:-1]) + "\n")
        fh.write("# flags: " + ", ".join(f"{bit}={name}" for bit, name in FLAG_NAMES.items()) + "\n")
        fmt = ["%.9f"] + ["%.9g"] * (len(FIELDS) - 2) + ["%d"]
        np.savetxt(fh, data, delimiter=",", header=",".join(FIELDS), comments="", fmt=fmt)


def write_ply(cloud: PointCloud, path: Path) -> None:
    """ASCII PLY: vertex x y z first (what viewers read), then σ and the other fields."""
    order = ["x", "y", "z"] + [f for f in FIELDS if f not in ("x", "y", "z")]
    with _open(path) as fh:
        fh.write("ply\nformat ascii 1.0\ncomment tvsd scan points, SI units, sigma = 1 std\n")
        fh.write(f"element vertex {len(cloud)}\n")
        for f in order:
            fh.write(f"property {'int' if f == 'flags' else 'double'} {f}\n")
        fh.write("end_header\n")
        data = (
            np.column_stack([getattr(cloud, f) for f in order]) if len(cloud) else np.zeros((0, len(order)))
        )
        fmt = ["%.9f" if f == "t" else "%.9g" for f in order[:-1]] + ["%d"]
        np.savetxt(fh, data, fmt=fmt)


def write(cloud: PointCloud, path: Path) -> None:
    """By extension: .csv or .ply."""
    suffix = path.suffix.lower()
    if suffix == ".csv":
        write_csv(cloud, path)
    elif suffix == ".ply":
        write_ply(cloud, path)
    else:
        raise UsageError(f"{path}: point clouds are written as .csv or .ply; give one of those")


def concat(a: PointCloud, b: PointCloud) -> PointCloud:
    return PointCloud(**{f: np.concatenate([getattr(a, f), getattr(b, f)]) for f in FIELDS})


def read_csv(path: Path) -> PointCloud:
    """Read a point CSV written by `write_csv` (metadata lines, then the FIELDS header)."""
    try:
        lines = path.read_text(encoding="ascii").splitlines()
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror}") from exc
    body = [ln for ln in lines if ln and not ln.startswith("#")]
    if not body or tuple(body[0].split(",")) != FIELDS:
        raise UsageError(f"{path}: not a tvs-points CSV (expected the header {','.join(FIELDS)})")
    data = np.loadtxt(body[1:], delimiter=",", ndmin=2) if len(body) > 1 else np.zeros((0, len(FIELDS)))
    cols: dict[str, Any] = {f: data[:, i] for i, f in enumerate(FIELDS)}
    cols["flags"] = cols["flags"].astype(np.int64)
    return PointCloud(**cols)
