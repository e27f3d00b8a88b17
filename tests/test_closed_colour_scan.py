"""Why the closed-loop colour is judged only with identify's excitation (u_exc): a SIL scan's
residual is coloured by one command step, not by its plant (docs/measurements/closedcolour3.md).

tests/data/walk's `make run` recording (nothing hidden, white vibration): 25 rev/s, a ramp to
20 and back at 10 rev/s². With the colour judged on any moving reference (rules.closed_colour_u_exc
off, the rule before closedcolour2) it is named `colored_noise`. Its constant first 20.6 s are
white; the same window 80 ms longer, over the ramp's first corner (the feed-forward's 5.3 V step),
is coloured far above the gate: the input coefficients the loop's own answer to the noise set
(a₀ ≈ 189, a₁ ≈ −178 for a gain of 11.7; an identify export's ≈ 23, −12) turn one exogenous
step into a residual spike the low-pass shape fits."""

from __future__ import annotations

import dataclasses
import gzip
import shutil
from pathlib import Path

import pytest

from tvsd.analysis.dataset import Dataset, load
from tvsd.analysis.doctor import COLOUR_P, diagnose
from tvsd.analysis.rules import DEFAULT
from tvsd.analysis.window import cut
from tvsd.config import Config, load_config

WALK = Path(__file__).parent / "data" / "walk" / "make-run-realtime-47s.csv.gz"
WIDE = dataclasses.replace(DEFAULT, closed_colour_u_exc=False)
CORNER_S = 20.636  # the ramp's first corner: u_ff 5.92 → 0.58 V


@pytest.fixture(scope="module")
def walk(tmp_path_factory: pytest.TempPathFactory) -> tuple[Dataset, Config]:
    out = tmp_path_factory.mktemp("scan") / "make-run-realtime-47s.csv"
    with gzip.open(WALK, "rb") as src, out.open("wb") as dst:
        shutil.copyfileobj(src, dst)
    cfg = load_config()
    return load(out, cfg), cfg


def _colour(data: Dataset, cfg: Config) -> tuple[str, float, tuple[str, str] | None]:
    dg = diagnose(data, cfg.plant.v0, rules=WIDE)
    c = next(s for s in dg.ranked if s.cause == "colored_noise")
    return dg.cause, c.p, c.why_not


@pytest.mark.slow
def test_a_scan_without_u_exc_is_coloured_only_under_the_wide_rule(walk: tuple[Dataset, Config]) -> None:
    data, cfg = walk
    default = diagnose(data, cfg.plant.v0)
    assert default.cause == "none"
    c = next(s for s in default.ranked if s.cause == "colored_noise")
    assert c.why_not is not None and c.why_not[0] == "closed_loop_colour"
    cause, p, _ = _colour(data, cfg)
    assert cause == "colored_noise" and p < COLOUR_P


@pytest.mark.slow
def test_the_scans_colour_comes_with_its_first_command_step(walk: tuple[Dataset, Config]) -> None:
    """Constant reference up to the corner: the ratio under χ²₁'s 1e-3 level (measured 0.0, the
    boundary law's atom); 64 ms past it: above (measured 114). The colour test runs whether or not
    the colour is judged (why_not tells), so both windows are read with the same test."""
    data, cfg = walk
    before, _ = cut(data, None, CORNER_S - 0.016)
    _, p_before, why = _colour(before, cfg)
    assert p_before >= COLOUR_P and why is not None and why[0] == "closed_loop_colour"
    after, _ = cut(data, None, CORNER_S + 0.064)
    _, p_after, _ = _colour(after, cfg)
    assert p_after < COLOUR_P
