"""Adversarial sweep of `tvsctl analyze`'s input: damaged variants of a valid recording.

Why: strangers throw files at the doctor that nobody here wrote. The contract (DESIGN.md,
"Recording CSV"; the project standard on bad input): a valid file, or one repairable without
guessing, gets exit 0 and a verdict; anything else exit 2 and one line on stderr naming what was
seen, where and the fix. Never exit 1 or 70, a traceback, a numpy/pandas warning, or a hang.

    nice -n 19 .venv/bin/python scripts/analyze_fuzz.py --seed 1 --out /tmp/fuzz [--bench FILE.csv]
    (before: the same with another worktree's python, e.g. /work/wt/integ3/.venv/bin/python)

Each variant runs as `tvsctl analyze FILE --json --quiet` and `tvsctl analyze FILE --quiet`; the
table prints variant, exit statuses, the class (verdict / refused / FAIL: why) and stderr's line.
"""

from __future__ import annotations

import argparse
import gzip
import json
import multiprocessing
import os
import subprocess
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TVSCTL = str(ROOT / ".venv" / "bin" / "tvsctl")
TIMEOUT_S = 300.0  # a valid 60 s file takes ~5 s: far past this is a hang
FORBIDDEN = ("Traceback", "Warning:", "internal error", "RuntimeWarning", "FutureWarning")


@dataclass
class Base:
    """A valid recording split into its parts."""

    meta: list[str]  # the '# ...' lines, '# tvs-recording: 1' first
    header: list[str]
    rows: list[list[str]]

    def text(
        self,
        meta: list[str] | None = None,
        header: list[str] | None = None,
        rows: list[list[str]] | None = None,
        sep: str = ",",
        nl: str = "\n",
    ) -> str:
        m = self.meta if meta is None else meta
        h = self.header if header is None else header
        r = self.rows if rows is None else rows
        return nl.join([*m, sep.join(h), *(sep.join(x) for x in r)]) + nl


def read_base(path: Path) -> Base:
    lines = path.read_text().splitlines()
    meta = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if not ln.startswith("#")]
    return Base(meta, body[0].split(","), [ln.split(",") for ln in body[1:] if ln])


@dataclass
class Variant:
    name: str
    expect: str  # "verdict", "refuse" or "either"
    path: Path
    args: list[str] = field(default_factory=list)
    as_user: str | None = None  # run as this user (a root sweep cannot test a permission)


def _col(b: Base, name: str) -> int:
    return b.header.index(name)


def _with_meta(b: Base, *lines: str, drop: str | None = None) -> list[str]:
    keep = [m for m in b.meta if drop is None or not m.startswith(f"# {drop}:")]
    return [keep[0], *lines, *keep[1:]]


def _map_col(b: Base, name: str, f: Callable[[str, int], str]) -> list[list[str]]:
    j = _col(b, name)
    return [[f(v, k) if i == j else v for i, v in enumerate(r)] for k, r in enumerate(b.rows)]


def _set_cell(b: Base, row: int, name: str, value: str) -> list[list[str]]:
    j = _col(b, name)
    return [[value if (k == row and i == j) else v for i, v in enumerate(r)] for k, r in enumerate(b.rows)]


def _drop_col(b: Base, name: str) -> tuple[list[str], list[list[str]]]:
    j = _col(b, name)
    return [h for i, h in enumerate(b.header) if i != j], [
        [v for i, v in enumerate(r) if i != j] for r in b.rows
    ]


