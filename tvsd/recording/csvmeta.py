"""The recording CSV's metadata lines that the reader checks (tvsd.recording.csvfile): what `u` is
and how it was sampled, the excitation's lines, the encoder's counts and the frames an angle was
interpolated between. Each bad value: one DataFileError naming the row (exit 2 on the command line)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping

from tvsd.errors import DataFileError

# What u is (DESIGN.md): a voltage drive (default), a current drive, a torque/force command, or a
# PWM duty −1…1 with `u_scale` volts at full duty.
U_UNITS = ("V", "A", "N*m", "N", "duty")
# How u was sampled (`# u_sampling:`): "mean" over the interval up to the sample, like ω (tvsd's
# recordings), or "hold" from the sample on (it acts one sample later). Absent: not known.
U_SAMPLING = ("mean", "hold")
Failer = Callable[[int, str], DataFileError]  # (row, problem) -> the error to raise


def check_meta(
    meta: Mapping[str, str], meta_row: Mapping[str, int], rate: float, fail: Failer
) -> tuple[float, ...]:
    """Every checked key of the header (`meta_row`: each key's row, for the message); the
    excitation's lines (Hz), () when undeclared."""
    _check_unit(meta, meta_row, fail)
    lines_hz = excitation_lines(meta.get("excitation_hz"), rate, meta_row.get("excitation_hz", 2), fail)
    _check_counts(meta.get("encoder_counts_per_rev"), meta_row.get("encoder_counts_per_rev", 2), fail)
    _check_frames(meta, meta_row, fail)
    return lines_hz


def _check_counts(value: str | None, row: int, fail: Failer) -> None:
    """`# encoder_counts_per_rev: N`: a whole number ≥ 4 (the model doctor reads the count's step)."""
    if value is None:
        return
    try:
        n = float(value)
    except ValueError:
        n = math.nan
    if not (math.isfinite(n) and n == int(n) and 4 <= n <= 1 << 30):
        raise fail(
            row,
            f"encoder_counts_per_rev must be a whole number of counts per revolution (≥ 4), got "
            f"{value!r}: fix it or delete the line",
        )


FRAME_KEYS = ("encoder_frame_hz", "encoder_frame_offset_s")


def _check_frames(meta: Mapping[str, str], meta_row: Mapping[str, int], fail: Failer) -> None:
    """`# encoder_frame_hz: F` (> 0) and `# encoder_frame_offset_s: d` (≥ 0): the encoder frames the
    angle was interpolated between (tvsctl export), with the counts declared; both or neither."""
    given = [k for k in FRAME_KEYS if k in meta]
    if not given:
        return
    row = meta_row.get(given[0], 2)
    if len(given) < len(FRAME_KEYS) or "encoder_counts_per_rev" not in meta:
        raise fail(
            row,
            "encoder_frame_hz and encoder_frame_offset_s go together, with encoder_counts_per_rev: "
            "give all three or delete the frame lines",
        )
    for key, ok in ((FRAME_KEYS[0], lambda x: x > 0), (FRAME_KEYS[1], lambda x: x >= 0)):
        try:
            value = float(meta[key])
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and ok(value)):
            raise fail(
                meta_row.get(key, row),
                f"{key} must be a number (the rate > 0 Hz, the offset ≥ 0 s), got {meta[key]!r}: fix it",
            )


def format_lines(lines_hz: Iterable[float]) -> str:
    """The `# excitation_hz:` value of a sequence of frequencies (Hz), space-separated."""
    return " ".join(f"{float(f):.6g}" for f in lines_hz)


def excitation_lines(value: str | None, rate: float, row: int, fail: Failer) -> tuple[float, ...]:
    """`# excitation_hz: f1 f2 …`: the frequencies (Hz) the excitation was designed with — the
    doctor's resonance scan leaves them out (a rigid model's misfit of the response leaves a line
    exactly there). Each must be a number in (0, sample_rate_hz/2)."""
    if value is None:
        return ()
    out: list[float] = []
    for tok in value.replace(",", " ").split():
        try:
            f = float(tok)
        except ValueError:
            f = math.nan
        if not (math.isfinite(f) and 0 < f < rate / 2):
            raise fail(
                row,
                f"excitation_hz {tok!r} is not a frequency in (0, {rate / 2:g}) Hz; the line is "
                "'# excitation_hz: <Hz> <Hz> ...' (the excitation's lines): fix it or delete it",
            )
        out.append(f)
    if not out:
        raise fail(row, "excitation_hz is empty; give '# excitation_hz: <Hz> <Hz> ...' or delete the line")
    return tuple(out)


def _check_unit(meta: Mapping[str, str], meta_row: Mapping[str, int], fail: Failer) -> None:
    unit = meta.get("u_unit", "V")
    if unit not in U_UNITS:
        raise fail(
            meta_row.get("u_unit", 2),
            f"u_unit {unit!r} is not one of {', '.join(U_UNITS)} (what the command u is): fix the line",
        )
    sampling = meta.get("u_sampling")
    if sampling is not None and sampling not in U_SAMPLING:
        raise fail(
            meta_row.get("u_sampling", 2),
            f"u_sampling {sampling!r} is not one of {', '.join(U_SAMPLING)} (u averaged over the "
            "interval up to its sample, or held from it on): fix it or delete the line",
        )
    if unit == "duty":
        try:
            scale = float(meta.get("u_scale", "nan"))
        except ValueError:
            scale = math.nan
        if not (math.isfinite(scale) and scale > 0):
            seen = f"got {meta['u_scale']!r}" if "u_scale" in meta else "the line is missing"
            raise fail(
                meta_row.get("u_scale", meta_row["u_unit"]),
                f"u_unit duty needs '# u_scale: <volts at full duty>', a positive number ({seen})",
            )
