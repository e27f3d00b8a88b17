"""Same answers before and after a speed change of the model doctor.

    python scripts/doctor_same.py save  FILE.json [--cases N] [--dir DIR]
    python scripts/doctor_same.py check FILE.json [--dir DIR]

`save` analyses the 13 bench-dev recordings (../shared/data/bench-dev) and N seeded cases of the
randomised matrix (tvsd.analysis.matrix, open and closed loop; their recordings are written once
into DIR and reused) and keeps each JSON verdict (what `tvsctl analyze --json` prints) in FILE
(gzipped when it ends in .gz). `check` analyses the same files again and compares: the cause,
every candidate's name, the decision and every string identical; numbers equal within float
round-off (relative 1e-9, or 1e-12 absolute near zero). Exit 1 on any difference, listing them.
"""

from __future__ import annotations

import argparse
import dataclasses
import gzip
import json
import math
import sys
from pathlib import Path
from typing import Any

BENCH_DEV = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "bench-dev"
REL, ABS = 1e-9, 1e-12


def matrix_cases(n: int) -> list[Any]:
    from tvsd.analysis import matrix as M

    open_ = M.cases(n_null=50, reps=3, seed=5, profiles=M.OPEN_PROFILES)
    closed = M.cases(n_null=50, reps=3, seed=5, profiles=M.CLOSED_PROFILES)
    n_open = n - n // 3
    pick_o = open_[:: max(1, len(open_) // n_open)][:n_open]
    pick_c = closed[7 :: max(1, len(closed) // (n - n_open))][: n - n_open]
    return pick_o + pick_c


def record_case(case: Any, path: Path, seconds: float = 30.0) -> None:
    from tvsd.causes import parse_effect
    from tvsd.config import load_config
    from tvsd.sim.record import record

    cfg = load_config()
    plant = dataclasses.replace(cfg.plant, **case.plant)
    plant = dataclasses.replace(
        plant, kb=plant.kM * cfg.plant.kb / cfg.plant.kM, L=cfg.plant.L * plant.R / cfg.plant.R
    )
    sil = cfg.sil_or_default
    vib = dataclasses.replace(sil.vibration, sigma_v=case.sigma_v)
    cfg = dataclasses.replace(cfg, plant=plant, sil=dataclasses.replace(sil, vibration=vib))
    effects = (parse_effect(case.effect),) if case.effect else ()
    record(cfg, path, case.profile, seconds, effects, case.seed, rps=case.rps or 20.0)


def files(n_cases: int, work: Path, bench_dev: Path = BENCH_DEV) -> list[Path]:
    out = sorted(bench_dev.resolve().glob("d*.csv"))
    work.mkdir(parents=True, exist_ok=True)
    for case in matrix_cases(n_cases):
        path = work / f"case{case.seed}-{case.profile}-{case.cause}.csv"
        if not path.exists():
            record_case(case, path)
        out.append(path)
    return out


def verdict(path: Path) -> dict[str, Any]:
    """What `tvsctl analyze FILE --json` prints, computed the way its _run does."""
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.analysis.prep import Band
    from tvsd.analysis.summary import as_json
    from tvsd.config import load_config

    cfg = load_config()
    data = load(path, cfg)
    dg = diagnose(data, cfg.plant.v0, band=Band(), seed=0)
    return json.loads(json.dumps(as_json(dg), default=float))


def differences(a: Any, b: Any, where: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{where}: keys {sorted(set(a) ^ set(b))}"]
        return [d for k in a for d in differences(a[k], b[k], f"{where}.{k}")]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: length {len(a)} vs {len(b)}"]
        return [
            d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in differences(x, y, f"{where}[{i}]")
        ]
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        if math.isnan(a) and math.isnan(b):
            return []
        if a == b or abs(a - b) <= max(ABS, REL * max(abs(a), abs(b))):
            return []
        return [f"{where}: {a!r} vs {b!r}"]
    return [] if a == b else [f"{where}: {a!r} vs {b!r}"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mode", choices=("save", "check"))
    ap.add_argument("file", type=Path)
    ap.add_argument("--cases", type=int, default=21)
    ap.add_argument("--dir", type=Path, default=Path("/tmp/doctor-same"), help="the cases' recordings")
    ap.add_argument("--bench-dev", type=Path, default=BENCH_DEV)
    args = ap.parse_args()
    if args.mode == "save":
        out = {}
        for path in files(args.cases, args.dir, args.bench_dev):
            out[path.name] = verdict(path)
            print(path.name, out[path.name]["cause"], flush=True)
        text = json.dumps({"cases": args.cases, "verdicts": out}, indent=1)
        if args.file.suffix == ".gz":
            args.file.write_bytes(gzip.compress(text.encode()))
        else:
            args.file.write_text(text)
        return 0
    raw = args.file.read_bytes()
    saved = json.loads(gzip.decompress(raw) if args.file.suffix == ".gz" else raw)
    bad = 0
    for path in files(saved["cases"], args.dir, args.bench_dev):
        diff = differences(saved["verdicts"][path.name], verdict(path))
        print(path.name, "same" if not diff else f"{len(diff)} DIFFERENCES", flush=True)
        for d in diff[:10]:
            print("   ", d)
        bad += bool(diff)
    print(f"{bad} file(s) differ of {len(saved['verdicts'])}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
