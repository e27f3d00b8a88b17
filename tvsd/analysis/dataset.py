"""What the model doctor analyses: one drive recording, rotary or linear, in SI units.

Sources: the recording CSV of DESIGN.md (SIL recordings, the daemon's exports) and the EMPS
benchmark's .mat files (a linear axis: metres, newtons; Janot, Gautier & Brunot 2019).

The doctor works on the mechanical equation with a known input gain:
    J·ω̇ = b_u·u − b_ω·ω − friction(ω) + unknown torques
For the scanning aperture's DC motor b_u = kM·ku/R and b_ω = kM·kb/R, taken from the config, and
the current follows the command with the electrical time constant L/R = 0.12 ms: far below a
sample, it acts as a delay of L/R (left out, a noise-free recording shows it as a 0.11 ms
`delay`). For EMPS b_u = gτ (N/V), b_ω = 0, no lag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.analysis import count_grid, timing
from tvsd.config import Config
from tvsd.errors import DataFileError
from tvsd.recording.csvfile import read as read_recording


@dataclass(frozen=True)
class Units:
    position: str
    speed: str
    accel: str
    effort: str  # torque or force
    inertia: str
    axis: str  # "rotary" or "linear"


ROTARY = Units("rad", "rad/s", "rad/s²", "N·m", "kg·m²", "rotary")
LINEAR = Units("m", "m/s", "m/s²", "N", "kg", "linear")


@dataclass(frozen=True)
class Dataset:
    name: str
    t: np.ndarray
    u: np.ndarray  # command, V
    position: np.ndarray
    speed: np.ndarray | None  # measured speed, or None (then differentiated from position)
    sample_rate_hz: float
    b_u: float  # effort per volt
    b_omega: float  # back-EMF damping, effort per unit speed
    units: Units
    offset_term: bool  # fit a constant effort offset (EMPS' reference model has one)
    lag_s: float = 0.0  # electrical time constant L/R: the current follows u this much later
    meta: dict[str, str] = field(default_factory=dict)
    path: Path | None = None
    u_unit: str = "V"
    refs: dict[str, np.ndarray] = field(default_factory=dict)  # reference columns, u_exc: closed_loop
    excitation_hz: tuple[float, ...] = ()  # the excitation's declared lines (`# excitation_hz:`)
    # rows tvsctl export filled by interpolation across a stall (its `gap` column = 1), or None
    filled: np.ndarray | None = None
    # whether `position` was measured (a phi column, EMPS' qm) or integrated from the speed
    position_measured: bool = True

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def closed_loop(self) -> bool:
        """Whether a controller closed the loop around the recording: it holds the controller's
        reference, of the speed (`omega_ref`) or of the angle (`phi_ref`; DESIGN.md allows
        either). A position loop is a closed loop as a speed loop is: its command is a function of
        the measured angle, so it answers the noise, least squares on it is biased, and the
        reference is the instrument (tvsd.analysis.instrument). Every closed-loop rule asks this."""
        return "omega_ref" in self.refs or "phi_ref" in self.refs

    @property
    def speed_reference(self) -> np.ndarray | None:
        """The loop's speed reference, the instrument's signal: `omega_ref`, or a position loop's
        `phi_ref` differentiated (ω_ref = dφ_ref/dt, as `tvsctl sim record` writes its omega_ref;
        a function of the reference alone, so as exogenous as the reference). None in open loop."""
        if "omega_ref" in self.refs:
            return self.refs["omega_ref"]
        phi_ref = self.refs.get("phi_ref")
        if phi_ref is None or len(phi_ref) < 2:
            return None
        # on the uniform grid (DESIGN.md): np.gradient over t's rounding reads a hold at 1e-14 rad/s
        return np.gradient(np.asarray(phi_ref, dtype=float), 1.0 / self.sample_rate_hz)

    def slice(self, start: int, stop: int, suffix: str) -> Dataset:
        return Dataset(
            f"{self.name}{suffix}",
            self.t[start:stop],
            self.u[start:stop],
            self.position[start:stop],
            None if self.speed is None else self.speed[start:stop],
            self.sample_rate_hz,
            self.b_u,
            self.b_omega,
            self.units,
            self.offset_term,
            self.lag_s,
            self.meta,
            self.path,
            self.u_unit,
            {k: v[start:stop] for k, v in self.refs.items()},
            self.excitation_hz,
            None if self.filled is None else self.filled[start:stop],
            self.position_measured,
        )


def offset_term(unit: str) -> bool:
    """Whether the baseline has a constant effort offset: only a linear force axis (EMPS).

    A constant load and a Coulomb friction that differs by direction are the same model: adding c
    to the effort moves the whole set-valued friction map (both sliding levels and both breakaway
    levels) by c, so no recording, standstill included, separates them; only a prior does. A
    linear axis has one (gravity, a cable: EMPS' reference model fits an offset). A rotary shaft
    has no constant torque in the paper's model (gravity on it is the imbalance term), so, as for
    a voltage drive, the direction split is read as friction asymmetry, and the doctor states the
    constant torque it could equally be (verdict: offset_equivalent).
    """
    return unit == "N"


def load(path: Path, cfg: Config) -> Dataset:
    """A recording CSV or an EMPS .mat file, by its suffix."""
    path = Path(path)
    if path.suffix.lower() == ".mat":
        return load_emps(path)
    rec = read_recording(path)
    p = cfg.plant
    unit = rec.meta.get("u_unit", "V")
    u = rec.u
    # The input map follows the declared unit (DESIGN.md): a voltage drive has back-EMF and the
    # L/R lag; a current drive applies kM·i; a torque (force) command is the effort itself.
    if unit == "duty":
        u = u * float(rec.meta["u_scale"])
    if rec.meta.get("u_sampling") == "hold" and len(u) > 1:
        # Held from its sample on, u[k] acts over (t_k, t_k+1]: the interval that ends at t_k+1,
        # which tvsd's convention (refit.convention_unpinned) calls row k+1.
        u = np.concatenate([u[:1], u[:-1]])
    if unit in ("V", "duty"):
        b_u, b_omega, lag_s = p.kM * p.ku / p.R, p.kM * p.kb / p.R, p.L / p.R
    elif unit == "A":
        b_u, b_omega, lag_s = p.kM, 0.0, 0.0
    else:  # N*m or N
        b_u, b_omega, lag_s = 1.0, 0.0, 0.0
    linear = unit == "N"
    refs = {k: v for k, v in rec.extra.items() if k in ("omega_ref", "phi_ref", "u_exc")}
    meta, speed = dict(rec.meta), rec.omega
    if rec.phi_measured:
        # The delay is measured against a period-mean ω (timing.py): a speed with other timing is
        # moved onto it (the lag measured against φ's backward difference), not read as a delay.
        lag, share = timing.speed_lag(rec.omega, rec.phi, rec.sample_rate_hz)
        if timing.off_reference(lag, share):
            # An encoder difference keeps its quantisation after the shift (an all-pass moves no
            # power) but leaves the count grid: its step is read here, on the recorded samples.
            step = count_grid.recorded_step(rec.omega, rec.sample_rate_hz, rec.meta)
            if step is not None:
                meta[count_grid.STEP_KEY] = repr(step)
            speed = timing.retimed(rec.omega, lag)
            meta["omega_timing"] = (
                f"omega lagged phi's period mean by {lag:.2f} samples ({100 * share:.0f} % of their "
                "in-band difference): advanced by it"
            )
    return Dataset(
        name=path.name,
        t=rec.t,
        u=u,
        position=rec.phi,
        speed=speed,
        sample_rate_hz=rec.sample_rate_hz,
        b_u=b_u,
        b_omega=b_omega,
        units=LINEAR if linear else ROTARY,
        offset_term=offset_term(unit),
        lag_s=lag_s,
        meta=meta,
        path=path,
        u_unit="V" if unit == "duty" else unit,
        refs=refs,
        excitation_hz=rec.excitation_hz,
        filled=rec.extra["gap"] != 0 if "gap" in rec.extra else None,
        position_measured=rec.phi_measured,
    )


def _mat_numbers(path: Path, data: dict[str, Any], name: str) -> np.ndarray:
    """A .mat variable as a flat float array, or one line saying what it is instead."""
    arr = np.asarray(data[name])
    if arr.dtype.kind not in "biuf":  # text, cells, structs, complex: not a measured signal
        raise DataFileError(f"{path}: variable {name} holds {arr.dtype} values, not real numbers")
    return arr.astype(float).ravel()


def load_emps(path: Path) -> Dataset:
    """EMPS benchmark file: qm (m), vir (V, force = gtau·vir), t (s); closed loop, 1 kHz."""
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError  # an empty or truncated file

    try:
        data = loadmat(str(path))
    except FileNotFoundError:
        raise DataFileError(f"{path}: no such file") from None
    except (ValueError, OSError, TypeError, MatReadError) as exc:
        raise DataFileError(f"{path}: not a readable MATLAB .mat file ({exc})") from exc
    missing = [k for k in ("t", "qm", "vir", "gtau") if k not in data]
    if missing:
        raise DataFileError(
            f"{path}: row 1: missing variable(s) {', '.join(missing)}; an EMPS file has t, qm, vir, gtau"
        )
    t, qm, vir, gtau_v = (_mat_numbers(path, data, k) for k in ("t", "qm", "vir", "gtau"))
    if not (len(t) == len(qm) == len(vir)) or len(t) < 100:
        raise DataFileError(f"{path}: t, qm, vir must have the same length ≥ 100")
    for name, arr in (("t", t), ("qm", qm), ("vir", vir)):
        bad = np.nonzero(~np.isfinite(arr))[0]
        if len(bad):
            raise DataFileError(f"{path}: row {bad[0] + 1}: {name} is NaN or infinite")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.nonzero(dt <= 0)[0][0]) + 1
        raise DataFileError(f"{path}: row {k + 1}: t does not increase")
    if len(gtau_v) != 1 or not (math.isfinite(gtau_v[0]) and gtau_v[0] > 0):
        raise DataFileError(f"{path}: gtau must be one positive number (N per V), got {gtau_v[:3]}")
    gtau = float(gtau_v[0])
    return Dataset(
        name=path.name,
        t=t - t[0],
        u=vir,
        position=qm,
        speed=None,
        sample_rate_hz=float(1.0 / np.median(dt)),
        b_u=gtau,
        b_omega=0.0,
        units=LINEAR,
        offset_term=True,
        meta={"source": "EMPS benchmark (Janot, Gautier, Brunot 2019)", "axis": "linear"},
        path=path,
        u_unit="N",
    )


def check_heldout(data: Dataset, heldout: Dataset) -> None:
    """`--heldout FILE` judges the model fitted on `data`: refused (exit 2) when its command is
    another kind (u_unit: V, A, N*m, N; duty counts as V, read in volts) or its axis another,
    since the fitted input map and units do not apply to it. Its rate may differ: the model is
    in continuous time."""
    ours = f"{data.u_unit} ({data.units.axis})"
    theirs = f"{heldout.u_unit} ({heldout.units.axis})"
    if ours != theirs:
        raise DataFileError(
            f"{heldout.path or heldout.name}: --heldout's command u is in {theirs}, the fitted file's "
            f"({data.name}) in {ours} (# u_unit): the model fitted on one input cannot be judged on "
            "the other; give a held-out recording of the same drive and command"
        )
