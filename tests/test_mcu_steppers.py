"""φ and γ axes: degrees <-> steps, limits, homing, move completion."""

from __future__ import annotations

import asyncio

import pytest

from tvsd.errors import ConfigError, DeviceError, UsageError
from tvsd.hw.mcu.messages import StepperState
from tvsd.hw.mcu.steppers import AxisSettings, Steppers, StepperSettings

MOVING, HOMED, AT_LIMIT = 1, 2, 4


class Port:
    def __init__(self, ok: bool = True) -> None:
        self.moves: list[tuple[int, int, int, int]] = []
        self.homes: list[int] = []
        self.ok = ok

    def send_stepper_move(self, axis: int, steps: int, rate_sps: int, accel_sps2: int) -> bool:
        self.moves.append((axis, steps, rate_sps, accel_sps2))
        return self.ok

    def send_stepper_home(self, axis: int) -> bool:
        self.homes.append(axis)
        return self.ok


def homed(port: Port | None = None) -> tuple[Steppers, Port]:
    p = port or Port()
    s = Steppers(p)
    s.home("phi")
    s.home("γ")
    assert p.homes == [0, 1]
    s.update(StepperState(0, 0, HOMED | AT_LIMIT))
    s.update(StepperState(1, 0, HOMED | AT_LIMIT))
    return s, p


def test_steps_per_degree() -> None:
    a = StepperSettings().phi
    # 200 full steps × 16 microsteps × gear 1 over 360°
    assert a.steps_per_deg == pytest.approx(3200 / 360)
    g = AxisSettings("γ", 1, -20, 20, -20, full_steps_per_rev=400, microsteps=8, gear_ratio=5)
    assert g.steps_per_deg == pytest.approx(400 * 8 * 5 / 360)
    # a target lands on the nearest step: within half a step of it
    half_step = 0.5 / g.steps_per_deg
    assert g.to_steps(-20) == 0 and g.to_deg(g.to_steps(7.5)) == pytest.approx(7.5, abs=half_step)


def test_move_sends_relative_steps_and_reads_degrees_back() -> None:
    s, p = homed()
    steps = s.move_to("phi", 45.0)
    a = s.axes["phi"]
    assert steps == round(45 * a.steps_per_deg) == 400
    assert p.moves == [(0, 400, a.rate_sps, a.accel_sps2)]
    s.update(StepperState(0, 200, HOMED | MOVING))
    assert s.status("phi").moving and s.status("phi").position_deg == pytest.approx(22.5)
    s.update(StepperState(0, 400, HOMED))
    assert s.status("φ").position_deg == pytest.approx(45.0)
    # next move is relative to where the MCU says the axis is
    assert s.move_to("phi", 40.0) == -round(5 * a.steps_per_deg)
    # γ's switch is at −20°: 0° is 20° of steps away
    assert s.move_to("gamma", 0.0) == round(20 * s.axes["gamma"].steps_per_deg)


def test_out_of_range_is_refused_naming_the_limits() -> None:
    s, p = homed()
    with pytest.raises(UsageError) as info:
        s.move_to("phi", 95.0)
    assert str(info.value) == (
        "φ = 95.0° is outside the axis limits [0.0°, 90.0°]: choose a target inside them"
    )
    with pytest.raises(UsageError, match=r"γ = -25.0° is outside the axis limits \[-20.0°"):
        s.move_to("γ", -25.0)
    with pytest.raises(UsageError, match="not an angle"):
        s.move_to("phi", float("nan"))
    with pytest.raises(UsageError, match="unknown stepper axis 'theta'"):
        s.move_to("theta", 1.0)
    assert p.moves == []


def test_refused_before_homing_and_while_moving() -> None:
    s = Steppers(Port())
    with pytest.raises(UsageError, match="φ is not homed"):
        s.move_to("phi", 10.0)
    s, _ = homed()
    s.move_to("phi", 10.0)
    with pytest.raises(UsageError, match="still moving"):
        s.move_to("phi", 20.0)


