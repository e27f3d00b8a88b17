"""Seed 52, case 128 (a closed-loop null) with the closed-loop colour on (default) and off, and
what test_doctor_nulls asserted before and after memflake (memflake.md, section 2):

    PY scripts/memflake_null520128.py
"""

import tempfile
from pathlib import Path

from tvsd.analysis import matrix
from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.rules import DEFAULT, Rules
from tvsd.config import load_config
from tvsd.sim.record import record


def main() -> None:
    case = matrix.cases(n_null=129, reps=0, seed=52, profiles=matrix.CLOSED_PROFILES)[128]
    cfg = matrix.case_config(load_config(), case)
    path = Path(tempfile.mkdtemp()) / "null.csv"
    record(cfg, path, case.profile, 30.0, (), case.seed, rps=case.rps or 20.0)
    for name, rules in (
        ("default (closed colour on)", DEFAULT),
        ("closed_colour off", Rules(closed_colour=False)),
    ):
        dg = diagnose(load(path, cfg), cfg.plant.v0, rules=rules)
        named = [c.cause for c in dg.causes]
        top = dg.outcome.tested[0]
        old = dg.cause == "colored_noise" and "delay" not in named
        new = dg.cause != "delay" and "delay" not in named
        print(
            f"{name}: answer {dg.cause}, causes {named}, top tested {top.cause} z {top.z:.1f} "
            f"(gate {dg.outcome.threshold:.2f}); old assert {'passes' if old else 'FAILS'}, "
            f"new assert {'passes' if new else 'FAILS'}"
        )


if __name__ == "__main__":
    main()
