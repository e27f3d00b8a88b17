"""The paper's model fitted to one recording: staged like friction identification, then IDIM-IV.

Stage 1, static map: on steady segments (|ω̇| small, moving), effort = kv·ω + τc·sgn ω [+ offset]
  gives the friction map alone, from the data, not from the config's defaults.
Stage 2, IDIM-LS: all baseline columns (J, kv, τc, Stribeck where identifiable, offset).
Stage 3, IDIM-IV: instruments from the stage-2 model simulated on the recorded command, iterated.
The static map of stage 1 is kept as a consistency check (reported beside the final values).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvsd.analysis.inverse import Columns, Fit, solve
from tvsd.analysis.simulate import ReducedModel, no_effect, simulate

IV_ITERATIONS = 2
INSTRUMENT_WINDOW_S = 0.1  # restart the instrument simulation from the measured state this often


@dataclass(frozen=True)
class Baseline:
    fit: Fit
    static: dict[str, float]  # stage 1: kv, tau_c from steady segments
    model: ReducedModel
    instrumented: bool
    ls: Fit  # stage 2, IDIM-LS: what published inverse models (EMPS) report


def reduced_model(cols: Columns, fit: Fit) -> ReducedModel:
    d = cols.prep.data
    J = fit.value("J")
    kv = fit.value("kv") if "kv" in fit.names else fit.value("kv_pos")
    tau_c = fit.value("tau_c") if "tau_c" in fit.names else fit.value("tau_c_pos")
    return ReducedModel(
        J=J if J > 0 else 1e-9,
        kv=max(kv, 0.0),
        tau_c=max(tau_c, 0.0),
        d_stribeck=max(fit.value("d_stribeck"), 0.0),
        v0=cols.v0,
        offset=fit.value("offset"),
        b_u=d.b_u,
        b_omega=d.b_omega,
    )


def static_map(cols: Columns) -> dict[str, float]:
    p = cols.prep
    w, a = p.rows(p.speed), p.rows(p.accel)
    top = float(np.max(np.abs(w))) if len(w) else 0.0
    steady = (np.abs(a) < 0.02 * max(float(np.max(np.abs(a))), 1e-12)) & (np.abs(w) > 0.05 * top)
    steady &= cols.fit_rows  # the held-out rows stay unseen, here too
    if np.count_nonzero(steady) < 20:
        return {}
    cols_static = [w[steady], np.sign(w[steady])]
    names: tuple[str, ...] = ("kv", "tau_c")
    if cols.prep.data.offset_term:
        cols_static.append(np.ones(np.count_nonzero(steady)))
        names = (*names, "offset")
    fit = solve(cols.y[steady], np.column_stack(cols_static), None, names)
    return fit.params()


def fit_baseline(cols: Columns, instruments: bool = True) -> Baseline:
    static = static_map(cols)
    cols.use_instruments(None)
    fit = ls = cols.baseline()
    d = cols.prep.data
    if instruments:
        for _ in range(IV_ITERATIONS):
            w_sim, _ = simulate(
                reduced_model(cols, fit),
                d.t,
                lagged_command(cols),
                no_effect(),
                measured_speed(cols),
                d.position,
                window_s=INSTRUMENT_WINDOW_S,
            )
            cols.use_instruments(w_sim)
            fit = cols.baseline()
    return Baseline(fit, static, reduced_model(cols, fit), instruments, ls)


def measured_speed(cols: Columns) -> np.ndarray:
    return cols.prep.speed


def lagged_command(cols: Columns, u: np.ndarray | None = None) -> np.ndarray:
    """The command as the current follows it (delayed by L/R, see dataset.py)."""
    d = cols.prep.data
    u = d.u if u is None else u
    return np.interp(d.t - d.lag_s, d.t, u) if d.lag_s > 0 else u


SCAN_WINDOW_S = 1.0  # restart period of the simulation that scores a scanned input parameter


def speed_error(cols: Columns, fit: Fit, command: np.ndarray) -> float:
    """Mean squared speed error of the model simulated from `command` on the fitting part.

    Scores a scanned parameter of an input effect (saturation, dead zone, delay): those act on
    the speed directly, and the equation error's least squares, biased by the vibration, can
    prefer a wrong threshold (a 5.1 V saturation scanned to 2.3 V; a 0.92 V dead zone to 1.45 V).
    """
    d = cols.prep.data
    w, _ = simulate(
        reduced_model(cols, fit),
        d.t,
        lagged_command(cols, command),
        no_effect(),
        measured_speed(cols),
        d.position,
        window_s=SCAN_WINDOW_S,
    )
    t_rows = cols.prep.t_rows
    fitting = d.t <= t_rows[cols.fit_rows][-1]
    measured = d.speed if d.speed is not None else cols.prep.speed
    return float(np.mean((w - measured)[fitting] ** 2))