def text_variants(b: Base, rng: np.random.Generator) -> dict[str, tuple[str, bytes | str]]:
    """name -> (expectation, file content)."""
    n = len(b.rows)
    mid = int(rng.integers(n // 4, 3 * n // 4))
    out: dict[str, tuple[str, bytes | str]] = {"valid": ("verdict", b.text())}
    # columns
    for c in ("t", "u", "omega"):
        h, r = _drop_col(b, c)
        out[f"missing column {c}"] = ("refuse", b.text(header=h, rows=r))
    if "phi" in b.header:
        h, r = _drop_col(b, "phi")
        out["no phi column (integrated)"] = ("verdict", b.text(header=h, rows=r))
    out["extra column"] = (
        "verdict",
        b.text(header=[*b.header, "temp_c"], rows=[[*r, "21.5"] for r in b.rows]),
    )
    order = list(reversed(range(len(b.header))))
    out["reordered columns"] = (
        "verdict",
        b.text(header=[b.header[i] for i in order], rows=[[r[i] for i in order] for r in b.rows]),
    )
    out["duplicated column u"] = (
        "refuse",
        b.text(header=[*b.header, "u"], rows=[[*r, r[1]] for r in b.rows]),
    )
    out["header names upper-case"] = ("either", b.text(header=[h.upper() for h in b.header]))
    out["header names with units"] = ("either", b.text(header=[f"{h} [si]" for h in b.header]))
    out["header names quoted"] = ("either", b.text(header=[f'"{h}"' for h in b.header]))
    out["no column header line"] = ("refuse", b.text(header=b.rows[0], rows=b.rows[1:]))
    # header comment lines
    out["no tvs-recording line"] = ("refuse", b.text(meta=b.meta[1:]))
    out["tvs-recording: 2"] = ("refuse", b.text(meta=["# tvs-recording: 2", *b.meta[1:]]))
    out["metadata line without colon"] = ("refuse", b.text(meta=_with_meta(b, "# recorded on the bench")))
    out["metadata line repeated identically"] = ("verdict", b.text(meta=[*b.meta, b.meta[1]]))
    out["no sample_rate_hz"] = ("refuse", b.text(meta=_with_meta(b, drop="sample_rate_hz")))
    out["sample_rate_hz 0"] = (
        "refuse",
        b.text(meta=_with_meta(b, "# sample_rate_hz: 0", drop="sample_rate_hz")),
    )
    out["sample_rate_hz text"] = (
        "refuse",
        b.text(meta=_with_meta(b, "# sample_rate_hz: 1 kHz", drop="sample_rate_hz")),
    )
    out["sample_rate_hz wrong (500)"] = (
        "refuse",
        b.text(meta=_with_meta(b, "# sample_rate_hz: 500", drop="sample_rate_hz")),
    )
    out["sample_rate_hz nan"] = (
        "refuse",
        b.text(meta=_with_meta(b, "# sample_rate_hz: nan", drop="sample_rate_hz")),
    )
    out["sample_rate_hz twice, contradictory"] = ("refuse", b.text(meta=[*b.meta, "# sample_rate_hz: 2000"]))
    out["u_unit unknown"] = ("refuse", b.text(meta=_with_meta(b, "# u_unit: volts", drop="u_unit")))
    out["u_unit empty"] = ("refuse", b.text(meta=_with_meta(b, "# u_unit:", drop="u_unit")))
    out["u_unit lower-case v"] = ("either", b.text(meta=_with_meta(b, "# u_unit: v", drop="u_unit")))
    out["two u_units"] = ("refuse", b.text(meta=_with_meta(b, "# u_unit: V", "# u_unit: A", drop="u_unit")))
    for s in ("0", "-12", "nan", "inf", "twelve", ""):
        out[f"duty, u_scale {s or 'empty'}"] = (
            "refuse",
            b.text(meta=_with_meta(b, "# u_unit: duty", f"# u_scale: {s}", drop="u_unit")),
        )
    out["duty, no u_scale"] = ("refuse", b.text(meta=_with_meta(b, "# u_unit: duty", drop="u_unit")))
    out["u_scale without duty"] = ("either", b.text(meta=_with_meta(b, "# u_scale: 12")))
    for c in ("0", "-1024", "1000.5", "1e40", "many", ""):
        out[f"counts {c or 'empty'}"] = (
            "refuse",
            b.text(meta=_with_meta(b, f"# encoder_counts_per_rev: {c}", drop="encoder_counts_per_rev")),
        )
    out["counts 2 (coarse)"] = (
        "refuse",
        b.text(meta=_with_meta(b, "# encoder_counts_per_rev: 2", drop="encoder_counts_per_rev")),
    )
    out["excitation_hz text"] = ("refuse", b.text(meta=_with_meta(b, "# excitation_hz: fast")))
    out["u_sampling unknown"] = ("refuse", b.text(meta=_with_meta(b, "# u_sampling: zoh", drop="u_sampling")))
    out["comment line inside the data"] = ("either", b.text(rows=[*b.rows[:mid], ["# pause"], *b.rows[mid:]]))
    out["blank line inside the data"] = ("either", b.text(rows=[*b.rows[:mid], [""], *b.rows[mid:]]))
    # cells
    for cell in (
        "nan",
        "NaN",
        "inf",
        "-inf",
        "",
        "  ",
        "1e308",
        "-1e308",
        "1e999",
        "0x1p3",
        "1,5",
        "abc",
        '"1.0"',
    ):
        out[f"omega cell {cell!r} at a middle row"] = (
            "refuse",
            b.text(rows=_set_cell(b, mid, "omega", cell)),
        )
    out["t cell nan"] = ("refuse", b.text(rows=_set_cell(b, mid, "t", "nan")))
    out["u cell empty in the first row"] = ("refuse", b.text(rows=_set_cell(b, 0, "u", "")))
    out["one row with too many fields"] = (
        "refuse",
        b.text(rows=[*b.rows[:mid], [*b.rows[mid], "0"], *b.rows[mid + 1 :]]),
    )
    out["one row with too few fields"] = (
        "refuse",
        b.text(rows=[*b.rows[:mid], b.rows[mid][:-1], *b.rows[mid + 1 :]]),
    )
    out["trailing comma on every row"] = ("either", b.text(rows=[[*r, ""] for r in b.rows]))
    out["spaces around values"] = ("verdict", b.text(rows=[[f" {v} " for v in r] for r in b.rows]))
    out["plus signs"] = (
        "verdict",
        b.text(rows=_map_col(b, "u", lambda v, k: "+" + v if not v.startswith("-") else v)),
    )
    # time
    t = np.array([float(r[_col(b, "t")]) for r in b.rows])
    swapped = list(b.rows)
    swapped[mid], swapped[mid + 1] = swapped[mid + 1], swapped[mid]
    out["two rows swapped (t non-monotonic)"] = ("refuse", b.text(rows=swapped))
    out["a row repeated (t repeated)"] = ("refuse", b.text(rows=[*b.rows[:mid], b.rows[mid], *b.rows[mid:]]))
    out["t in ms"] = ("refuse", b.text(rows=_map_col(b, "t", lambda v, k: f"{1000 * t[k]:.6g}")))
    jit = t + rng.uniform(-0.05, 0.05, n) / 1000 * (1000 / (1 / np.median(np.diff(t))))
    out["t jittered 5 %"] = ("refuse", b.text(rows=_map_col(b, "t", lambda v, k: f"{jit[k]:.9g}")))
    out["gap of 100 rows"] = ("refuse", b.text(rows=[*b.rows[:mid], *b.rows[mid + 100 :]]))
    out["t starting at 1e6 s"] = ("verdict", b.text(rows=_map_col(b, "t", lambda v, k: f"{1e6 + t[k]:.12g}")))
    out["t descending"] = ("refuse", b.text(rows=b.rows[::-1]))
    # bytes
    out["CRLF"] = ("verdict", b.text(nl="\r\n"))
    out["CR only (old Mac)"] = ("either", b.text(nl="\r"))
    out["UTF-8 BOM"] = ("verdict", "\ufeff" + b.text())
    out["UTF-8 BOM and CRLF"] = ("verdict", "\ufeff" + b.text(nl="\r\n"))
    out["Latin-1 byte in a comment"] = (
        "either",
        b.text(meta=_with_meta(b, "# operator: M\xfcller")).encode("latin-1"),
    )
    out["Latin-1 byte in the data"] = (
        "refuse",
        b.text(rows=_set_cell(b, mid, "u", "1\xb05")).encode("latin-1"),
    )
    out["UTF-16"] = ("verdict", b.text().encode("utf-16"))  # its BOM says how to read it
    out["NUL bytes"] = ("refuse", b.text().replace("\n", "\n\0", 3))
    out["tab separated"] = ("refuse", b.text(sep="\t"))
    out["semicolon separated"] = ("refuse", b.text(sep=";"))
    out["semicolons and decimal commas"] = (
        "refuse",
        b.text(sep=";", rows=[[v.replace(".", ",") for v in r] for r in b.rows]),
    )
    out["decimal commas"] = ("refuse", b.text(rows=[[v.replace(".", ",") for v in r] for r in b.rows]))
    full = b.text()
    out["truncated last line"] = ("either", full[: full.rstrip("\n").rfind(",") + 2])
    out["last line without newline"] = ("verdict", full.rstrip("\n"))
    out["truncated mid-file (half a row, then more rows)"] = (
        "refuse",
        b.text(rows=[*b.rows[:mid], b.rows[mid][:2], *b.rows[mid + 1 :]]),
    )
    out["empty file (0 bytes)"] = ("refuse", b"")
    out["only a newline"] = ("refuse", "\n")
    out["comment lines only"] = ("refuse", "\n".join(b.meta) + "\n")
    out["header only"] = ("refuse", b.text(rows=[]))
    for k in (1, 2, 10, 499):
        out[f"{k} rows"] = ("refuse", b.text(rows=b.rows[:k]))
    out["random bytes"] = ("refuse", rng.integers(0, 256, 4096, dtype=np.uint8).tobytes())
    out["gzip of the CSV, named .csv"] = ("refuse", gzip.compress(full.encode()))
    out["PNG signature"] = ("refuse", b"\x89PNG\r\n\x1a\n" + bytes(64))
    out["JSON"] = ("refuse", json.dumps({"t": [0, 1], "u": [0, 1]}))
    # signals
    for c in ("u", "omega") + (("phi",) if "phi" in b.header else ()):
        out[f"{c} all zero"] = (
            "refuse" if c != "phi" else "either",
            b.text(rows=_map_col(b, c, lambda v, k: "0")),
        )
        out[f"{c} constant 3"] = (
            "refuse" if c != "phi" else "either",
            b.text(rows=_map_col(b, c, lambda v, k: "3")),
        )
    out["omega all 1e308"] = ("refuse", b.text(rows=_map_col(b, "omega", lambda v, k: "1e308")))
    out["u scaled 1e-12"] = ("either", b.text(rows=_map_col(b, "u", lambda v, k: f"{1e-12 * float(v):.6g}")))
    out["u scaled 1e9"] = ("either", b.text(rows=_map_col(b, "u", lambda v, k: f"{1e9 * float(v):.6g}")))
    out["omega in rpm (×9.549)"] = (
        "either",
        b.text(rows=_map_col(b, "omega", lambda v, k: f"{60 / 2 / np.pi * float(v):.9g}")),
    )
    out["u sign flipped"] = ("either", b.text(rows=_map_col(b, "u", lambda v, k: f"{-float(v):.9g}")))
    out["every value is 0"] = ("refuse", b.text(rows=[["0"] * len(r) for r in b.rows]))
    return out


def build(base: Path, out: Path, seed: int, prefix: str, full: bool) -> list[Variant]:
    b = read_base(base)
    rng = np.random.default_rng(seed)
    out.mkdir(parents=True, exist_ok=True)
    vs: list[Variant] = []
    texts = text_variants(b, rng)
    if not full:  # the format family only (a second base)
        keep = (
            "valid",
            "CRLF",
            "UTF-8 BOM",
            "reordered",
            "extra column",
            "tab",
            "semicolon",
            "decimal commas",
            "truncated last line",
            "last line without",
            "no phi",
            "one row with too",
            "omega cell 'nan'",
        )
        texts = {k: v for k, v in texts.items() if k.startswith(keep)}
    for i, (name, (expect, content)) in enumerate(texts.items()):
        p = out / f"{prefix.rstrip(': ')}{i:03d}.csv"
        p.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
        vs.append(Variant(f"{prefix}{name}", expect, p))
    if not full:
        return vs
    valid = out / f"{prefix}000.csv"
    d = out / f"{prefix}dir.csv"
    d.mkdir(exist_ok=True)
    vs.append(Variant(f"{prefix}a directory", "refuse", d))
    vs.append(Variant(f"{prefix}a missing file", "refuse", out / "no-such-file.csv"))
    locked = out / f"{prefix}locked.csv"
    locked.write_bytes(valid.read_bytes())
    locked.chmod(0o000)
    # root reads a mode-000 file: then the variant is a valid file (tests/test_bad_input_files.py
    # runs the refusal as another user)
    vs.append(
        Variant(f"{prefix}no read permission", "either" if os.access(locked, os.R_OK) else "refuse", locked)
    )
    gz = out / f"{prefix}gz.csv.gz"
    gz.write_bytes(gzip.compress(valid.read_bytes()))
    vs.append(Variant(f"{prefix}a .csv.gz file", "refuse", gz))
    vs.append(Variant(f"{prefix}a .mat that is the CSV", "refuse", _copy(valid, out / f"{prefix}csv.mat")))
    vs.append(Variant(f"{prefix}/dev/null", "refuse", Path("/dev/null")))
    vs.append(Variant(f"{prefix}a file named '-'", "either", Path("-")))
    # --start / --end
    t = np.array([float(r[_col(b, "t")]) for r in b.rows])
    t0, t1 = float(t[0]), float(t[-1])
    for args, expect in (
        (["--start", "2", "--end", "1"], "refuse"),
        (["--start", "2", "--end", "2"], "refuse"),
        (["--start", f"{t1 + 5:g}"], "refuse"),
        (["--end", f"{t0 - 5:g}"], "refuse"),
        (["--start", "0.1", "--end", "0.3"], "refuse"),
        (["--start", "abc"], "refuse"),
        (["--start", "nan"], "refuse"),
        (["--end", "inf"], "refuse"),
        (["--start", "1e308"], "refuse"),
        (["--start", "-1e308"], "verdict"),
        (["--end", "1e9"], "verdict"),
        (["--start", ""], "refuse"),
        (["--start", "1s"], "refuse"),
        (["--start", "0x10"], "refuse"),
    ):
        vs.append(Variant(f"{prefix}{' '.join(args)}", expect, valid, args))
    # --heldout
    hb = out / f"{prefix}heldout_A.csv"
    hb.write_text(b.text(meta=_with_meta(b, "# u_unit: A", drop="u_unit")))
    vs.append(Variant(f"{prefix}--heldout in another unit (A)", "refuse", valid, ["--heldout", str(hb)]))
    hr = out / f"{prefix}heldout_rate.csv"
    half = [r for k, r in enumerate(b.rows) if k % 2 == 0]
    hr.write_text(
        b.text(
            meta=_with_meta(b, f"# sample_rate_hz: {0.5 / np.median(np.diff(t)):g}", drop="sample_rate_hz"),
            rows=half,
        )
    )
    vs.append(Variant(f"{prefix}--heldout at another rate", "either", valid, ["--heldout", str(hr)]))
    hn = out / f"{prefix}heldout_nophi.csv"
    h, r = _drop_col(b, "phi") if "phi" in b.header else (b.header, b.rows)
    hn.write_text(b.text(header=h, rows=r))
    vs.append(Variant(f"{prefix}--heldout without phi", "verdict", valid, ["--heldout", str(hn)]))
    hc = out / f"{prefix}heldout_counts.csv"
    hc.write_text(b.text(meta=_with_meta(b, "# encoder_counts_per_rev: 1024", drop="encoder_counts_per_rev")))
    vs.append(Variant(f"{prefix}--heldout with other counts", "either", valid, ["--heldout", str(hc)]))
    vs.append(Variant(f"{prefix}--heldout missing", "refuse", valid, ["--heldout", str(out / "nope.csv")]))
    vs.append(Variant(f"{prefix}--heldout a directory", "refuse", valid, ["--heldout", str(d)]))
    vs.append(
        Variant(
            f"{prefix}--heldout 10 rows",
            "refuse",
            valid,
            ["--heldout", str(out / f"{prefix}{list(texts).index('10 rows'):03d}.csv")],
        )
    )
    vs.append(Variant(f"{prefix}--heldout the same file", "verdict", valid, ["--heldout", str(valid)]))
    return vs


def _copy(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    return dst


def _inproc(argv: list[str]) -> tuple[int, str, str]:
    """`tvsctl ARGV` in this process (a pool worker): exit status, stdout, stderr. Python warnings
    go to the captured stderr as they would in a shell (PYTHONWARNINGS=default)."""
    import contextlib
    import io
    import warnings

    from tvsd.cli.main import main as tvsctl_main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter("default")
        try:
            rc = tvsctl_main(argv)
        except SystemExit as exc:  # argparse
            rc = exc.code if isinstance(exc.code, int) else 1
        except BaseException as exc:
            rc, _ = 1, err.write(f"Traceback: {type(exc).__name__}: {exc}\n")
    return rc, out.getvalue(), err.getvalue()


def run_one(v: Variant, tvsctl: str | None, pool: Any) -> dict[str, object]:
    """Both modes of one variant: in a worker of `pool` (tvsctl None), else as a subprocess."""
    res: dict[str, object] = {"name": v.name, "expect": v.expect}
    for mode, extra in (("json", ["--json", "--quiet"]), ("human", ["--quiet"])):
        argv = ["analyze", str(v.path), *v.args, *extra]
        try:
            if tvsctl is None and v.as_user is None:
                rc, stdout, stderr = pool.apply_async(_inproc, (argv,)).get(TIMEOUT_S)
            else:
                cmd = [tvsctl or TVSCTL, *argv]
                if v.as_user:
                    cmd = ["runuser", "-u", v.as_user, "--", *cmd]
                p = subprocess.run(
                    cmd,
                    capture_output=True,
                    text=True,
                    timeout=TIMEOUT_S,
                    cwd="/tmp",
                    env={**os.environ, "PYTHONWARNINGS": "default"},
                )
                rc, stdout, stderr = p.returncode, p.stdout, p.stderr
        except (subprocess.TimeoutExpired, multiprocessing.TimeoutError):
            res[mode] = {"rc": "hang", "stderr": "", "cause": None}
            continue
        try:
            cause = json.loads(stdout).get("cause") if mode == "json" and rc == 0 else None
        except json.JSONDecodeError:
            cause = "unparsable stdout"
        res[mode] = {"rc": rc, "stderr": stderr, "cause": cause}
    res["verdict"] = judge(res)
    return res


def message_lines(stderr: str) -> list[str]:
    """stderr's lines, argparse's usage block (its continuation lines) counted as none."""
    lines = stderr.splitlines()
    if lines and lines[0].startswith("usage:"):
        lines = [ln for ln in lines if ln.startswith("tvsctl")]
    return lines


def judge(res: dict[str, object]) -> str:
    outs = [res["json"], res["human"]]
    classes = []
    for mode, o in zip(("json", "human"), outs, strict=True):
        assert isinstance(o, dict)
        rc, err = o["rc"], o["stderr"]
        if rc == "hang":
            return f"FAIL: hang ({mode})"
        if any(f in err for f in FORBIDDEN):
            return f"FAIL: exit {rc}, forbidden text on stderr ({mode})"
        if rc == 0:
            classes.append(f"verdict {o['cause']}" if mode == "json" else "verdict")
        elif rc == 2:
            if len(message_lines(err)) != 1:
                return f"FAIL: exit 2 with {len(message_lines(err))} message lines ({mode})"
            classes.append("refused")
        else:
            return f"FAIL: exit {rc} ({mode})"
    if classes[0].split()[0] != classes[1]:
        return f"FAIL: json {classes[0]} but human {classes[1]}"
    got = classes[0]
    if res["expect"] == "verdict" and got == "refused":
        return "FAIL: refused a valid (or repairable) file"
    if res["expect"] == "refuse" and got.startswith("verdict"):
        return f"FAIL: {got} on a bad file"
    return got


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("/tmp/analyze_fuzz"))
    ap.add_argument("--base", type=Path, help="a valid recording (default: tvsctl sim record --seconds 8)")
    ap.add_argument("--bench", type=Path, help="a second valid recording: the format variants only")
    ap.add_argument("--only", help="run the variants whose name contains this text")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--tvsctl",
        help="run this tvsctl as a subprocess (another worktree's: a before); "
        "default: this tree's, in-process in pool workers (one import, not one per run)",
    )
    ap.add_argument("--jsonl", type=Path, help="write each result as a JSON line here")
    a = ap.parse_args()
    base = a.base
    if base is None:
        base = a.out / "base.csv"
        a.out.mkdir(parents=True, exist_ok=True)
        subprocess.run(
            [
                TVSCTL,
                "sim",
                "record",
                "--profile",
                "steps",
                "--seconds",
                "8",
                "--seed",
                str(a.seed),
                "--out",
                str(base),
            ],
            check=True,
            capture_output=True,
        )
    vs = build(base, a.out / "v", a.seed, "", True)
    if a.bench:
        vs += build(a.bench, a.out / "b", a.seed, "bench: ", False)
    if a.only:
        vs = [v for v in vs if a.only in v.name]
    fails, results = 0, []
    pool = multiprocessing.get_context("spawn").Pool(a.workers, maxtasksperchild=20)
    with ThreadPoolExecutor(a.workers) as ex:
        for r in ex.map(lambda v: run_one(v, a.tvsctl, pool), vs):
            results.append(r)
            o = r["json"]
            assert isinstance(o, dict)
            line = (message_lines(o["stderr"]) or [""])[-1]
            fails += str(r["verdict"]).startswith("FAIL")
            print(
                f"{r['name'][:48]:48} | {r['expect']:7} | {o['rc']!s:4} | {r['verdict']!s:40} | {line[:200]}",
                flush=True,
            )
    pool.terminate()  # a hung worker, if any
    if a.jsonl:
        a.jsonl.write_text("".join(json.dumps(r) + "\n" for r in results))
    print(f"{len(results)} variants, {fails} failures")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
