"""The positioning laser's two stepper axes, φ (mirror) and γ (main rod), in degrees.

The MCU moves in relative steps with a trapezoidal ramp (firmware/core/stepper.c) and reports
``stepper_state`` (position in steps from the home switch, moving / homed / at-limit flags). This
module turns degrees into those steps, refuses targets outside the axis limits before anything
moves, and reads positions back in degrees.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass, field
from typing import Protocol

from tvsd.errors import ConfigError, DeviceError, UsageError
from tvsd.hw.mcu.messages import StepperState

FIRMWARE_MAX_SPS = 5000  # firmware/core/core_config.h STEPPER_MAX_SPS (its ISR budget)
WIRE_MAX = 0xFFFF  # rate_sps and accel_sps2 are u16 on the wire


@dataclass(frozen=True)
class AxisSettings:
    name: str  # as the user knows it: "φ", "γ"
    axis: int  # MCU axis index
    min_deg: float
    max_deg: float
    home_deg: float  # axis angle where the home switch closes (MCU position 0)
    full_steps_per_rev: int = 200  # 1.8° motor
    microsteps: int = 16
    gear_ratio: float = 1.0  # motor revolutions per axis revolution
    max_rate_dps: float = 30.0
    accel_dps2: float = 60.0

    def __post_init__(self) -> None:
        where = f"stepper axis {self.name}"
        if not (math.isfinite(self.min_deg) and math.isfinite(self.max_deg)) or not (
            self.min_deg < self.max_deg
        ):
            raise ConfigError(f"{where}: limits [{self.min_deg}, {self.max_deg}] are not a range")
        if self.full_steps_per_rev <= 0 or self.microsteps <= 0 or not self.gear_ratio > 0:
            raise ConfigError(f"{where}: steps per rev, microsteps and gear ratio must be > 0")
        if not 0 < self.rate_sps <= min(FIRMWARE_MAX_SPS, WIRE_MAX):
            raise ConfigError(
                f"{where}: max_rate_dps {self.max_rate_dps} is {self.rate_sps} steps/s; the "
                f"firmware steps at most {FIRMWARE_MAX_SPS} steps/s: lower it or the microsteps"
            )
        if not 0 < self.accel_sps2 <= WIRE_MAX:
            raise ConfigError(
                f"{where}: accel_dps2 {self.accel_dps2} is {self.accel_sps2} steps/s², outside 1..{WIRE_MAX}"
            )

    @property
    def steps_per_deg(self) -> float:
        return self.full_steps_per_rev * self.microsteps * self.gear_ratio / 360.0

    @property
    def rate_sps(self) -> int:
        return round(self.max_rate_dps * self.steps_per_deg)

    @property
    def accel_sps2(self) -> int:
        return round(self.accel_dps2 * self.steps_per_deg)

    def to_steps(self, deg: float) -> int:
        """MCU position (steps from home) of an axis angle."""
        return round((deg - self.home_deg) * self.steps_per_deg)

    def to_deg(self, steps: int) -> float:
        return self.home_deg + steps / self.steps_per_deg


def _phi() -> AxisSettings:
    # the paper aims φ at 40°, 60°, 80°; the switch sits at 0°
    return AxisSettings("φ", 0, min_deg=0.0, max_deg=90.0, home_deg=0.0)


def _gamma() -> AxisSettings:
    # the paper tilts γ to −15°, 0°, 15°; the switch sits at the low end
    return AxisSettings("γ", 1, min_deg=-20.0, max_deg=20.0, home_deg=-20.0)


@dataclass(frozen=True)
class StepperSettings:
    phi: AxisSettings = field(default_factory=_phi)
    gamma: AxisSettings = field(default_factory=_gamma)


class StepperPort(Protocol):
    """What the axes need from the link (McuLink provides it)."""

    def send_stepper_move(self, axis: int, steps: int, rate_sps: int, accel_sps2: int) -> bool: ...

    def send_stepper_home(self, axis: int) -> bool: ...


@dataclass(frozen=True)
class AxisStatus:
    name: str
    position_deg: float | None  # None until homed
    homed: bool
    moving: bool
    at_limit: bool


class Steppers:
    """φ and γ. Feed ``update`` with every stepper_state (McuLink(on_stepper=steppers.update))."""

    def __init__(self, port: StepperPort, settings: StepperSettings | None = None) -> None:
        self.settings = settings or StepperSettings()
        self._port = port
        self.axes = {"phi": self.settings.phi, "gamma": self.settings.gamma}
        if self.settings.phi.axis == self.settings.gamma.axis:
            raise ConfigError("stepper axes φ and γ must use different MCU axis numbers")
        self._by_index = {a.axis: key for key, a in self.axes.items()}
        self._state: dict[str, StepperState | None] = dict.fromkeys(self.axes)
        self._target: dict[str, int | None] = dict.fromkeys(self.axes)
        self._homing: dict[str, bool] = dict.fromkeys(self.axes, False)
        self._seen_moving: dict[str, bool] = dict.fromkeys(self.axes, False)
        self._error: dict[str, str | None] = dict.fromkeys(self.axes)
        self._changed = asyncio.Event()

    def _axis(self, name: str) -> AxisSettings:
        aliases = {"φ": "phi", "γ": "gamma"}
        key = aliases.get(name, name)
        if key not in self.axes:
            raise UsageError(f"unknown stepper axis {name!r}: use phi (φ) or gamma (γ)")
        return self.axes[key]

    def _key(self, a: AxisSettings) -> str:
        return self._by_index[a.axis]

    def update(self, st: StepperState) -> None:
        key = self._by_index.get(st.axis)
        if key is None:
            return
        self._state[key] = st
        if st.moving:
            self._seen_moving[key] = True
        if self._homing[key] and st.homed and not st.moving:
            self._homing[key] = False
            self._target[key] = st.position
        self._changed.set()

    def refused(self, name: str, values: tuple[int, ...], reason: str) -> None:
        """The MCU refused a stepper command (McuLink(on_refused=...) passes it on)."""
        if name not in ("stepper_move", "stepper_home") or not values:
            return
        key = self._by_index.get(values[0])
        if key is None:
            return
        self._homing[key] = False
        self._target[key] = None
        self._error[key] = f"the MCU refused {self.axes[key].name} {name}: {reason}"
        self._changed.set()

    def status(self, name: str) -> AxisStatus:
        a = self._axis(name)
        st = self._state[self._key(a)]
        if st is None:
            return AxisStatus(a.name, None, False, False, False)
        pos = a.to_deg(st.position) if st.homed else None
        return AxisStatus(a.name, pos, st.homed, st.moving, st.at_limit)

    def _busy(self, key: str) -> bool:
        st = self._state[key]
        if self._homing[key]:
            return True
        target = self._target[key]
        if target is None or st is None:
            return False
        # Over when the MCU reports it stopped after we saw it move (a limit may have stopped
        # it short), or stopped at the target (the "moving" report may have been lost).
        return st.moving or not (self._seen_moving[key] or st.position == target)

    def move_to(self, name: str, target_deg: float) -> int:
        """Start a move to an absolute angle; returns the steps commanded (0: already there)."""
        a = self._axis(name)
        key = self._key(a)
        if not math.isfinite(target_deg):
            raise UsageError(f"{a.name} = {target_deg} is not an angle")
        if not a.min_deg <= target_deg <= a.max_deg:
            raise UsageError(
                f"{a.name} = {target_deg:.1f}° is outside the axis limits "
                f"[{a.min_deg:.1f}°, {a.max_deg:.1f}°]: choose a target inside them"
            )
        st = self._state[key]
        if st is None or not st.homed:
            raise UsageError(f"{a.name} is not homed: home the axis before moving it")
        if self._busy(key):
            raise UsageError(f"{a.name} is still moving: wait for it to stop")
        target = a.to_steps(target_deg)
        steps = target - st.position
        if steps == 0:
            return 0
        if not self._port.send_stepper_move(a.axis, steps, a.rate_sps, a.accel_sps2):
            raise DeviceError(f"cannot send the {a.name} move: the MCU link is closed or full")
        self._target[key] = target
        self._error[key] = None
        self._seen_moving[key] = False
        self._changed.clear()
        return steps

    def home(self, name: str) -> None:
        a = self._axis(name)
        key = self._key(a)
        if not self._port.send_stepper_home(a.axis):
            raise DeviceError(f"cannot send {a.name} homing: the MCU link is closed or full")
        self._homing[key] = True
        self._target[key] = None
        self._error[key] = None
        self._changed.clear()

    def move_time_s(self, name: str, delta_deg: float) -> float:
        """Duration of a trapezoidal (or triangular) move of |delta_deg|."""
        a = self._axis(name)
        d, v, acc = abs(delta_deg), a.max_rate_dps, a.accel_dps2
        if d >= v * v / acc:
            return d / v + v / acc
        return 2.0 * math.sqrt(d / acc)

    async def wait_idle(self, name: str, timeout_s: float) -> AxisStatus:
        a = self._axis(name)
        key = self._key(a)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while self._busy(key):
            left = deadline - loop.time()
            if left <= 0:
                raise DeviceError(
                    f"{a.name} did not finish its move within {timeout_s:.1f} s: check the "
                    "motor driver's power and enable, and the step/dir wiring"
                )
            self._changed.clear()
            try:
                await asyncio.wait_for(self._changed.wait(), left)
            except TimeoutError:
                continue
        error = self._error[key]
        if error is not None:
            raise DeviceError(error)
        return self.status(name)