def test_wait_idle_ends_at_target_or_limit() -> None:
    async def main() -> None:
        s, _ = homed()
        s.move_to("phi", 30.0)
        target = s.axes["phi"].to_steps(30.0)
        loop = asyncio.get_running_loop()
        loop.call_later(0.01, s.update, StepperState(0, 5, HOMED | MOVING))
        loop.call_later(0.02, s.update, StepperState(0, target, HOMED))
        st = await s.wait_idle("phi", 1.0)
        half_step = 0.5 / s.axes["phi"].steps_per_deg  # the target rounds to the nearest step
        assert st.position_deg == pytest.approx(30.0, abs=half_step) and not st.moving
        # a limit switch stops the next move short: it is over all the same
        s.move_to("phi", 80.0)
        loop.call_later(0.01, s.update, StepperState(0, target + 10, HOMED | MOVING))
        loop.call_later(0.02, s.update, StepperState(0, target + 20, HOMED | AT_LIMIT))
        st = await s.wait_idle("phi", 1.0)
        assert st.at_limit and st.position_deg == pytest.approx(s.axes["phi"].to_deg(target + 20))

    asyncio.run(main())


def test_wait_idle_times_out_with_a_hint() -> None:
    async def main() -> None:
        s, _ = homed()
        s.move_to("gamma", 5.0)
        with pytest.raises(DeviceError, match=r"did not finish its move within 0\.1 s"):
            await s.wait_idle("gamma", 0.1)

    asyncio.run(main())


def test_homing_completes_on_homed_report() -> None:
    async def main() -> None:
        s = Steppers(Port())
        s.home("gamma")
        asyncio.get_running_loop().call_later(0.01, s.update, StepperState(1, 0, HOMED | AT_LIMIT))
        st = await s.wait_idle("gamma", 1.0)
        assert st.homed and st.position_deg == -20.0

    asyncio.run(main())


def test_closed_link_is_a_device_error() -> None:
    s, p = homed()
    p.ok = False
    with pytest.raises(DeviceError, match="cannot send the φ move"):
        s.move_to("phi", 10.0)


def test_move_time_trapezoid_and_triangle() -> None:
    s = Steppers(Port())
    # 30°/s, 60°/s²: ramps take 0.5 s and 7.5° each way
    assert s.move_time_s("phi", 60.0) == pytest.approx(60 / 30 + 0.5)
    assert s.move_time_s("phi", 6.0) == pytest.approx(2 * (6 / 60) ** 0.5)


def test_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match="firmware steps at most 5000"):
        AxisSettings("φ", 0, 0, 90, 0, max_rate_dps=1000)
    with pytest.raises(ConfigError, match="not a range"):
        AxisSettings("φ", 0, 90, 0, 0)
    with pytest.raises(ConfigError, match="different MCU axis"):
        Steppers(Port(), StepperSettings(gamma=AxisSettings("γ", 0, -20, 20, -20)))


def test_refused_command_ends_the_wait_with_the_reason() -> None:
    async def main() -> None:
        s, _ = homed()
        s.move_to("phi", 10.0)
        s.refused("stepper_move", (0, 89, 267, 533), "the stepper axis is already moving")
        with pytest.raises(DeviceError, match="MCU refused φ stepper_move: the stepper axis"):
            await s.wait_idle("phi", 1.0)
        s.refused("laser_set", (1,), "whatever")  # not a stepper command: ignored
        s.move_to("phi", 10.0)  # a new command clears the old refusal
        s.update(StepperState(0, s.axes["phi"].to_steps(10.0), HOMED))
        half_step = 0.5 / s.axes["phi"].steps_per_deg
        assert (await s.wait_idle("phi", 1.0)).position_deg == pytest.approx(10.0, abs=half_step)

    asyncio.run(main())
