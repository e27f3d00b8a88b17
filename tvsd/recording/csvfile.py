"""Recording CSV of docs/architecture.md: written by `tvsctl sim record` / `tvsctl export`, read by analyze

    # tvs-recording: 1
    # sample_rate_hz: 1000
    # <key>: <value>            optional metadata
    # excitation_hz: 0.2 0.4 …  optional: the lines the excitation was designed with (Hz)
    # encoder_counts_per_rev: N optional: φ is an encoder's count × 2π/N (kept in meta)
    # encoder_frame_hz: F       optional, with encoder_frame_offset_s: d and the counts: ω, φ
                                interpolated between the encoder's frames (the checks: csvmeta)
    t,u,omega,phi[,more...]     SI: s, V, rad/s, rad (phi optional: integrated from omega)

A bad file raises DataFileError with one line naming the file, the row (1-based line of the file)
and the problem; the command line turns it into exit status 2.
For numpy users: ``numpy.genfromtxt(path, delimiter=",", names=True, comments="#")``; pandas:
``pandas.read_csv(path, comment="#")``.
"""

from __future__ import annotations

import math
import re
import stat
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tvsd.errors import DataFileError
from tvsd.recording.csvmeta import U_SAMPLING as U_SAMPLING  # re-exported: the readers' vocabulary
from tvsd.recording.csvmeta import U_UNITS as U_UNITS
from tvsd.recording.csvmeta import Failer, check_meta
from tvsd.recording.csvmeta import format_lines as format_lines

FORMAT_VERSION = "1"
REFERENCE_COLUMNS = ("omega_ref", "phi_ref")
HUGE = 1e15  # no time, command, speed or angle of a drive comes near this
REQUIRED = ("t", "u", "omega")


@dataclass(frozen=True)
class Recording:
    t: np.ndarray
    u: np.ndarray
    omega: np.ndarray
    phi: np.ndarray
    sample_rate_hz: float
    meta: Mapping[str, str] = field(default_factory=dict)
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)
    path: Path | None = None
    phi_measured: bool = True  # False: phi was integrated from omega
    excitation_hz: tuple[float, ...] = ()  # `# excitation_hz:` (the excitation's known lines)


def write(
    path: Path,
    t: np.ndarray,
    u: np.ndarray,
    omega: np.ndarray,
    phi: np.ndarray | None,
    sample_rate_hz: float,
    meta: Mapping[str, object] | None = None,
    extra: Mapping[str, np.ndarray] | None = None,
) -> None:
    columns: dict[str, np.ndarray] = {"t": t, "u": u, "omega": omega}
    if phi is not None:
        columns["phi"] = phi
    columns.update(extra or {})
    lines = [f"# tvs-recording: {FORMAT_VERSION}", f"# sample_rate_hz: {sample_rate_hz:g}"]
    lines += [f"# {k}: {v}" for k, v in (meta or {}).items()]
    data = np.column_stack([np.asarray(c, dtype=float) for c in columns.values()])
    path = Path(path)
    try:
        with path.open("w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n" + ",".join(columns) + "\n")
            np.savetxt(fh, data, delimiter=",", fmt="%.9g")
    except OSError as exc:
        raise DataFileError(f"{path}: cannot write the recording: {exc.strerror}") from exc


