"""The `identify:` section: the bounded excitation of `tvsctl identify` and its own rules (the
rules against other sections are `tvsd.config.load`'s)."""

from __future__ import annotations

from dataclasses import dataclass

from tvsd.schema import FieldError, check, option

EXCITATION_KINDS = ("steps", "multisine", "prbs", "reversal")
DEFAULT_KINDS = ("steps", "multisine", "prbs")  # reversal: asked for (it turns the aperture backwards)


@dataclass(frozen=True, kw_only=True)
class IdentifySettings:
    """The `identify:` section: the bounded excitation `tvsctl identify` adds while the aperture
    spins (tvsd/control/excitation.py builds it, the control thread plays it). Steps and the
    multisine move the speed reference (through the scanning ramp, so the acceleration stays
    within control.scan_accel_rps2); the PRBS is added to the drive voltage after the law, then
    clipped at ±drive.u_max_v."""

    kinds: tuple[str, ...] = option(
        list(DEFAULT_KINDS),
        doc="excitations to add, any of steps, multisine, prbs, reversal",
        choices=EXCITATION_KINDS,
    )
    seconds: float = option(20.0, doc="how long the excitation runs", unit="s", ge=1)
    max_seconds: float = option(
        120.0, doc="longest excitation: the control thread preallocates its table", unit="s", ge=1, le=600
    )
    table_rate_hz: float = option(
        1000.0, doc="rows per second of the excitation table (the 10 kHz loop holds each)", unit="Hz",
        ge=10, le=10000,
    )  # fmt: skip
    step_rps: float = option(0.5, doc="speed-reference step size", unit="rev/s", ge=0, le=5)
    step_hold_s: float = option(1.0, doc="each step is held this long", unit="s", ge=0.05, le=30)
    multisine_rps: float = option(0.2, doc="peak of the speed-reference multisine", unit="rev/s", ge=0, le=5)
    multisine_min_hz: float = option(0.2, doc="lowest multisine line", unit="Hz", gt=0, le=100)
    multisine_max_hz: float = option(8.0, doc="highest multisine line", unit="Hz", gt=0, le=100)
    prbs_v: float = option(0.5, doc="PRBS amplitude added to the drive voltage", unit="V", ge=0, le=6)
    prbs_clock_s: float = option(
        0.004, doc="PRBS bit time (≥ the MCU's PWM frame period)", unit="s", ge=0.0004, le=1
    )
    max_delta_rps: float = option(
        1.5, doc="bound on the speed-reference excitation (steps + multisine peak)", unit="rev/s", gt=0, le=10
    )
    abort_error_rps: float = option(
        3.0, doc="abort when the measured speed strays this far from the speed reference", unit="rev/s",
        gt=0, le=20,
    )  # fmt: skip
    min_rps: float = option(
        5.0, doc="the aperture spins at least this fast (after the excitation) during identify", unit="rev/s",
        gt=0,
    )  # fmt: skip
    seed: int = option(1, doc="random seed of the step order, multisine phases and PRBS", ge=0)
    reversal_rps: float = option(
        2.0, doc="reversal: the speed reached in the other direction", unit="rev/s", gt=0, le=10
    )
    reversal_hold_s: float = option(
        2.0, doc="reversal: how long that speed is held (after the ramp to it)", unit="s", ge=0.1, le=30
    )

    def __post_init__(self) -> None:
        check(self)
        for kind in self.kinds:
            if kind not in EXCITATION_KINDS:
                raise FieldError(
                    "kinds", f"unknown excitation {kind!r}: use any of {', '.join(EXCITATION_KINDS)}"
                )
        if not self.kinds:
            raise FieldError("kinds", f"give at least one of {', '.join(EXCITATION_KINDS)}")
        if self.seconds > self.max_seconds:
            raise FieldError(
                "seconds", f"must be at most max_seconds ({self.max_seconds:g} s), got {self.seconds:g}"
            )
        if self.multisine_min_hz >= self.multisine_max_hz:
            raise FieldError(
                "multisine_min_hz",
                f"must be below multisine_max_hz ({self.multisine_max_hz:g} Hz), "
                f"got {self.multisine_min_hz:g}",
            )
        if self.multisine_max_hz > self.table_rate_hz / 10:
            raise FieldError(
                "multisine_max_hz",
                f"must be at most table_rate_hz / 10 ({self.table_rate_hz / 10:g} Hz), got "
                f"{self.multisine_max_hz:g}: ten rows per period keep the sine a sine",
            )
        if self.prbs_clock_s * self.table_rate_hz < 1 - 1e-9:
            raise FieldError(
                "prbs_clock_s",
                f"must be at least one table row (1/table_rate_hz = {1 / self.table_rate_hz:g} s), "
                f"got {self.prbs_clock_s:g}",
            )
        speed = self.speed_excitation_rps
        if speed > self.max_delta_rps:
            key = "step_rps" if "steps" in self.kinds else "multisine_rps"
            raise FieldError(
                key,
                f"the speed excitation (step_rps + multisine_rps of the kinds on) reaches {speed:g} "
                f"rev/s, beyond max_delta_rps ({self.max_delta_rps:g}): lower them or raise that bound",
            )

    @property
    def speed_excitation_rps(self) -> float:
        """The largest excursion of the speed reference the kinds on can make."""
        return (self.step_rps if "steps" in self.kinds else 0.0) + (
            self.multisine_rps if "multisine" in self.kinds else 0.0
        )
