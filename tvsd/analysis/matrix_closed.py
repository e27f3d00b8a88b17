"""The closed-loop family of the matrix (tvsd.analysis.matrix), run per cause at chosen sizes and
analysed by several variants of the doctor on the same files, resumably, into a JSON-lines file.

Why a module of its own: a closed-loop case costs a 30 s closed-loop simulation and ≈ 4 s of
analysis per variant on an idle core; on a shared machine a batch of 300 runs for an hour or more,
so each case's outcome is appended as it comes (a batch stopped half way keeps what it did, a
restart skips it), and the cases are ordered round by round (every cause and size once, then the
next repetition) so a partial batch is balanced.

Variants: `ls` (least squares, the doctor's default), `iv` (two-stage least squares with the
reference and, when recorded, identify's voltage excitation `u_exc` as instruments),
`iv_ref` (the reference alone, as before u_exc was recorded), `ls0` (least squares as before this
branch: every fold in the out-of-sample check, crossval.heldout_gain; the line scan off the
command's lines), `ls1` (the folds' rule on, the lines still the command's), `ls2` (the
instrumented confirmation with rules.identified_only and expected_maps: branch cldz), `lsm`
(the clip confirmed on main's instrumented design, as before branch closedsat), `lsd` (the drift
confirmed along the identified directions too), `lss` (the clip's confirmation on rows from the
spin-up's end: instrument.steady_start's spin_only); both measured and left off
(docs/measurements/closedsat.md). Each is a frozen `Variant` (VARIANTS) whose rules
(tvsd.analysis.rules) diagnose() gets explicitly. (`lscf`, the drift confirmed with a control
function, was measured and removed: docs/measurements/closedfix.md.)

    python -m tvsd.analysis.matrix_closed OUT.jsonl [--reps 15] [--nulls 30] [--sizes 3,10]
        [--seed 0] [--worker 0 --workers 1] [--variants ls,iv] [--reversal]
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
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.analysis import matrix as M
from tvsd.analysis.rules import DEFAULT, Rules
from tvsd.causes import Effect, parse_effect
from tvsd.config import Config, load_config


@dataclasses.dataclass(frozen=True)
class Variant:
    """One way of running the doctor on the matrix's files: its rules, 2SLS as the whole
    analysis (`iv`), and whether identify's PRBS column is hidden from it (the reference alone)."""

    rules: Rules = DEFAULT
    iv: bool = False
    reference_only: bool = False


VARIANTS: dict[str, Variant] = {
    "ls": Variant(),
    "lsm": Variant(Rules(identified_for=(), expected_for=(), spin_only_for=())),
    "lsd": Variant(Rules(identified_for=(*DEFAULT.identified_for, "drift"))),
    "lss": Variant(Rules(spin_only_for=("saturation",))),
    "ls0": Variant(Rules(skip_undetermined_folds=False, lines_of_reference=False)),
    "ls1": Variant(Rules(lines_of_reference=False)),
    "ls2": Variant(Rules(identified_only=True, expected_maps=True)),
    "iv": Variant(iv=True),
    "iv_ref": Variant(iv=True, reference_only=True),
}


