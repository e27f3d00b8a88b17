"""The open-loop family of the matrix (tvsd.analysis.matrix) per cause and size, resumably, into
JSON lines, and the per-cause limits read from it (issue 12, item 5).

Each case draws its plant as matrix.cases does (J, kv, τc, R, kM log-uniform over ÷√10…×√10 of
the config's), its excitation (staircase or PRBS/multisine) and σv stratified: the i-th case of a cause
and size (offset by its place in the round) has σv = SIGMAS[i % 3] and profile i % 2, so any six
consecutive ones hold every pair, and its effect at m × the
matrix's base (saturation and delay sized on the case's own command). Rounds: every cause at
every size once, then the next; a size in `--thin` (1× by default) only every other round; one
null per round. Each case's row is appended as it comes (a batch cut short keeps what it did, a
restart skips it) with its effect measured on its recording (tvsd.analysis.exposure: `seen`) and
why the doctor answered (each cause's z, the threshold: tvsd.analysis.confusion's raw material).

    nice -n 5 python -m tvsd.analysis.matrix_open OUT.w0.jsonl --reps 8 --seed 31 --worker 0 --workers 2
    python -m tvsd.analysis.matrix_open 'OUT.w*.jsonl' --summary [--json]   # the per-cause limits
    python -m tvsd.analysis.matrix_open 'OUT.w*.jsonl' --confusion          # what was named instead

The stated limit of a cause is the lowest size from which naming is ≥ 95 % at that size and at
every larger one (and the 90 % one likewise), with the rate over all cases from there up and its
95 % Clopper–Pearson interval.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import glob
import json
import math
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.analysis import matrix as M
from tvsd.analysis.matrix_limits import limits, nulls, table
from tvsd.causes import Effect, parse_effect
from tvsd.config import load_config


def causes() -> tuple[str, ...]:
    cfg = load_config()
    return tuple(M._effects(cfg.plant, cfg.drive.u_max_v, np.random.default_rng(0)))


def plan(
    reps: int, sizes: tuple[float, ...], seed: int, thin: tuple[float, ...] = (1.0,), nulls: int = 1
) -> list[M.Case]:
    """`reps` rounds; sizes in `thin` only in even rounds; `nulls` nulls per round."""
    cfg = load_config()
    order: list[tuple[str, float, int]] = []
    count: Counter[tuple[str, float]] = Counter()
    for r in range(reps):
        for j, key in enumerate([(c, m) for c in causes() for m in sizes] + [("none", 0.0)] * nulls):
            if key[1] in thin and r % 2:
                continue
            order.append((*key, count[key] + j))  # j: a round's cases do not share σv and profile
            count[key] += 1
    dt = 1.0 / cfg.control.rate_hz
    out = []
    for k, (cause, m, i) in enumerate(order):
        g = np.random.default_rng([seed, 11, k])
        plant = M._plant(cfg, g)
        sigma = M.SIGMAS[i % 3]
        profile = M.OPEN_PROFILES[i % 2]
        case_seed = 10_000 * seed + k
        text, torque = None, math.nan
        if cause != "none":
            command = None
            if cause in ("saturation", "delay"):
                command = M.open_loop_command(cfg, profile, 30.0, case_seed)
            text, torque = M._effects(plant, cfg.drive.u_max_v, g, command, dt)[cause](m)
        units = torque / (plant.J * sigma) if math.isfinite(torque) else math.nan
        if cause == "colored_noise":  # the null's spectrum below the corner (matrix.coloured_sigma)
            sigma = M.coloured_sigma(sigma, m * M.COLOUR_TAU_S)
        p = {k2: getattr(plant, k2) for k2 in ("J", "kv", "R", "kM", "tau_c")}
        out.append(M.Case(case_seed, cause, m, units, text, profile, sigma, p, 0.0))
    return out


def _no_gain() -> None:
    """Skip the held-out speed simulation: it runs after the cause is decided (doctor.py) and
    changes no answer; it is a third of an analysis's CPU (scripts/doctor_nulls.py --no-gain)."""
    from tvsd.analysis import heldout_sim

    heldout_sim.heldout_speed = lambda *_a, **_k: (math.nan, math.nan, {}, {})


@contextlib.contextmanager
def heldout_gain_skipped() -> Iterator[None]:
    """`_no_gain` for the duration of a block, then the held-out simulation back (a test or a
    library call that skipped it left every later analysis in the process without it)."""
    from tvsd.analysis import heldout_sim

    saved = heldout_sim.heldout_speed
    _no_gain()
    try:
        yield
    finally:
        heldout_sim.heldout_speed = saved


