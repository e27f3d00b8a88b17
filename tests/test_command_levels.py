"""A drive's static error per held command level is not the vibration's colour
(tvsd.analysis.command_levels, applied in quantisation.gated before the spectral tests)."""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter
from scipy.stats import binom

from tvsd.analysis import quantisation as Q
from tvsd.analysis.dataset import ROTARY, Dataset
from tvsd.analysis.noise import COLOUR_P, analyse
from tvsd.analysis.prep import Band, prepare

FS = 1000.0


def _staircase(g: np.random.Generator, n: int) -> np.ndarray:
    """The outsider bench's open-loop staircase: levels held 1–3 s, both directions."""
    levels, holds = [], []
    while sum(holds) < n:
        levels.append(g.choice([-1.0, 1.0]) * g.uniform(0.2, 1.0) * 3.5)
        holds.append(int(g.uniform(1.0, 3.0) * FS))
    return np.repeat(levels, holds)[:n]


def _case(g: np.random.Generator, pwm: bool, tau_s: float = 0.0, closed: bool = False):
    """(prepared signals, residual rows, row rate): white acceleration noise of unit level
    (OU-coloured with `tau_s` as the outsider bench colours it, + its 0.3 white floor), plus, with
    `pwm`, the torque error of an 8-bit bridge on a 4.55 V supply: each level applied rounded to
    its 35.5 mV step, a constant error per hold that the recorded command does not show."""
    n = int(30 * FS)
    u = _staircase(g, n)
    speed = np.cumsum(g.standard_normal(n)) * 0.01 + 20.0 * u  # on no count grid: no floor
    refs = {"omega_ref": 30.0 * u} if closed else {}
    data = Dataset("levels", np.arange(n) / FS, u, np.cumsum(speed) / FS, speed, FS, 1.0, 0.0, ROTARY,
                   False, refs=refs)  # fmt: skip
    prep = prepare(data, Band())
    noise = g.standard_normal(n) * np.sqrt(FS)
    if tau_s > 0:
        d = np.exp(-1.0 / (FS * tau_s))
        white = 0.3 * g.standard_normal(n) * np.sqrt(FS)
        noise = lfilter([1 - d], [1, -d], noise) * np.sqrt(2 * tau_s * FS) + white
    step = 1.3 * 3.5 / 2**7
    err = (np.round(u / step) * step - u) * 2000.0 if pwm else 0.0 * u  # b = 2000 rad/s² per V
    resid = prep.band_rows(noise + err)
    return prep, resid, FS / prep.band.decim


def _coloured(prep, resid, rate, gated: bool) -> bool:
    keep = np.ones(len(resid), dtype=bool)
    rows = Q.gated(prep, keep, resid, rate)[0] if gated else resid
    return analyse(rows, rate, 1.0, prep.band.cutoff_hz, None).colour_p < COLOUR_P


def test_a_pwms_error_per_held_level_is_not_colour() -> None:
    """12 seeded white-vibration staircases with an 8-bit bridge. Unprojected, the per-level error
    (piecewise constant: 1/f² above the holds' rate) is a low-pass shape and most are coloured;
    through gated, ≤ binomial(12, 1e-3)'s 99.9 % point (the colour gate's own rate)."""
    g = np.random.default_rng(12)
    cases = [_case(g, pwm=True) for _ in range(12)]
    raw = sum(_coloured(*c, gated=False) for c in cases)
    after = sum(_coloured(*c, gated=True) for c in cases)
    assert raw >= 9, raw  # the problem is there
    assert after <= binom.ppf(0.999, 12, COLOUR_P), after


def test_a_vibration_colour_is_still_seen_on_a_staircase() -> None:
    """A 20 ms OU colour (corner 8 Hz, in the band) on the same staircases, with the PWM's error:
    the projection takes K ≈ 20 degrees of freedom at the holds' rate (< 1 Hz) and leaves it."""
    g = np.random.default_rng(13)
    cases = [_case(g, pwm=True, tau_s=0.02) for _ in range(6)]
    assert all(_coloured(*c, gated=True) for c in cases)


def test_in_closed_loop_nothing_is_projected() -> None:
    """In closed loop the command answers the noise: a projection on its levels would take the
    noise's own part, so the rows pass as they were."""
    g = np.random.default_rng(14)
    prep, resid, rate = _case(g, pwm=True, closed=True)
    keep = np.ones(len(resid), dtype=bool)
    assert np.array_equal(Q.gated(prep, keep, resid, rate)[0], resid)


