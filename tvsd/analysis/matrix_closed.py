"""The closed-loop family of the matrix (tvsd.analysis.matrix), run per cause at chosen sizes and
analysed by several variants of the doctor on the same files, resumably, into a JSON-lines file.

Why a module of its own: a closed-loop case costs a 30 s closed-loop simulation and ≈ 4 s of
analysis per variant on an idle core; on a shared machine a batch of 300 runs for an hour or more,
so each case's outcome is appended as it comes (a batch stopped half way keeps what it did, a
restart skips it), and the cases are ordered round by round (every cause and size once, then the
next repetition) so a partial batch is balanced.

The cases and their order: tvsd.analysis.closed_plan; the variants of the doctor that judge each
file and what a recording exposes of its effect: tvsd.analysis.closed_judge; the tables:
tvsd.analysis.matrix (figures), tvsd.analysis.confusion, tvsd.analysis.matrix_limits.

    python -m tvsd.analysis.matrix_closed OUT.jsonl [--reps 15] [--nulls 30] [--sizes 3,10]
        [--seed 0] [--worker 0 --workers 1] [--variants ls,iv]
    python -m tvsd.analysis.matrix_closed 'OUT*.jsonl' --confusion [--variant ls]
    python -m tvsd.analysis.matrix_closed 'OUT*.jsonl' --figures      # matrix.summarise's keys

The per-cause limits (issue 12, item 5; the closed-loop counterpart of tvsd.analysis.matrix_open):
`--cells` draws the plan cell by cell (plan_cells: every cause at every size and `--nulls` nulls per
round, σv stratified per cell), `--cache DIR` keeps the recordings so a rule can be re-judged on
the same files, and `--summary` prints matrix_open's table (tvsd.analysis.matrix_limits):

    nice -n 5 python -m tvsd.analysis.matrix_closed OUT.w0.jsonl --cells --reps 8 --nulls 4 \
        --sizes 3,10,30 --seed 71 --variants ls --no-gain --cache DIR --worker 0 --workers 2
    python -m tvsd.analysis.matrix_closed 'OUT.w*.jsonl' --summary [--json] [--variant ls]
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
from pathlib import Path
from typing import Any

from tvsd.analysis import matrix as M
from tvsd.analysis.closed_judge import VARIANTS, analyse, seen
from tvsd.analysis.closed_plan import case_config, plan, plan_cells, round_length, sized
from tvsd.causes import Effect, parse_effect


def run(
    out: Path,
    cases: list[M.Case],
    variants: tuple[str, ...],
    seconds: float = 30.0,
    identify: dict[str, Any] | None = None,
    cache: Path | None = None,
    gain: bool = True,
    exposed_deadzone: bool = False,
) -> None:
    """`cache`: keep the recordings (and a clip's pilot) there and reuse them, so a rule can be
    re-judged on the same files; `gain=False` skips the held-out speed simulation, which runs after
    the cause is decided and changes no answer (matrix_open._no_gain)."""
    from tvsd.analysis.matrix_open import heldout_gain_skipped

    # A library call must not leave the doctor without its held-out simulation for later callers.
    with heldout_gain_skipped() if not gain else contextlib.nullcontext():
        _run(out, cases, variants, seconds, identify, cache, exposed_deadzone)


def _run(
    out: Path,
    cases: list[M.Case],
    variants: tuple[str, ...],
    seconds: float,
    identify: dict[str, Any] | None,
    cache: Path | None,
    exposed_deadzone: bool = False,
) -> None:
    from tvsd.sim.record import record

    done = {json.loads(line)["seed"] for line in out.read_text().splitlines()} if out.exists() else set()
    with tempfile.TemporaryDirectory() as tmp:
        folder = cache or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for case in cases:
            if case.seed in done:
                continue
            cfg = case_config(case, identify)
            keep = cache is not None
            case = sized(case, cfg, folder, seconds, keep=keep, exposed_deadzone=exposed_deadzone)
            effects: tuple[Effect, ...] = (parse_effect(case.effect),) if case.effect else ()
            path = folder / f"case{case.seed}.csv"
            t0 = time.perf_counter()
            if not path.exists():
                part = path.with_suffix(".part")
                record(cfg, part, "identify", seconds, effects, case.seed, rps=case.rps)
                part.rename(path)
            row: dict[str, Any] = {**dataclasses.asdict(case), "record_s": time.perf_counter() - t0}
            row["seen"] = seen(path, case, cfg)
            for v in variants:
                row[v], row[f"{v}_s"], row[f"{v}_why"] = analyse(path, cfg, v)
            with out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            if cache is None:
                path.unlink()


def summary(rows: list[dict[str, Any]], variant: str) -> dict[str, Any]:
    """The matrix's figures (tvsd.analysis.matrix.summarise) for one variant's answers."""
    results = []
    for r in rows:
        if variant not in r:
            continue
        case = M.Case(**{f.name: r[f.name] for f in dataclasses.fields(M.Case)})
        results.append({"case": case, "found": r[variant], "seconds": r[f"{variant}_s"]})
    return M.summarise(results, f"closed_{variant}", math.nan)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--nulls", type=int, default=30, help="nulls in all (--cells: per round)")
    ap.add_argument("--sizes", default="3,10")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--worker", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--variants", default="ls,iv")
    ap.add_argument("--causes", default="", help="only these causes (and the nulls)")
    ap.add_argument("--no-nulls", action="store_true", help="with --causes: without the nulls")
    ap.add_argument("--seeds", default="", help="only these case seeds (comma list; re-judging)")
    rounds_help = "only the plan's first N rounds (paired with a full run)"
    ap.add_argument("--rounds", type=int, default=0, help=rounds_help)
    ap.add_argument("--identify", default="", help="identify: overrides as JSON")
    ap.add_argument("--cells", action="store_true", help="the per-cause plan (plan_cells: σv per cell)")
    ap.add_argument("--cache", type=Path, help="keep (and reuse) the recordings here")
    ap.add_argument("--no-gain", action="store_true", help="skip the held-out speed simulation")
    exposed_help = "size dead zones by the torque the pilot recording exposes (deadzone_size)"
    ap.add_argument("--exposed-deadzone", action="store_true", help=exposed_help)
    ap.add_argument("--summary", action="store_true", help="print the per-cause limits (--variant's)")
    ap.add_argument("--json", action="store_true", help="--summary as JSON")
    ap.add_argument("--figures", action="store_true", help="matrix.summarise's keys per variant")
    ap.add_argument(
        "--confusion", action="store_true", help="print the confusion table (tvsd.analysis.confusion)"
    )
    ap.add_argument("--variant", default="ls", help="--summary/--confusion: which variant's answers")
    a = ap.parse_args()
    if a.summary or a.confusion or a.figures:  # OUT may be a glob (the workers' files together)
        files = [Path(f) for f in sorted(glob.glob(str(a.out)))] or [a.out]
        rows = [json.loads(line) for f in files for line in f.read_text().splitlines() if line.strip()]
        if a.confusion:
            from tvsd.analysis.confusion import table

            print(table(rows, a.variant))
        elif a.figures:
            variants = [v for v in VARIANTS if any(v in r for r in rows)]
            print(json.dumps({v: summary(rows, v) for v in variants}, indent=1, default=str))
        else:
            from tvsd.analysis import matrix_limits as L

            rows = [r for r in rows if a.variant in r]
            if a.json:
                lim = {
                    "limits_95": L.limits(rows, 0.95, a.variant),
                    "limits_90": L.limits(rows, 0.9, a.variant),
                }
                print(json.dumps({**lim, **L.nulls(rows, a.variant)}))
            else:
                print(L.table(rows, a.variant))
        return
    names = tuple(a.variants.split(","))
    unknown = [v for v in names if v not in VARIANTS]
    if unknown:
        ap.error(f"unknown variant(s) {', '.join(unknown)}: one of {', '.join(VARIANTS)}")
    sizes = tuple(float(x) for x in a.sizes.split(","))
    if a.cells:
        cases = plan_cells(a.reps, sizes, a.seed, a.nulls)
        if a.rounds:
            cases = cases[: a.rounds * (len(cases) // max(a.reps, 1))]
    else:
        cases = plan(a.nulls, a.reps, sizes, a.seed)
        if a.rounds:
            cases = cases[: a.rounds * round_length(a.nulls, a.reps, sizes)]
    if a.causes:
        keep = set(a.causes.split(",")) | (set() if a.no_nulls else {"none"})
        cases = [c for c in cases if c.cause in keep]
    if a.seeds:
        chosen = {int(x) for x in a.seeds.split(",")}
        cases = [c for c in cases if c.seed in chosen]
    mine = [c for k, c in enumerate(cases) if k % a.workers == a.worker]
    ident = json.loads(a.identify) if a.identify else None
    dz = a.exposed_deadzone
    run(a.out, mine, names, identify=ident, cache=a.cache, gain=not a.no_gain, exposed_deadzone=dz)


if __name__ == "__main__":
    main()