def run(out: Path, cases: list[M.Case], cache: Path | None = None, seconds: float = 30.0) -> None:
    with heldout_gain_skipped():
        _run(out, cases, cache, seconds)


def _run(out: Path, cases: list[M.Case], cache: Path | None, seconds: float) -> None:
    from tvsd.analysis.closed_judge import analyse, seen
    from tvsd.sim.record import record

    done = (
        {json.loads(x)["seed"] for x in out.read_text().splitlines() if x.strip()} if out.exists() else set()
    )
    with tempfile.TemporaryDirectory() as tmp:
        folder = cache or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for case in cases:
            if case.seed in done:
                continue
            cfg = M.case_config(load_config(), case)
            path = folder / f"{case.profile}-{case.seed}.csv"
            t0 = time.perf_counter()
            if not path.exists():
                effects: tuple[Effect, ...] = (parse_effect(case.effect),) if case.effect else ()
                part = path.with_suffix(".part")
                record(cfg, part, case.profile, seconds, effects, case.seed)
                part.rename(path)
            row: dict[str, Any] = {**dataclasses.asdict(case), "record_s": time.perf_counter() - t0}
            row["seen"] = seen(path, case, cfg)
            row["ls"], row["ls_s"], row["ls_why"] = analyse(path, cfg, "ls")
            with out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            if cache is None:
                path.unlink()


def identifiable(row: dict[str, Any]) -> bool:
    """Whether the case's recording can show its cause as such. A torque periodic N times per
    revolution (imbalance N = 1, cogging N = its order) shows its period only where the angle
    spans ≥ 1/N of a turn: over less, the once- and N-per-revolution blocks are both smooth
    functions of the arc, and which of the two the doctor names (it names one: the torque is
    there) is not a finding (30× imbalances on weak plants, trapped like a pendulum, spanning
    0.20 and 0.47 of a turn: `cogging` at z 13.0 and 32.2 beside `imbalance` at 11.7 and 30.9).
    Scored apart only when the doctor named an angle-periodic cause; any other answer is a miss."""
    cause = row.get("cause")
    if cause not in ("imbalance", "cogging") or row.get("ls") not in ("imbalance", "cogging"):
        return True
    order = 1.0
    if cause == "cogging" and row.get("effect"):
        order = float(parse_effect(row["effect"]).params.get("order", 1.0))
    revolutions = row.get("seen", {}).get("revolutions")
    return revolutions is None or revolutions >= 1.0 / order


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--reps", type=int, default=8)
    ap.add_argument("--sizes", default="1,3,10,30")
    ap.add_argument("--thin", default="1", help="sizes run only every other round")
    ap.add_argument("--nulls", type=int, default=1, help="nulls per round")
    ap.add_argument("--seed", type=int, default=31)
    ap.add_argument("--worker", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--causes", default="", help="only these causes (and the nulls)")
    ap.add_argument("--cache", type=Path, help="keep (and reuse) the recordings here")
    ap.add_argument("--summary", action="store_true", help="print the per-cause limits")
    ap.add_argument("--json", action="store_true", help="--summary as JSON")
    ap.add_argument("--confusion", action="store_true", help="print the confusion table")
    a = ap.parse_args()
    if a.summary or a.confusion:  # OUT may be a glob (the workers' files together)
        files = [Path(f) for f in sorted(glob.glob(str(a.out)))] or [a.out]
        rows = [json.loads(x) for f in files for x in f.read_text().splitlines() if x.strip()]
        apart = [r for r in rows if not identifiable(r)]
        rows = [r for r in rows if identifiable(r)]
        if apart:
            said = [
                f"{r['seed']} {r['cause']} {r['size']:g}x {r['seen']['revolutions']:.2f} rev -> {r['ls']}"
                for r in apart
            ]
            print(f"scored apart (not identifiable): {len(apart)}: " + ", ".join(said))
        if a.confusion:
            from tvsd.analysis.confusion import table as confusion

            print(confusion(rows, "ls"))
        elif a.json:
            print(json.dumps({"limits_95": limits(rows), "limits_90": limits(rows, 0.9), **nulls(rows)}))
        else:
            print(table(rows))
        return
    sizes = tuple(float(x) for x in a.sizes.split(","))
    thin = tuple(float(x) for x in a.thin.split(",") if x)
    todo = plan(a.reps, sizes, a.seed, thin, a.nulls)
    if a.causes:
        keep = set(a.causes.split(",")) | {"none"}
        todo = [c for c in todo if c.cause in keep]
    run(a.out, [c for k, c in enumerate(todo) if k % a.workers == a.worker], a.cache)


if __name__ == "__main__":
    main()
