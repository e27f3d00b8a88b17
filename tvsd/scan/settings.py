"""Settings of the scan pipeline: geometry, stepper resolution, timing and IMU error budget.

`ScanSettings` is written like the config sections of tvsd.config (fields built with
`tvsd.schema.option`), so it can become the `scan:` section of config/tvsd.yaml as it is; until
then the defaults below are the scanner's. Each number's source is on its line.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from tvsd.errors import UsageError
from tvsd.schema import option


@dataclass(frozen=True, kw_only=True)
class ScanSettings:
    baseline_m: float = option(0.5, doc="baseline a between PL and SA (MODEL-NOTES §6)", unit="m", gt=0)
    # 1.8° stepper at 16 microsteps: 3200 steps/rev, 0.1125° per step.
    phi_steps_per_rev: int = option(3200, doc="PL mirror stepper steps per revolution", ge=4)
    gamma_steps_per_rev: int = option(3200, doc="main-rod stepper steps per revolution", ge=4)
    phi_min_deg: float = option(10.0, doc="PL mirror travel, lower end", unit="deg", gt=0, lt=180)
    phi_max_deg: float = option(170.0, doc="PL mirror travel, upper end", unit="deg", gt=0, lt=180)
    gamma_max_deg: float = option(45.0, doc="main-rod tilt limit ±", unit="deg", gt=0, lt=90)
    min_range_m: float = option(0.1, doc="closest target the SA optics focus", unit="m", ge=0)
    # The firmware's Timer1 input capture runs undivided at 16 MHz: 62.5 ns per tick
    # (firmware/PROTOCOL.md, "Timestamps").
    timer_resolution_s: float = option(62.5e-9, doc="MCU pulse timer resolution", unit="s", gt=0)
    clock_sync_error_s: float = option(
        3e-6, doc="1σ error of the MCU→host clock map (aligns IMU with pulses)", unit="s", ge=0
    )
    imu_rate_hz: float = option(1000.0, doc="IMU FIFO rate (MODEL-NOTES §4: ≥ 1 kHz)", unit="Hz", gt=0)
    # MPU6050 datasheet: rate noise spectral density 0.005 °/s/√Hz.
    gyro_noise_density: float = option(
        math.radians(0.005), doc="gyro rate noise density", unit="rad/s/√Hz", ge=0
    )
    # MPU6050 datasheet: sensitivity scale-factor tolerance ±3 %; ~2 % (1σ) left after calibration.
    imu_scale_tolerance: float = option(0.02, doc="1σ relative gyro scale error", ge=0, lt=1)
    # Drive model (kM·ku/(R·J)) relative error: kM, R measured to a few % (paper text).
    model_tolerance: float = option(0.05, doc="1σ relative error of the drive-torque model", ge=0, lt=1)
    # Paper's σv levels: min 0.0838, average 0.3381, max 0.8069; flag what exceeds the average.
    vibration_threshold: float = option(
        0.3381, doc="flag points whose measured vibration intensity exceeds this", unit="rad/s^1.5", ge=0
    )
    vibration_window_s: float = option(0.5, doc="window over which vibration is measured", unit="s", gt=0)
    estimator: str = option(
        "centred",
        doc="zero pulses around the optical pulse: centred (k-1,k,k+1; waits one revolution) "
        "or causal (k-2,k-1,k)",
        choices=("centred", "causal"),
    )

    def __post_init__(self) -> None:
        # The config loader checks these rules too; direct construction (tests, CLI) gets the same.
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            meta = f.metadata
            if meta.get("choices") and value not in meta["choices"]:
                raise UsageError(f"scan.{f.name}: must be one of {', '.join(meta['choices'])}, got {value!r}")
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                if not math.isfinite(value):
                    raise UsageError(f"scan.{f.name}: must be finite, got {value}")
                for key, ok, word in (
                    ("gt", lambda v, b: v > b, "above"),
                    ("ge", lambda v, b: v >= b, "at least"),
                    ("lt", lambda v, b: v < b, "below"),
                    ("le", lambda v, b: v <= b, "at most"),
                ):
                    bound = meta.get(key)
                    if bound is not None and not ok(value, bound):
                        unit = f" {meta['unit']}" if meta.get("unit") else ""
                        raise UsageError(f"scan.{f.name}: must be {word} {bound:g}{unit}, got {value:g}")
        if self.phi_min_deg >= self.phi_max_deg:
            raise UsageError(
                f"scan.phi_min_deg ({self.phi_min_deg:g}) must be below phi_max_deg ({self.phi_max_deg:g})"
            )
