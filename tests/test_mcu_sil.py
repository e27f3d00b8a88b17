"""McuLink, Steppers and `tvsctl mcu` against the real firmware core (the virtual MCU on a pty).

The FakeMcu of test_mcu_link.py checks the host against this project's reading of the spec;
here the other side is the C firmware itself (built for the host), so a hash rule, a field order
or an unwrap assumption that the two sides read differently fails here.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import math
import time

import pytest
from conftest import until

import tvsd.cli.main as cli_main
from tvsd.errors import DeviceError
from tvsd.hw.mcu.events import FaultEvent, PulseEvent
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec
from tvsd.hw.mcu.steppers import AxisSettings, Steppers, StepperSettings
from tvsd.sim import virtual_mcu as vm


def test_identify_matches_the_firmware(vmcu: vm.VirtualMcu) -> None:
    async def main() -> None:
        async with McuLink(McuSettings(port=vmcu.port)) as link:
            assert link.identity is not None
            # the C generator and spec.py computed the same hash from protocol.yaml
            assert link.identity.table_hash == load_spec().table_hash
            assert link.identity.clock_hz == 16_000_000

    asyncio.run(main())


def test_state_ticks_encoder_pulses_and_pwm(vmcu: vm.VirtualMcu) -> None:
    states: list[StateSample] = []
    pulses: list[PulseEvent] = []

    async def main() -> None:
        # (a stall of this process, which pumps the virtual MCU, must not read as a link loss:
        # the stamps' chain would break and `exact` below with it)
        settings = McuSettings(port=vmcu.port, watchdog_ms=20, link_lost_ms=10_000)  # heartbeat 5 ms
        async with McuLink(settings, on_state=states.append, on_pulse=pulses.append) as link:
            # the motor turns 12 rev in 0.3 s: 49152 counts, past the i16 wrap
            t0 = time.monotonic()
            while (t := time.monotonic() - t0) < 0.3:
                vmcu.set_shaft(t / 0.3 * 12 * math.tau)
                await asyncio.sleep(0.002)
            vmcu.set_shaft(12 * math.tau)
            # the fit needs 8 round trips within 0.2 ms of the best: on a loaded machine the
            # 0.35 s so far may not hold them yet (wait for the outcome, not a fixed time)
            await wait(lambda: link.clock is not None and link.clock.ready, 5.0)
            t_pulse = time.monotonic()  # the edge latched at this very instant, not at the call's
            vmcu.pulse(vm.PULSE_OPTICAL, t_s=t_pulse - vmcu.power_on_monotonic)
            while not any(p.channel == vm.PULSE_OPTICAL for p in pulses):
                await asyncio.sleep(0.001)
            # armed by the heartbeat, the firmware takes the duty
            assert link.send_pwm(0.5)
            await wait(lambda: abs(vmcu.pwm_duty - 0.5) <= 1 / 32767, 2.0)
            st = link.stats()
            assert st.lost_frames == st.crc_errors == st.lost_events == 0

            # consecutive state frames are 1 ms of 16 MHz ticks apart (state_div 10 at 10 kHz)
            # (state frames flow from power-on: those before the first heartbeat_ack are held by
            # the link and placed by it, so every one is exact, however late the ack came)
            assert all(s.exact for s in states) and link.stats().states_unanchored == 0
            steps = {b.mcu_ticks - a.mcu_ticks for a, b in itertools.pairwise(states)}
            assert steps == {16_000}
            assert states[-1].encoder == 12 * vmcu.counts_per_rev  # unwrapped past ±32768
            zero = [p for p in pulses if p.channel == vm.PULSE_ZERO]
            assert len(zero) == 12
            opt = next(p for p in pulses if p.channel == vm.PULSE_OPTICAL)
            # The virtual core's clock advances in ~1 ms pump steps, so heartbeat timestamps
            # (and the clock fit) are good to about a millisecond; 3 ms leaves room for a slow CI.
            assert opt.host_time == pytest.approx(t_pulse, abs=3e-3)

    asyncio.run(main())


def test_steppers_home_and_move_on_the_firmware(vmcu: vm.VirtualMcu) -> None:
    # fast axis so the test takes ~0.3 s: 2667 steps/s (< the firmware's 5000), 26 667 steps/s²
    gamma = AxisSettings("γ", 1, -20.0, 20.0, -20.0, max_rate_dps=300.0, accel_dps2=3000.0)
    vmcu.set_limit(1, -100)  # the home switch closes 100 steps below where the axis starts

    async def main() -> None:
        link = McuLink(McuSettings(port=vmcu.port))
        steppers = Steppers(link, StepperSettings(gamma=gamma))
        link.on_stepper = steppers.update
        link.on_refused = lambda r: steppers.refused(r.name, r.values, r.reason)
        async with link:
            steppers.home("γ")
            st = await steppers.wait_idle("γ", 2.0)
            assert st.homed and st.position_deg == -20.0
            steppers.move_to("γ", 0.0)
            st = await steppers.wait_idle("γ", 2.0)
            assert st.position_deg == pytest.approx(0.0, abs=0.5 / gamma.steps_per_deg)
            # the mechanism really stepped there: home switch at -100, then 20° of steps
            assert vmcu.stepper_position(1) == -100 + gamma.to_steps(0.0)

    asyncio.run(main())


def test_refusal_reaches_the_caller(vmcu: vm.VirtualMcu) -> None:
    async def main() -> None:
        link = McuLink(McuSettings(port=vmcu.port))
        steppers = Steppers(link)
        link.on_stepper = steppers.update
        link.on_refused = lambda r: steppers.refused(r.name, r.values, r.reason)
        await link.open()
        try:
            await link.identify()  # no heartbeat yet: the firmware keeps its outputs off
            steppers.home("phi")
            with pytest.raises(DeviceError, match="MCU refused φ stepper_home: outputs are refused"):
                await steppers.wait_idle("phi", 1.0)
            assert link.stats().nacks == 1 and link.refusals[0].values == (0,)
        finally:
            await link.close()

    asyncio.run(main())


def test_watchdog_cuts_outputs_when_heartbeats_stop(vmcu: vm.VirtualMcu) -> None:
    faults: list[FaultEvent] = []

    async def main() -> None:
        link = McuLink(McuSettings(port=vmcu.port, watchdog_ms=40), on_fault=faults.append)
        async with link:
            link.send_config(watchdog_ms=100, state_div=10, max_on_ms=0)
            await asyncio.sleep(0.02)
            assert link.send_pwm(0.4)
            await wait(lambda: abs(vmcu.pwm_duty - 0.4) <= 1 / 32767, 2.0)
            # (a loaded host can stall the virtual MCU's pump past the watchdog before this:
            # only a fault that comes after the heartbeat stops counts)
            before = len(faults)
            await link.stop_heartbeat()
            await wait(lambda: len(faults) > before, 1.0)
            assert faults[-1].name == "watchdog_expired" and faults[-1].detail == 100
            assert vmcu.pwm_duty == 0.0
            refused = len(link.refusals)
            link.send_pwm(0.4)  # refused until the next heartbeat
            await wait(lambda: len(link.refusals) > refused, 1.0)
            assert link.refusals[-1].name == "pwm_set" and link.refusals[-1].status == 2
            assert link.stats().faults == len(faults)

    asyncio.run(main())


wait = until  # the shared poll


def run_cli(argv: list[str], monkeypatch: pytest.MonkeyPatch) -> int:
    # the lead adds "mcu" to COMMANDS; until then the test registers it alone
    monkeypatch.setattr(cli_main, "COMMANDS", {"mcu": "tvsd.cli.mcu"})
    return cli_main.main(argv)


def test_cli_identify_ping_stats(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    try:
        vm.build_library()
    except vm.VirtualMcuError as exc:
        pytest.skip(f"virtual MCU unavailable: {exc}")
    assert run_cli(["mcu", "identify", "--sil", "--json"], monkeypatch) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["match"] is True and out["table_hash"] == f"0x{load_spec().table_hash:08X}"
    assert (
        run_cli(
            ["mcu", "ping", "--sil", "--count", "20", "--interval", "0", "--timeout", "5", "--json"],
            monkeypatch,
        )
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    assert out["answered"] == 20 and 0 < out["rtt_us"]["min"] <= out["rtt_us"]["max"]
    assert run_cli(["mcu", "stats", "--sil", "--seconds", "0.1"], monkeypatch) == 0
    text = capsys.readouterr().out
    assert "crc_errors" in text and "rx_frames" in text


def test_cli_user_mistakes_are_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run_cli(["mcu", "identify", "--port", "/dev/ttyNOPE7"], monkeypatch) == 3
    err = capsys.readouterr().err
    assert err == (
        "tvsctl: cannot open serial port /dev/ttyNOPE7: No such file or directory; "
        "check the cable / the path / permissions (dialout group)\n"
    )
    assert run_cli(["mcu", "ping", "--port", "/dev/null"], monkeypatch) == 3
    assert "not a serial port" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        run_cli(["mcu", "ping"], monkeypatch)
    assert info.value.code == 2
    assert "one of the arguments --port --sil is required" in capsys.readouterr().err
    assert run_cli(["mcu", "ping", "--port", "/dev/null", "--count", "0"], monkeypatch) == 2
    assert "--count must be at least 1" in capsys.readouterr().err
    assert run_cli(["mcu", "ping", "--port", "/dev/null", "--timeout", "0"], monkeypatch) == 2
    assert "--timeout must be more than 0 s, got 0.0" in capsys.readouterr().err