def read(path: Path) -> Recording:
    path = Path(path)
    try:
        if not stat.S_ISREG(path.stat().st_mode) and not path.is_dir():  # /dev/zero: read until MemoryError
            raise DataFileError(f"{path}: not a regular file (a device or a pipe); give the recording CSV")
        raw = path.read_bytes()
    except FileNotFoundError:
        raise DataFileError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise DataFileError(
            f"{path}: is a directory; give a recording CSV (a daemon recording becomes one with "
            "`tvsctl export REC --csv OUT`)"
        ) from None
    except PermissionError:
        raise DataFileError(
            f"{path}: cannot read: permission denied; check the file's mode or owner"
        ) from None
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read: {exc.strerror}") from exc
    lines = decode(path, raw).splitlines()

    def fail(row: int, problem: str) -> DataFileError:
        return DataFileError(f"{path}: row {row}: {problem}")

    if not lines or lines[0].replace(" ", "") != f"#tvs-recording:{FORMAT_VERSION}":
        seen = repr(lines[0][:60]) if lines else "an empty file"
        raise fail(
            1,
            f"expected '# tvs-recording: {FORMAT_VERSION}' as the first line, got {seen}"
            " (is this a tvs recording? see docs/architecture.md, 'Recording CSV')",
        )
    meta: dict[str, str] = {}
    meta_row: dict[str, int] = {}  # the file's row of each key (errors name it)
    row = 1
    while row < len(lines) and lines[row].startswith("#"):
        key, colon, value = lines[row][1:].partition(":")
        if not colon:
            raise fail(row + 1, f"metadata line {lines[row]!r} is not '# key: value'")
        key, value = key.strip(), value.strip()
        if key in meta and meta[key] != value:  # `# u_unit: V` then `# u_unit: A`: which one?
            raise fail(row + 1, f"'{key}' is given again (first at row {meta_row[key]}): keep one line")
        meta[key] = value
        meta_row[key] = row + 1
        row += 1
    if "sample_rate_hz" not in meta:
        raise fail(2, "missing '# sample_rate_hz: <Hz>' metadata line; add it after the first line")
    try:
        rate = float(meta["sample_rate_hz"])
    except ValueError:
        rate = math.nan
    if not (math.isfinite(rate) and rate > 0):
        raise fail(
            meta_row["sample_rate_hz"],
            f"sample_rate_hz must be a positive number (Hz), got {meta['sample_rate_hz']!r}: fix the line",
        )
    lines_hz = check_meta(meta, meta_row, rate, fail)
    if row >= len(lines):
        raise fail(row + 1, "missing the column header line (t,u,omega[,phi,...])")
    header = [h.strip() for h in lines[row].split(",")]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        sep = next((c for c in ";\t|" if c in lines[row] and "," not in lines[row]), None)
        hint = f": its columns are separated by {sep!r}; the recording CSV uses ',' (and '.' for decimals)"
        raise fail(
            row + 1,
            f"missing column(s) {', '.join(missing)} in header {lines[row]!r} (need t,u,omega; phi optional)"
            + (hint if sep else ""),
        )
    if len(set(header)) != len(header):
        raise fail(row + 1, f"duplicate column names in header {lines[row]!r}")
    data = _parse_rows(lines, row + 1, header, fail, ends_in_newline=raw.endswith((b"\n", b"\r")))
    cols = {name: data[:, j] for j, name in enumerate(header)}
    _check_time(cols["t"], rate, row + 2, fail)
    phi_measured = "phi" in cols
    if phi_measured:
        phi = cols["phi"]
    else:
        dt = np.diff(cols["t"])
        phi = np.concatenate([[0.0], np.cumsum(0.5 * (cols["omega"][1:] + cols["omega"][:-1]) * dt)])
    extra = {k: v for k, v in cols.items() if k not in ("t", "u", "omega", "phi")}
    return Recording(
        cols["t"], cols["u"], cols["omega"], phi, rate, meta, extra, path, phi_measured, lines_hz
    )


GZIP_MAGIC = b"\x1f\x8b"
UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")


def decode(path: Path, raw: bytes) -> str:
    """The file's text, or one line saying what the bytes are instead: compressed, UTF-16 (a
    Windows editor's "Unicode"; its byte order mark makes it unambiguous, so it is read), another
    8-bit encoding (the row and byte named), binary."""
    if raw.startswith(GZIP_MAGIC):
        raise DataFileError(f"{path}: a gzip-compressed file; decompress it first (gunzip -k {path.name})")
    if raw.startswith(UTF16_BOMS):
        try:
            text = raw.decode("utf-16")
        except UnicodeDecodeError:
            text = ""
        if text.lstrip("\ufeff").startswith("#"):  # a recording's first line; else binary, named below
            return text.lstrip("\ufeff")
    if b"\0" in raw[:65536]:
        at = raw.index(b"\0")
        row = raw.count(b"\n", 0, at) + 1
        raise DataFileError(
            f"{path}: row {row}: a NUL byte (at byte {at}): binary data, not a "
            "recording CSV (a daemon recording becomes one with `tvsctl export REC --csv OUT`)"
        )
    try:
        return raw.decode("utf-8-sig")  # -sig: a spreadsheet's UTF-8 BOM is dropped
    except UnicodeDecodeError as exc:
        row = raw.count(b"\n", 0, exc.start) + 1
        raise DataFileError(
            f"{path}: row {row}: byte 0x{raw[exc.start]:02x} is not UTF-8 text (a Latin-1 or Windows "
            "file?): save the file as UTF-8 (the recording CSV is UTF-8)"
        ) from None


def _parse_rows(
    lines: list[str], first: int, header: list[str], fail: Failer, ends_in_newline: bool = True
) -> np.ndarray:
    width = len(header)
    body = lines[first:]
    while body and not body[-1].strip():
        body.pop()
    if len(body) < 2:
        raise fail(first + 1, f"only {len(body)} data row(s); a recording needs at least 2")
    data = _parse_fast(body, width)
    if data is not None:
        return data
    return _parse_slow(body, first, header, fail, ends_in_newline)


