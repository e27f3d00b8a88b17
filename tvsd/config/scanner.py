"""The scanner's own sections: the drive's plant (paper eqs. 9–17), the drive's limit, the control
loop and its gains (eq. 18), the geometry; and the simulated environment (`sil:`) and the paper
figures to reproduce (`reproduction:`). Frozen dataclasses whose fields carry their rules
(`tvsd.schema.option`); `tvsd.config.load` composes them."""

from __future__ import annotations

import math
from dataclasses import dataclass

from tvsd.errors import UsageError
from tvsd.schema import check, option


@dataclass(frozen=True, kw_only=True)
class PlantParams:
    """The scanning-aperture drive, paper eqs. (9)–(11) and (15)–(16) in SI units."""

    name: str = option(doc="name of the parameter set")
    J: float = option(doc="inertia of motor + aperture", unit="kg·m²", gt=0, le=10)
    kv: float = option(doc="viscous friction", unit="N·m·s/rad", ge=0, le=100)
    kM: float = option(doc="torque constant", unit="N·m/A", gt=0, le=100)
    kb: float = option(doc="back-EMF constant", unit="V·s/rad", gt=0, le=100)
    R: float = option(doc="armature resistance", unit="Ω", gt=0, le=1e4)
    L: float = option(doc="armature inductance", unit="H", gt=0, le=100)
    ku: float = option(doc="drive voltage gain", unit="V/V", gt=0, le=1e4)
    tau_c: float = option(doc="Coulomb friction torque", unit="N·m", ge=0, le=1e4)
    tau_s: float = option(doc="stiction torque", unit="N·m", ge=0, le=1e4)
    sigma0: float = option(doc="LuGre bristle stiffness", unit="N·m/rad", gt=0, le=1e9)
    sigma1: float = option(doc="LuGre bristle damping", unit="N·m·s/rad", ge=0, le=1e6)
    sigma2: float = option(0.0, doc="LuGre viscous term", unit="N·m·s/rad", ge=0, le=1e3)
    v0: float = option(doc="Stribeck velocity", unit="rad/s", gt=0, le=1e3)
    source: str = option("", doc="where the numbers come from")

    def __post_init__(self) -> None:
        if self.tau_c + self.tau_s <= 0:
            raise UsageError(f"plant {self.name}: tau_c and tau_s are both 0; LuGre needs g(ω) > 0")


@dataclass(frozen=True, kw_only=True)
class DriveConfig:
    u_max_v: float = option(12.0, doc="drive voltage limit ±U", unit="V", gt=0, le=400)


@dataclass(frozen=True, kw_only=True)
class Gains:
    """Gains of the robust law u = Gp·tanh(ε) + Gd·tanh(ε̇) + Gr·tanh(G0·ε) (paper eq. 18)."""

    Gp: float = option(doc="proportional gain", unit="V", ge=0, le=1e4)
    Gd: float = option(doc="derivative gain", unit="V", ge=0, le=1e4)
    Gr: float = option(doc="robust gain", unit="V", ge=0, le=1e4)
    G0: float = option(doc="sharpness factor", unit="1/rad", gt=0, le=1e6)

    def __post_init__(self) -> None:
        check(self)  # the one rule for gains from YAML, the API and the command line

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.Gp, self.Gd, self.Gr, self.G0)


@dataclass(frozen=True, kw_only=True)
class ControlConfig:
    rate_hz: float = option(10000.0, doc="control loop rate", unit="Hz", ge=100, le=100000)
    gains: Gains = option(doc="robust law gains")
    disturbance_bound_rad_s2: float = option(
        1.65, doc="Δv_max for condition (23), paper's largest measured value", unit="rad/s²", ge=0, le=1e6
    )
    scan_accel_rps2: float = option(
        10.0, doc="speed-reference ramp in scanning mode", unit="rev/s²", gt=0, le=1e4
    )
    overrun_streak_ms: float = option(
        100.0,
        doc="late ticks in a row for this long put the drive in its safe state (a shared machine stalls "
        "for ms at times; the MCU's watchdog cuts at 200 ms)",
        unit="ms",
        gt=0,
        le=1000,
    )
    scan_feedforward: bool = option(
        True, doc="scanning mode adds the model's steady voltage to the law's output (README)"
    )
    max_lag_rad: float = option(
        math.pi,
        doc="scanning mode: the reference slips beyond this lag (anti-windup)",
        unit="rad",
        gt=0,
        le=1e3,
    )

    @property
    def overrun_streak_ticks(self) -> int:
        """The overrun latch in ticks: this many late ticks in a row put the drive in its safe state."""
        return max(1, round(self.overrun_streak_ms * 1e-3 * self.rate_hz))


@dataclass(frozen=True, kw_only=True)
class GeometryConfig:
    baseline_m: float = option(
        0.5, doc="baseline a between PL and SA (MODEL-NOTES §6)", unit="m", gt=0, le=100
    )


@dataclass(frozen=True, kw_only=True)
class VibrationConfig:
    model: str = option("ou", doc="Δv model (MODEL-NOTES §4)", choices=("off", "sde", "ou"))
    sigma_v: float = option(
        0.3381, doc="σv: std (ou, rad/s²) or SDE intensity (sde, rad/s^1.5)", ge=0, le=1e4
    )
    tau_n_s: float = option(0.005, doc="OU correlation time", unit="s", gt=0, le=100)


@dataclass(frozen=True, kw_only=True)
class MeasurementConfig:
    sample_rate_hz: float = option(1000.0, doc="recording rate", unit="Hz", gt=0, le=100000)
    encoder_counts_per_rev: int = option(8192, doc="encoder counts per revolution (×4)", ge=4, le=1 << 24)
    speed_noise_rad_s: float = option(0.02, doc="speed measurement noise std", unit="rad/s", ge=0, le=1e3)


@dataclass(frozen=True, kw_only=True)
class SilConfig:
    vibration: VibrationConfig = option(VibrationConfig())
    measurement: MeasurementConfig = option(MeasurementConfig())
    effects: tuple[str, ...] = option([], doc='effects on, as "name:key=value,..." (tvsctl sim --help)')
    seed: int = option(1, doc="random seed of the simulated plant", ge=0, le=2**32 - 1)


@dataclass(frozen=True, kw_only=True)
class Reproduction:
    """Figures of the paper that `tvsctl sim` reproduces (paper.yaml only)."""

    table6_refs_deg: tuple[float, ...] = option([], doc="Table 6 reference positions", unit="deg")
    table6_settling_s: tuple[float, ...] = option([], doc="Table 6 settling times", unit="s")
    table6_ku: float = option(10.0, doc="ku that reproduces Table 6 (MODEL-NOTES §3)", gt=0)
    open_loop_ku: float = option(166.0, doc="ku of the open-loop runs (MODEL-NOTES §3)", gt=0)
