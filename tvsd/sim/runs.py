"""Offline simulation runs on the drive model: step responses, spin-ups, open-loop inputs.

Each run starts from a `Setup` (tvsd.control.setup) and returns a `Trace` (columns of
tvsd.sim.closed_loop's output, as named arrays). `tvsctl sim`, the benchmarks, the SIL
recordings and the model doctor all go through here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tvsd.control.layout import pack_law
from tvsd.control.setup import Setup
from tvsd.model import plant as K
from tvsd.sim import closed_loop as C


@dataclass(frozen=True)
class Trace:
    """A simulated run, decimated: one entry per output row (SI units)."""

    t: np.ndarray
    u: np.ndarray  # command at the row instant, V
    u_mean: np.ndarray  # mean command over the row's interval, V
    u_applied: np.ndarray  # voltage the drive applied (after effects), V
    phi: np.ndarray
    omega: np.ndarray
    omega_mean: np.ndarray  # mean speed over the row's interval
    current: np.ndarray
    disturbance: np.ndarray  # mean disturbance acceleration about the SA axis, rad/s²
    phi_ref: np.ndarray
    slips: int = 0

    @property
    def sample_rate_hz(self) -> float:
        return float(1.0 / (self.t[1] - self.t[0])) if len(self.t) > 1 else math.nan


def controller(setup: Setup, mode: int, ref: float) -> np.ndarray:
    """The closed-loop kernel's controller array for `setup` in `mode` (reference: rad or rev/s)."""
    ctrl = np.zeros(C.N_CTRL)
    pack_law(ctrl, setup, mode, ref)
    ctrl[C.C_DIV] = setup.substeps
    return ctrl


def _run(
    setup: Setup,
    mode: int,
    ref: float,
    n_periods: int,
    decim: int,
    u_in: np.ndarray | None = None,
    state: np.ndarray | None = None,
    exc: np.ndarray | None = None,
) -> Trace:
    """Run n_periods controller periods; one output row every `decim` periods."""
    out = np.zeros((n_periods // decim, C.N_OUT))
    st = np.zeros(K.N_STATE) if state is None else state
    u = np.zeros(1) if u_in is None else np.ascontiguousarray(u_in, dtype=np.float64)
    sub = setup.substeps
    slips = C.run(
        st,
        setup.plant,
        setup.effects,
        setup.vibration,
        controller(setup, mode, ref),
        setup.dt / sub,
        n_periods * sub,
        u,
        np.zeros((0, 2)) if exc is None else np.ascontiguousarray(exc, dtype=np.float64),
        decim * sub,
        setup.seed,
        out,
    )
    return Trace(
        t=out[:, C.O_T],
        u=out[:, C.O_U],
        u_mean=out[:, C.O_U_MEAN],
        u_applied=out[:, C.O_UAPP],
        phi=out[:, C.O_PHI],
        omega=out[:, C.O_OMEGA],
        omega_mean=out[:, C.O_OMEGA_MEAN],
        current=out[:, C.O_I],
        disturbance=out[:, C.O_DIST_MEAN],
        phi_ref=out[:, C.O_PHI_REF],
        slips=int(slips),
    )


def step_response(setup: Setup, ref_rad: float, seconds: float) -> Trace:
    """Position mode from rest at φ = 0 to φr (paper Table 6, Figs. 14–16); full-rate output."""
    return _run(setup, C.MODE_POSITION, ref_rad, round(seconds / setup.dt), 1)


def spin(setup: Setup, rps: float, seconds: float, decim: int = 1) -> Trace:
    """Scanning mode from rest: the speed reference ramps to `rps` and the law tracks it."""
    return _run(setup, C.MODE_SCAN, rps, round(seconds / setup.dt), decim)


def spin_excited(setup: Setup, rps: float, seconds: float, exc: np.ndarray, decim: int = 1) -> Trace:
    """Scanning mode from rest to `rps`, with `exc` (one row per controller period: rev/s added to
    the speed target, volts added to the command) played on top, as `tvsctl identify` does."""
    return _run(setup, C.MODE_SCAN, rps, round(seconds / setup.dt), decim, exc=exc)


def open_loop(
    setup: Setup, u_per_period: np.ndarray, decim: int = 1, state: np.ndarray | None = None
) -> Trace:
    """Apply a given voltage command, one value per controller period (setup.dt)."""
    return _run(setup, C.MODE_OPEN, 0.0, len(u_per_period), decim, u_per_period, state)
