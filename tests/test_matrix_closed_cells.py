"""The closed-loop matrix's per-cause plan and its limits table (tvsd.analysis.matrix_closed
--cells; issue 12, item 5). Fast: the plan is drawn (no recording), the table read from rows made
here."""

from __future__ import annotations

from collections import Counter

from tvsd.analysis import matrix as M
from tvsd.analysis import matrix_limits as L
from tvsd.analysis.closed_plan import plan_cells
from tvsd.analysis.matrix_open import causes


def test_every_cell_holds_every_vibration_level_and_the_draws_are_seeded():
    p = plan_cells(6, (3.0, 10.0, 30.0), seed=71, nulls=3)
    assert len({c.seed for c in p}) == len(p) == 6 * (9 * 3 + 3)
    n = Counter((c.cause, c.size) for c in p)
    for cause in causes():
        for m in (3.0, 10.0, 30.0):
            assert n[(cause, m)] == 6
            if cause != "colored_noise":  # its σv is rescaled to its colour (matrix.coloured_sigma)
                got = Counter(c.sigma_v for c in p if c.cause == cause and c.size == m)
                assert got == {s: 2 for s in M.SIGMAS}, (cause, m, got)
    assert Counter(c.sigma_v for c in p if c.cause == "none") == {s: 6 for s in M.SIGMAS}
    assert all(c.profile == "identify" and 1.5 <= c.rps <= M.CLOSED_RPS for c in p)
    assert plan_cells(6, (3.0, 10.0, 30.0), seed=71, nulls=3) == p != plan_cells(6, (3.0,), seed=72)


def test_the_limits_table_reads_any_variants_answers():
    """The same rows judged by two variants: the table and the nulls follow the key asked for."""
    rows = [
        {"cause": "delay", "size": m, "noise_units": m, "seen": {}, "profile": "identify", "sigma_v": 0.08,
         "ls": "delay", "iv": "delay" if m > 3 else "none"}
        for m in (3.0, 10.0) for _ in range(10)
    ]  # fmt: skip
    rows.append({"cause": "none", "size": 0.0, "noise_units": float("nan"), "ls": "none", "iv": "resonance"})
    assert L.limits(rows, 0.95, "ls")["delay"]["limit_size"] == 3.0
    assert L.limits(rows, 0.95, "iv")["delay"]["limit_size"] == 10.0
    assert L.nulls(rows, "ls")["false_alarms"] == 0 and L.nulls(rows, "iv")["named"] == {"resonance": 1}
    assert "nulls: 1/1 false alarms" in L.table(rows, "iv")
