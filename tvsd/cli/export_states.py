"""`tvsctl export`'s phi and omega from the MCU's encoder frames (the recording's `states` channel).

The loop channel's omega and phi are what the control thread had: each state frame's angle and a
speed over its last 2 ms of frames, held from the frame's *arrival* until the next, averaged per
1 ms. That measurement lags the shaft (the 2 ms window's centre, the frame's way over the link, the
hold: 3 ms on the SIL daemon) and, where the frames reach the host late in a burst (the link's
I/O thread late, a pty's batch), it stands still and then jumps: a step in phi at an instant that
has nothing to do with the shaft, broadband, in the model doctor's band, which a `cogging` of a
high order (13-20 on four SIL identify exports) or a longer `delay` fitted
(docs/measurements/doctor-method.md, model doctor
step 8). The frames carry the MCU's own tick stamp of the instant it read the encoder, so the
export places each count there (the link's clock sync maps ticks to the host's clock) and writes,
per loop sample, the angle at the sample's end and the mean speed over the sample (the angle's
difference over its 1 ms, as `u` is the mean of the same 1 ms): exact but for the encoder's
quantisation (±½ count at each end: 0.31 rad/s rms at 8192 counts/rev, almost all above the
doctor's 100 Hz band), with no lag and no hold.

That quantisation is the model doctor's known floor in its noise-colour test, but ω interpolated
between frames is off the count grid, so the doctor cannot read it from ω: the export declares the
encoder's counts (`# encoder_counts_per_rev:`) and the frames' timing against the samples
(`frame_timing`: `# encoder_frame_hz:`, `# encoder_frame_offset_s:`), from which
tvsd.analysis.quantisation builds the floor of an interpolated angle (docs/measurements/closedcolour2.md).
"""

from __future__ import annotations

import numpy as np

CLOCK_SEGMENT_S = 60.0  # the MCU clock's map to the host's: a line, its offset followed per minute
MAX_FRAME_GAP_S = 5e-3  # frames further apart than this (a link outage): the loop's own values kept
OMEGA_SOURCE = (
    "the MCU's encoder frames at their sampling instants (channel states): omega the mean speed over "
    "each sample, phi the angle at its end (omega_loop: the control thread's measurement)"
)


def from_states(
    rows: np.ndarray, t_first: float, n: int, period: float, omega: np.ndarray, phi: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """(omega, phi, samples taken from the frames) on the loop's grid — sample k the bin
    (t_first + (k−1)·period, t_first + k·period] — from the state frames `rows` (t, mcu_ticks,
    phi); the loop's `omega`/`phi` where the frames do not cover a bin. None when the frames
    cannot be placed (no clock sync: fewer than two sampling instants known)."""
    frames = _frames(rows)
    if frames is None:
        return None
    rows, t = frames
    angle = rows["phi"].astype(float)
    edges = t_first - period + np.arange(n + 1) * period
    at = np.interp(edges, t, angle)
    # an edge is covered when frames on both sides lie within MAX_FRAME_GAP_S of each other
    j = np.searchsorted(t, edges, side="right")
    inside = (j > 0) & (j < len(t))
    jj = np.clip(j, 1, len(t) - 1)
    covered = inside & (t[jj] - t[jj - 1] <= MAX_FRAME_GAP_S)
    ok = covered[:-1] & covered[1:]
    w = np.where(ok, np.diff(at) / period, omega)
    p = np.where(ok, at[1:], phi)
    return w, p, int(np.count_nonzero(ok))


def frame_timing(rows: np.ndarray, t_first: float, period: float) -> tuple[float, float] | None:
    """(frame rate Hz, offset s): the frames' rate (their median spacing) and where they lie after
    the loop's sample edges (t_first − period + k·period), modulo the frame period — the circular
    mean over the record (the SIL's frames drift 0.01 ms in 20 s against the edges). None when the
    frames cannot be placed."""
    frames = _frames(rows)
    if frames is None:
        return None
    placed = frames[1]
    spacing = float(np.median(np.diff(placed)))
    if not (spacing > 0):
        return None
    rate = 1.0 / spacing
    turn = np.exp(2j * np.pi * rate * (placed - (t_first - period)))
    offset = float(np.mod(np.angle(np.mean(turn)) / (2 * np.pi * rate), spacing))
    return rate, offset


def _frames(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(the frames in tick order, each once; their sampling instants on the loop's axis), or None
    when fewer than two instants are known (no clock sync)."""
    rows = rows[np.argsort(rows["mcu_ticks"], kind="stable")]
    ticks = rows["mcu_ticks"].astype(float)
    keep = np.concatenate([[True], np.diff(ticks) > 0])  # a frame recorded twice: once
    rows, ticks = rows[keep], ticks[keep]
    t = rows["t"].astype(float)
    known = np.isfinite(t)
    if np.count_nonzero(known) < 2:
        return None
    return rows, _placed(ticks, t, known)


def _placed(ticks: np.ndarray, t: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Sampling instants on the loop's axis from the MCU's ticks, on a smooth map: the clock sync's
    own values step by up to 0.1 ms where it refits (115 µs on a SIL identify run, 38 µs rms about
    a line), and a step in time is a step in φ (0.018 rad at 25 rev/s), in the doctor's band. The
    MCU's crystal is linear over minutes: one line through the placed instants (the frames before
    the sync placed by it too), its offset then followed per CLOCK_SEGMENT_S (median, linear in
    between) for a slow drift over a long recording."""
    k, tk = ticks[known], t[known]
    slope, icpt = np.polyfit(k - k[0], tk, 1)
    line = icpt + slope * (ticks - k[0])
    seg = CLOCK_SEGMENT_S * slope**-1 if slope > 0 else np.inf  # ticks per segment
    n_seg = int((k[-1] - k[0]) // seg) if np.isfinite(seg) else 0
    if n_seg < 2:
        return line
    j = np.minimum(((k - k[0]) // seg).astype(int), n_seg - 1)
    off = tk - (icpt + slope * (k - k[0]))
    centres = np.array([np.median(k[j == i]) for i in range(n_seg)])
    medians = np.array([np.median(off[j == i]) for i in range(n_seg)])
    return line + np.interp(ticks, centres, medians)