def test_levels_are_capped_in_number_not_only_in_share() -> None:
    """A long staircase of distinct levels (10 min at 1 kHz, holds of 0.3 s: 2000 levels in
    150 000 rows, within MAX_LEVEL_DOF's share) made a rows × 2000 matrix refitted by least
    squares: 4 min took 76 s and 1.6 GB, 10 min ≈ 10 GB, past what memory.check budgets. Past
    MAX_LEVELS nothing is projected, as past the share. Since the refit is piecewise (linear in
    the rows, O(K³) in the levels) 1000 levels are projected (256 was the dense refit's cap)."""
    from tvsd.analysis import command_levels as CL

    g = np.random.default_rng(15)
    n, hold = 600_000, 300
    u = np.repeat(g.uniform(-3.5, 3.5, n // hold), hold)
    rows = n // 4
    assert len(CL.held_levels(u)) <= CL.MAX_LEVEL_DOF * rows  # the share alone would allow them
    assert CL.usable_levels(u, closed=False, n_rows=rows) is None
    few = np.repeat(g.uniform(-3.5, 3.5, 40), n // 40)  # a staircase of 40 levels is still projected
    assert CL.usable_levels(few, closed=False, n_rows=rows) is not None
    many = np.repeat(g.uniform(-3.5, 3.5, 1000), n // 1000)
    assert CL.usable_levels(many, closed=False, n_rows=rows) is not None


def _dense_reference(prep, keep, residual, X, ar):  # type: ignore[no-untyped-def]
    """The projection as it was first written (integ3): dense indicator columns, GLS on [X, C]."""
    from tvsd.analysis.command_levels import usable_levels
    from tvsd.analysis.gls import gls

    u = np.asarray(prep.data.u, dtype=float)
    levels = usable_levels(u, False, len(residual))
    assert levels is not None
    C = np.column_stack([prep.band_rows((u == v).astype(float)) for v in levels])
    if X is None:
        coef, *_ = np.linalg.lstsq(C[keep], residual[keep], rcond=None)
        return np.where(keep, residual - C @ coef, residual)
    XC = np.column_stack([X, C])
    return np.where(keep, residual - XC @ gls(residual, XC, ar, keep).theta, residual)


def test_the_piecewise_projection_is_the_dense_one() -> None:
    """Seeded staircases (distinct levels; 20 levels repeated; with gaps in `keep`), refitted
    with a model whose constant column the levels' indicators nearly sum to: the piecewise
    normal equations give the dense GLS's residual. Tolerance: the normal equations square the
    design's condition number (≈ 1e4 here, the constant against the levels' sum, which differ
    only at the rows' ends), so they agree to eps·κ² ≈ 2e-8 of the change; without that
    near-collinearity (the unweighted projection) to eps·κ·√rows ≈ 1e-10."""
    from tvsd.analysis.command_levels import without_levels

    for seed, hold, repeat in [(0, 0.3, False), (1, 1.0, True), (2, 2.0, False), (3, 0.5, True)]:
        g = np.random.default_rng(seed)
        n = int(60 * FS)
        k = int(n / (hold * FS)) + 1
        lv = g.uniform(-3.5, 3.5, k)
        if repeat:
            lv = g.choice(lv[:20], k)
        u = np.repeat(lv, int(hold * FS))[:n]
        speed = 20 * u + np.cumsum(g.standard_normal(n)) * 0.01
        data = Dataset("lv", np.arange(n) / FS, u, np.cumsum(speed) / FS, speed, FS, 1.0, 0.0, ROTARY, False)
        prep = prepare(data, Band())
        rows = len(prep.t_rows)
        resid = g.standard_normal(rows) + np.repeat(g.standard_normal(rows // 100 + 1), 100)[:rows]
        keep = g.random(rows) > 0.1 if seed >= 2 else np.ones(rows, dtype=bool)
        X = np.column_stack([np.ones(rows), g.standard_normal((rows, 5)), np.zeros(rows)])
        ar = np.array([1.0, -0.3, 0.1])
        for model, tol in [((X, ar), 1e-7), ((None, None), 1e-9)]:
            ref = _dense_reference(prep, keep, resid, *model)
            new = without_levels(prep, keep, resid, *model)
            change = np.abs(resid - ref).max()
            assert np.abs(new - ref).max() <= tol * change, (seed, model[0] is None)
