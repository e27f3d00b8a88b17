"""Outsider draws of the two classes whose colour false alarms tvsd.analysis.spectral_fit removes
(docs/measurements/colour14.md), and the doctor run on one in process.

Each draw keeps the outsider's plant, noise and command (tests/outsider_bench.draw, open loop, the
case seeds whose draw is a V drive), with the class's fields set:
- `coarse`: o14033's — 8-bit PWM, 256-count encoder difference (declared), 2 kHz, staircase, 30 s;
- `prbs500`: o14073's — 10-bit PWM, 8192-count encoder difference, 500 Hz, PRBS, 60 s;
- `coarse1k`: 8-bit PWM, 1024 counts at 1 kHz, a staircase or a PRBS, 30 s.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import outsider_bench as ob

from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, Prepared, prepare
from tvsd.config import load_config

CLASSES: dict[str, dict[str, Any]] = {
    "coarse": dict(unit="V", fs=2000.0, seconds=30.0, excitation="staircase", cpr=256, pwm_bits=8),
    "prbs500": dict(unit="V", fs=500.0, seconds=60.0, excitation="prbs", cpr=8192, pwm_bits=10),
    "coarse-quiet": dict(
        unit="V", fs=2000.0, seconds=30.0, excitation="staircase", cpr=256, pwm_bits=8, sigma_v=0.1
    ),
    "prbs500-quiet": dict(
        unit="V", fs=500.0, seconds=120.0, excitation="prbs", cpr=8192, pwm_bits=10, sigma_v=0.1
    ),
    "coarse1k": dict(
        unit="V", fs=1000.0, seconds=30.0, excitation=("staircase", "prbs"), cpr=1024, pwm_bits=8
    ),
}


def v_seeds(seed: int, n: int) -> list[int]:
    """The first n case seeds from `seed` whose outsider draw is a V drive (its command range,
    PWM and back-EMF as drawn)."""
    out, j = [], seed
    while len(out) < n:
        if ob.draw(j, "none", 0.0, closed=False).unit == "V":
            out.append(j)
        j += 1
    return out


def spec_of(cls: str, seed: int, cause: str, size: float) -> ob.Spec:
    """The outsider's draw (open loop) with the class's fields set."""
    s = ob.draw(seed, cause, size, closed=False)
    c = CLASSES[cls]
    exc = c["excitation"]
    s.excitation = exc if isinstance(exc, str) else exc[seed % len(exc)]
    s.fs, s.seconds = c["fs"], c["seconds"]
    s.drive["pwm_bits"] = c["pwm_bits"]
    if "sigma_v" in c:  # a quiet vibration: the drive's and the encoder's parts weigh more
        s.noise["sigma_v"] = c["sigma_v"]
    s.sensor.update(cpr=c["cpr"], omega="diff", declare_cpr=True)
    if cause == "resonance":  # a mode below the class's fs/5, as draw() places it
        s.truth["frequency_hz"] = min(s.truth["frequency_hz"], 0.2 * s.fs)
    return s


def run_one(s: ob.Spec, tmp: Path) -> dict[str, Any]:
    from tvsd.analysis import doctor
    from tvsd.analysis.dataset import load
    from tvsd.config import load_config

    path = tmp / f"{s.name}.csv"
    ob.write(path, s, ob.make(s))
    cfg = load_config()
    t0 = time.time()
    try:
        d = doctor.diagnose(load(path, cfg), cfg.plant.v0)
    except Exception as e:  # a refusal (DataFileError and the like): recorded, not named
        return {"cause": "refused", "error": str(e)[:160], "wall_s": time.time() - t0}
    finally:
        path.unlink(missing_ok=True)
    n = d.noise
    return {"cause": d.cause, "colour_p": n.colour_p, "tau_s": n.tau_s, "floor_hz": n.floor_cut_hz,
            "band": n.colour_band_hz, "wall_s": round(time.time() - t0, 2)}  # fmt: skip


def coarse_encoder_rows(tmp_path: Path, closed: bool) -> Prepared:
    """Outsider case 14083 redrawn for 20 s on a declared 256-count encoder difference (open or
    closed loop), written as a recording and prepared as the doctor prepares its rows."""
    s = ob.draw(14083, "none", 0.0, closed=closed)
    s.seconds, s.sensor["cpr"], s.sensor["omega"], s.sensor["declare_cpr"] = 20.0, 256, "diff", True
    path = tmp_path / ("closed.csv" if closed else "open.csv")
    ob.write(path, s, ob.make(s))
    return prepare(load(path, load_config()), Band())