def _parse_fast(body: list[str], width: int) -> np.ndarray | None:
    """The whole body at once (the same float() of each field, 6× faster than row by row), or
    None when any row is bad: the row-by-row pass then names the first bad row."""
    if any(ln.count(",") != width - 1 for ln in body):
        return None
    try:
        data = np.array(list(map(float, ",".join(body).split(","))), dtype=float).reshape(len(body), width)
    except ValueError:
        return None
    if not np.all(np.isfinite(data)) or np.any(np.abs(data) > HUGE):
        return None
    return data


def _parse_slow(
    body: list[str], first: int, header: list[str], fail: Failer, ends_in_newline: bool
) -> np.ndarray:
    width = len(header)
    data = np.empty((len(body), width))
    for k, line in enumerate(body):
        row = first + k + 1
        last = k == len(body) - 1 and not ends_in_newline
        parts = line.split(",")
        if last and len(parts) <= width and _cut(parts, width):
            raise fail(
                row,
                f"the last row {line[:80]!r} is cut short (no end of line, {len(parts)} of {width} "
                "values or a number cut): the file was cut while being written; delete that row",
            )
        if len(parts) != width:
            raise fail(row, _field_count(line, len(parts), header))
        for j, p in enumerate(parts):
            try:
                data[k, j] = float(p)
            except ValueError:
                seen = "is empty" if not p.strip() else f"is {p.strip()[:30]!r}, not a number"
                raise fail(row, f"{header[j]} {seen} in {line[:80]!r}: repair or delete the row") from None
        if not np.all(np.isfinite(data[k])):
            raise fail(row, f"NaN or infinite value in {line[:80]!r}; remove or repair the row")
        if np.any(np.abs(data[k]) > HUGE):
            raise fail(
                row,
                f"value beyond ±{HUGE:g} in {line[:80]!r}: not a measurement (overflow, or a unit error)",
            )
    return data


# What a number cut while it was written can end as: a sign, digits, a point, an exponent's start.
_NUMBER_PREFIX = re.compile(r"\s*[+-]?(\d+\.?\d*|\.\d*)?([eE][+-]?\d*)?\s*")


def _cut(parts: list[str], width: int) -> bool:
    """Whether a last row with no end of line was cut while written: fields missing, or only its
    last field bad and that field the start of a number ('1.5e', '-', ''). A whole row with a
    word in it is a non-number, reported as such with its column (the row-by-row check)."""
    bad = [j for j, p in enumerate(parts) if not _parses(p)]
    if len(parts) < width:
        return bool(bad)
    return bad == [width - 1] and _NUMBER_PREFIX.fullmatch(parts[-1]) is not None


def _parses(p: str) -> bool:
    try:
        float(p)
    except ValueError:
        return False
    return True


def _field_count(line: str, got: int, header: list[str]) -> str:
    """A row with the wrong number of values: what it is likely to be, and the fix."""
    names, width = ",".join(header), len(header)
    if not line.strip():
        return f"an empty line inside the data (the header {names} has {width} columns): delete it"
    if line.lstrip().startswith("#"):
        return f"a comment line {line[:60]!r} inside the data: comments go above the header; delete it"
    if got > width and line.rstrip().endswith(","):
        why = "a trailing comma"
    elif got > width and "." not in line:
        why = "decimal commas? the recording CSV uses '.' for decimals"
    else:
        why = "a cut or merged line"
    return f"{got} values in {line[:80]!r}, the header {names} has {width} ({why}): repair or delete the row"


def _check_time(t: np.ndarray, rate: float, first_row: int, fail: Failer) -> None:
    dt = np.diff(t)
    bad = np.nonzero(dt <= 0)[0]
    if len(bad):
        k = int(bad[0]) + 1
        raise fail(
            first_row + k,
            f"t = {t[k]:g} s does not increase (previous {t[k - 1]:g} s); t must be strictly increasing",
        )
    # Uniform within 1 % of a period: looser would hide dropped samples, tighter would trip on
    # the 9 significant digits the writer keeps.
    period = 1.0 / rate
    off = np.nonzero(np.abs(dt - period) > 0.01 * period)[0]
    if len(off):
        k = int(off[0]) + 1
        raise fail(
            first_row + k,
            f"time step {dt[k - 1]:g} s differs from 1/sample_rate_hz = {period:g} s"
            " (missing samples, or wrong sample_rate_hz / time unit: t is in seconds)",
        )
