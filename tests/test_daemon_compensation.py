"""The daemon's compensated point stream against its own uncompensated β, on the SIL plant.

The whole chain runs as on the scanner: encoder frames through the pty, the control thread's
command back as PWM, the SA IMU twin behind the smbus2 calls, the compensated stream. The same
recorded pulses, re-run through an uncompensated PointStream, give the scatter without the IMU
and the drive model; the scene's β is one constant, so a robust spread of β is its error.

Measured (25 rev/s, 8 s, docs/measurements/daemon.md, "Point stream"): uncompensated 6.5e-4 rad, compensated
5.7–7.8e-5
rad: a gain of 8–11. Before the sampling-instant fix, the PWM actually sent, the SIL encoder ramp
and the twin's DLPF delay it was 0.9–1.2. The bound, 3, sits far below the measured gain and
far above no gain: the MAD of ~150 points is good to ~10 %, SIL timing varies run to run.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_daemon import daemon, status, tvsctl, wait_compensated, wait_status, wait_ticks  # noqa: F401  (the fixture)

from tvsd.config import load_config
from tvsd.recording.reader import open_recording
from tvsd.scan import pulses as PP
from tvsd.scan.points import FLAG_COMPENSATED
from tvsd.scan.stream import PointStream

pytestmark = pytest.mark.slow  # spins a SIL daemon to 25 rev/s and scans (~60 s)

MIN_GAIN = 3.0
MIN_POINTS = 60  # a MAD of 60 values is good to ~15 %
TICK_S = 1 / 16e6


def _robust_std(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def _scan_once(sock, data, config, seconds: float) -> tuple[np.ndarray, np.ndarray, bool]:  # type: ignore[no-untyped-def]
    """(compensated β of the points, the recording's pulses, whether a fault cut in): `seconds`
    of control ticks from the moment the daemon compensates (until the MCU clock sync is ready it
    makes no_imu points, not counted here)."""
    before = set(data.iterdir()) if data.exists() else set()
    tvsctl(sock, "record", "start")
    # a fault (a stall of the shared machine) ends the attempt, refused scan start included:
    # the caller tries again
    started = tvsctl(sock, "scan", "start", check=False).returncode == 0
    try:
        if started:
            wait_compensated(sock, config)
    except AssertionError:
        if status(sock)["state"] != "fault":
            raise
    else:
        if started:
            wait_ticks(sock, seconds)
    tvsctl(sock, "scan", "stop", check=False)
    tvsctl(sock, "record", "stop")
    (path,) = set(data.iterdir()) - before
    rec = open_recording(path)
    faulted = not started or any(m["event"] == "fault" for m in rec.marks)
    points = rec.channels.get("points")
    beta = np.zeros(0) if points is None else points["beta"][(points["flags"] & FLAG_COMPENSATED) != 0]
    return beta, rec.channels["pulses"], faulted


def test_compensated_beta_scatters_several_times_less_than_uncompensated(daemon, tmp_path):  # noqa: F811
    _, sock, data = daemon
    tvsctl(sock, "speed", "25")
    wait_status(sock, lambda s: abs(s["rps"] - 25) < 0.3, 60, "25 rev/s")
    wait_ticks(sock, 2.0)  # past the ramp's end: its jerk is not what this measures
    for _attempt in range(2):  # a stall of the shared machine may trip a SIL fault: once more
        beta, pulses, faulted = _scan_once(sock, data, tmp_path / "tvsd.yaml", 8.0)
        if not faulted and len(beta) >= MIN_POINTS:
            break
        tvsctl(sock, "faults", "--clear", check=False)
        tvsctl(sock, "speed", "25", check=False)
        wait_status(sock, lambda s: abs(s["rps"] - 25) < 0.3, 60, "25 rev/s again")
        wait_ticks(sock, 2.0)
    assert len(beta) >= MIN_POINTS, f"only {len(beta)} compensated points in 8 s (faulted: {faulted})"
    cfg = load_config(params="default")
    plain = PointStream(cfg.scan, math.radians(60.0), 0.0, TICK_S, compensate=False)
    rows = []
    for p in pulses:
        kind = PP.ZERO if p["channel"] == 0 else PP.OPTICAL
        rows += plain.add_pulse(kind, int(p["mcu_ticks"]))
    uncompensated = np.array([r.beta for r in rows])
    assert len(uncompensated) >= MIN_POINTS
    gain = _robust_std(uncompensated) / _robust_std(beta)
    assert gain >= MIN_GAIN, (
        f"compensation gain {gain:.2f}: β spread {_robust_std(beta):.2e} rad compensated, "
        f"{_robust_std(uncompensated):.2e} rad without"
    )