def plan(n_null: int, reps: int, sizes: tuple[float, ...], seed: int) -> list[M.Case]:
    """Round by round: in each of `reps` rounds every cause at every size once, and its share of
    the nulls; each case draws its plant, σv (cycling), scanning speed and effect from its index."""
    cfg = load_config()
    names = tuple(M._effects(cfg.plant, cfg.drive.u_max_v, np.random.default_rng(0)))
    order: list[tuple[str, float]] = []
    per_round = -(-n_null // max(reps, 1))
    nulls_left = n_null
    for _ in range(reps):
        order += [(c, m) for c in names for m in sizes]
        k = min(per_round, nulls_left)
        order += [("none", 0.0)] * k
        nulls_left -= k
    order += [("none", 0.0)] * nulls_left
    return [
        _case(cfg, np.random.default_rng([seed, 7, k]), 10_000 * seed + k, cause, m, M.SIGMAS[k % 3])
        for k, (cause, m) in enumerate(order)
    ]


def _case(cfg: Config, g: np.random.Generator, index: int, cause: str, m: float, sigma: float) -> M.Case:
    """One closed-loop case: a plant drawn from the family, its cause at m × the base, σv."""
    plant = M._plant(cfg, g)
    text, torque = None, math.nan
    if cause != "none":
        text, torque = M._effects(plant, cfg.drive.u_max_v, g)[cause](m)
    units = torque / (plant.J * sigma) if math.isfinite(torque) else math.nan
    if cause == "colored_noise":  # the null's spectrum below the corner (matrix.coloured_sigma)
        sigma = M.coloured_sigma(sigma, m * M.COLOUR_TAU_S)
    p = {k2: getattr(plant, k2) for k2 in ("J", "kv", "R", "kM", "tau_c")}
    rps = M.scan_rps(plant, cfg.drive.u_max_v)
    return M.Case(index, cause, m, units, text, "identify", sigma, p, rps)


def round_length(n_null: int, reps: int, sizes: tuple[float, ...]) -> int:
    cfg = load_config()
    names = M._effects(cfg.plant, cfg.drive.u_max_v, np.random.default_rng(0))
    return len(names) * len(sizes) + -(-n_null // max(reps, 1))


def plan_cells(reps: int, sizes: tuple[float, ...], seed: int, nulls: int = 1) -> list[M.Case]:
    """The per-cause plan (as matrix_open.plan, closed loop): `reps` rounds of every cause at every
    size once and `nulls` nulls; the i-th case of a cause and size (offset by its place in the
    round) has σv = SIGMAS[i % 3], so any three consecutive ones of a cell hold every σv. (`plan`
    cycles σv over the whole order: with a round length divisible by 3 a cell kept one σv.)"""
    cfg = load_config()
    names = tuple(M._effects(cfg.plant, cfg.drive.u_max_v, np.random.default_rng(0)))
    order: list[tuple[str, float, int]] = []
    count: Counter[tuple[str, float]] = Counter()
    for _ in range(reps):
        for j, key in enumerate([(c, m) for c in names for m in sizes] + [("none", 0.0)] * nulls):
            order.append((*key, count[key] + j))
            count[key] += 1
    return [
        _case(cfg, np.random.default_rng([seed, 13, k]), 10_000 * seed + k, cause, m, M.SIGMAS[i % 3])
        for k, (cause, m, i) in enumerate(order)
    ]


def case_config(case: M.Case, identify: dict[str, Any] | None = None) -> Config:
    cfg = M.case_config(load_config(), case)
    if identify:
        given: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in identify.items()}
        cfg = dataclasses.replace(cfg, identify=dataclasses.replace(cfg.identify, **given))
    return cfg


def analyse(path: Path, cfg: Config, variant: str) -> tuple[str, float, dict[str, Any]]:
    """What the variant named, its time, and why (each cause's z, the threshold, a mismatch's
    reason): the confusion table's raw material."""
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose

    t0 = time.perf_counter()
    why: dict[str, Any] = {}
    how = VARIANTS[variant]
    try:
        data = load(path, cfg)
        if how.reference_only:
            data = dataclasses.replace(data, refs={k: v for k, v in data.refs.items() if k != "u_exc"})
        dg = diagnose(data, cfg.plant.v0, iv=how.iv, rules=how.rules)
        found = dg.cause
        why = {
            "z": {s.cause: round(float(s.z), 3) for s in dg.ranked},
            "threshold": round(float(dg.outcome.threshold), 3),
            "reason": dg.reason,
            # which check refused a cause (verdict.WHY's codes): the gate, a refit, the instruments
            "why_not": {s.cause: s.why_not[0] for s in dg.ranked if s.why_not},
        }
    except Exception as exc:  # a bad case is a result too (reported, not hidden)
        found = f"error: {type(exc).__name__}: {exc}"[:160]
    return found, time.perf_counter() - t0, why


def sized(
    case: M.Case, cfg: Config, tmp: Path, seconds: float, keep: bool = False, exposed_deadzone: bool = False
) -> M.Case:
    """A closed-loop saturation set where the command is: the case recorded without it (same
    seed: same noise and excitation) gives the command, and u_max sits m × 1 % below its 99 %
    quantile, as in open loop (matrix.saturation_size). From the drive limit, 0.97–0.90 ×
    u_max lay above every command of a scanning plant held with ≤ 40 % of the drive. `keep`: the
    pilot stays in `tmp` (a cache) and is reused. `exposed_deadzone` (`--exposed-deadzone`, opt-in,
    not measured yet): a dead zone sized by what the pilot exposes, not by u_max
    (docs/measurements/cldz.md: 0.4 % of u_max per 1× gave 0–80 exposed noise units)."""
    if case.cause != "saturation" and not (case.cause == "deadzone" and exposed_deadzone):
        return case
    from tvsd.sim.record import record

    pilot = tmp / f"pilot{case.seed}.csv"
    if not (keep and pilot.exists()):
        record(cfg, pilot, "identify", seconds, (), case.seed, rps=case.rps)
    from tvsd.analysis.dataset import load

    data = load(pilot, cfg)
    u = data.u
    if not keep:
        pilot.unlink()
    if case.cause == "deadzone":
        omega = data.speed if data.speed is not None else np.gradient(data.position, data.t)
        b_u = cfg.plant.kM * cfg.plant.ku / cfg.plant.R
        u0, torque = deadzone_size(u, omega, case.size * 0.5 * cfg.plant.J / b_u)
        units = torque * b_u / (cfg.plant.J * case.sigma_v)
        return dataclasses.replace(case, effect=f"deadzone:u0={u0:.6g}", noise_units=units)
    u_max, excess = M.saturation_size(u, case.size)
    units = excess * cfg.plant.kM * cfg.plant.ku / cfg.plant.R / (cfg.plant.J * case.sigma_v)
    return dataclasses.replace(case, effect=f"saturation:u_max={u_max:.6g}", noise_units=units)


def deadzone_size(u: np.ndarray, omega: np.ndarray, target_v: float) -> tuple[float, float]:
    """The narrowest zone u0 whose torque beyond a Coulomb level (exposure.beyond_coulomb, in
    volts of command) on this command reaches `target_v`, and what it reaches: the torque causes'
    base (m × 0.5·J N·m) in the dead zone's exposed units. Zones up to half the command's 99 %
    point: wider ones stop the drive (a 12 V zone on a 12 V drive: model_mismatch) or lie past
    the doctor's scan (design.py: up to half the largest command). Where none reaches the
    target, the widest, and the row's exposed_units says what it shows."""
    from tvsd.analysis.exposure import MOVING_RAD_S, beyond_coulomb

    moving = np.abs(omega) > MOVING_RAD_S
    top = 0.5 * float(np.quantile(np.abs(u), 0.99)) if len(u) else 0.0
    lo, hi = 0.0, top
    if beyond_coulomb(u, omega, hi, moving) < target_v:
        return hi, beyond_coulomb(u, omega, hi, moving)
    for _ in range(40):  # the exposed torque grows with u0 (more of the command inside)
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if beyond_coulomb(u, omega, mid, moving) < target_v else (lo, mid)
    return hi, beyond_coulomb(u, omega, hi, moving)


def seen(path: Path, case: M.Case, cfg: Config) -> dict[str, float]:
    """tvsd.analysis.exposure's measures of the case's effect on the recording the doctor got; a
    clip's exposed units on the rows and columns of its confirmation (the default rules').
    """
    from tvsd.analysis.dataset import load
    from tvsd.analysis.exposure import confirmation_baseline, exposure

    data = load(path, cfg)
    omega = data.speed if data.speed is not None else np.gradient(data.position, data.t)
    dt = 1.0 / data.sample_rate_hz
    baseline = confirmation_baseline(data) if case.cause == "saturation" else None
    return exposure(case.effect, data.u, omega, cfg.plant, case.sigma_v, dt, baseline)


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
