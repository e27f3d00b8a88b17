"""Pulse bookkeeping: the MCU's zero and optical pulse timestamps → clean revolutions.

The MCU timestamps both sensors on one timer (ticks, extended to 64 bits by the link), so β is
computed from tick differences: the MCU→host clock map's offset and rate cancel out of them, and
only the alignment with the IMU (host time) depends on the map.

Anomalies are detected, counted, and never become points:
- out of order: a pulse whose timestamp is not later than one that arrived before it;
- doubled zero pulse: less than half a nominal period after the previous zero pulse;
- missed zero pulse: an interval of n ≥ 2 nominal periods; the revolution numbers skip n − 1, so no
  estimate spans the gap and optical pulses inside it are dropped;
- doubled optical pulse: more than one in a revolution (one laser spot is met once per turn); all
  of that revolution's optical pulses are dropped, as none can be told from the echo;
- optical pulse in a gap: in a revolution that holds a missed zero pulse, before the first zero
  pulse, or more than a nominal period after the last one;
- missed optical pulse: a clean revolution without one (counted; nothing to drop).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

ZERO, OPTICAL = 0, 1
F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
_MEDIAN_SPAN = 9  # intervals in the running median of the nominal period


@dataclass(frozen=True)
class PulseStats:
    zero: int = 0
    optical: int = 0
    out_of_order: int = 0
    doubled_zero: int = 0
    missed_zero: int = 0
    doubled_optical: int = 0
    missed_optical: int = 0
    optical_in_gap: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


@dataclass(frozen=True)
class CleanPulses:
    """Zero pulses with revolution numbers (gaps where pulses were missed) and usable optical pulses."""

    zero_t: F64  # s, MCU time
    zero_rev: I64
    opt_t: F64
    opt_idx: I64  # index into zero_t of the zero pulse that starts the optical pulse's revolution
    stats: PulseStats


def _nominal_period(dt: F64) -> F64:
    """Running median of the zero-pulse intervals (robust to the odd doubled or missed pulse)."""
    if len(dt) < _MEDIAN_SPAN:
        return np.full(len(dt), np.median(dt) if len(dt) else np.nan)
    pad = _MEDIAN_SPAN // 2
    med = np.median(sliding_window_view(dt, _MEDIAN_SPAN), axis=1)
    return np.concatenate([np.full(pad, med[0]), med, np.full(pad, med[-1])])


def clean(kind: NDArray[np.integer], ticks: NDArray[np.integer], tick_s: float) -> CleanPulses:
    """Sort out a pulse stream given in arrival order (kind ZERO/OPTICAL, timer ticks)."""
    kind = np.asarray(kind)
    ticks = np.asarray(ticks, dtype=np.int64)
    if kind.shape != ticks.shape:
        raise ValueError("kind and ticks must have the same length")
    # Out of order: not later than the latest timestamp seen before it.
    prev_max = np.maximum.accumulate(np.concatenate([[np.iinfo(np.int64).min], ticks[:-1]]))
    in_order = ticks > prev_max
    t = ticks * tick_s
    zt = t[in_order & (kind == ZERO)]
    ot = t[in_order & (kind == OPTICAL)]
    n_zero_raw = len(zt)

    doubled = 0
    if len(zt) >= 3:
        dt = np.diff(zt)
        nominal = _nominal_period(dt)
        keep = np.concatenate([[True], dt >= 0.5 * nominal])
        doubled = int(np.count_nonzero(~keep))
        zt = zt[keep]
    rev = np.arange(len(zt), dtype=np.int64)
    missed = 0
    nominal = np.zeros(0)
    if len(zt) >= 3:
        dt = np.diff(zt)
        nominal = _nominal_period(dt)
        n = np.maximum(np.rint(dt / nominal).astype(np.int64), 1)
        missed = int(np.sum(n - 1))
        rev = np.concatenate([[0], np.cumsum(n)])

    # Optical pulses: the revolution they fall in. A closed revolution must not hold a missed zero
    # pulse; the open one (after the last zero pulse) must be shorter than a nominal period.
    idx = np.searchsorted(zt, ot, side="right") - 1
    span_ok = np.zeros(len(ot), dtype=bool)
    if len(zt) >= 3:
        idx_c = np.clip(idx, 0, len(zt) - 1)
        nxt = np.minimum(idx_c + 1, len(zt) - 1)
        closed = (idx >= 0) & (idx < len(zt) - 1) & (rev[nxt] - rev[idx_c] == 1)
        last_period = float(nominal[-1])
        open_ok = (idx == len(zt) - 1) & (ot - zt[-1] < last_period)
        span_ok = closed | open_ok
    in_gap = int(np.count_nonzero(~span_ok))
    ot, idx = ot[span_ok], idx[span_ok]
    per_rev = np.bincount(idx, minlength=len(zt))
    single = per_rev[idx] == 1
    doubled_opt = int(np.count_nonzero(~single))
    clean_revs = np.flatnonzero(np.diff(rev) == 1) if len(zt) >= 2 else np.zeros(0, dtype=np.int64)
    missed_opt = int(np.count_nonzero(per_rev[clean_revs] == 0))
    stats = PulseStats(
        zero=n_zero_raw,
        optical=int(np.count_nonzero(in_order & (kind == OPTICAL))),
        out_of_order=int(np.count_nonzero(~in_order)),
        doubled_zero=doubled,
        missed_zero=missed,
        doubled_optical=doubled_opt,
        missed_optical=missed_opt,
        optical_in_gap=in_gap,
    )
    return CleanPulses(zt, rev, ot[single], idx[single].astype(np.int64), stats)
