"""The STM32F405 image (firmware/board/stm32f405) in QEMU, driven by the real McuLink over a pty.

The image is the one `make -C firmware stm32` builds with arm-none-eabi-gcc; QEMU's netduinoplus2
is an STM32F405 with USART1 on a pseudo-terminal. What the board drives onto the PWM and laser
pins is read through the QEMU monitor (QEMU models neither TIM1 nor the GPIOs). QEMU runs with
`-icount shift=0,sleep=on`: the guest's time follows its instruction count while it runs, so its
busy time is exact when this shared machine is slow (the guest then runs slower than real time,
which the checks allow: they are in the MCU's own ticks, or waits bounded in host seconds with a
wide margin for the load); while it sleeps its clock follows the host's, so a host stall then
skips whole SysTick periods (the state period check allows whole periods and no lost frame).
"""

from __future__ import annotations

from dataclasses import replace

import mcu_exchange
import pytest
from conftest import until

from tvsd.config import load_config
from tvsd.daemon.drive_link import DriveLink
from tvsd.errors import DeviceError
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec
from tvsd.sim import qemu_mcu

pytestmark = pytest.mark.slow

# QEMU's pty backend notices the host side being opened by a 1 s poll, and this machine is shared:
# identify gets 3 tries over 6 s. Heartbeats every 25 ms against a 100 ms watchdog: the guest
# runs at ~0.2x real time here, so that is ~20 ms of the board's time.
SETTINGS = replace(
    McuSettings(), watchdog_ms=100, identify_timeout_ms=6000, link_timeout_ms=500, link_lost_ms=2000
)
TICKS_PER_CONTROL_TICK = qemu_mcu.CLOCK_HZ // 10_000
# The board's watchdog while the 10 kHz exchange is under test: QEMU feeds the pty to the USART a
# main-loop turn at a time, so a heartbeat can queue behind the 500 pwm_sets past 100 ms of the
# board's time (seen: watchdog_expired mid-exchange, 1 run in 8) — the emulator's input path, not
# the board. The watchdog's own cut is checked at SETTINGS.watchdog_ms below.
EXCHANGE_WATCHDOG_MS = 1000


@pytest.fixture(scope="module")
def image() -> qemu_mcu.Path:
    return mcu_exchange.built_image(
        qemu_mcu.missing_tools(), "STM32 toolchain/emulator", qemu_mcu.build_image
    )


def test_stm32_image_in_qemu_through_mcu_link(image: qemu_mcu.Path) -> None:
    spec = load_spec(None)

    async def run(q: qemu_mcu.QemuMcu) -> None:
        duty = 0.25
        want = round(duty * 32767)
        # QEMU feeds the pty's bytes to the USART one main-loop turn each, far below 2 Mbaud on a
        # loaded host: the exchange answers a bounded number of states, or a backlog of pwm_sets
        # would hold up every later frame.
        exchange = mcu_exchange.Exchange(duty)
        states = exchange.states

        async def drained() -> None:
            await mcu_exchange.drained(link, 60.0, lambda: q.load())

        link = exchange.open_link(replace(SETTINGS, port=q.port))
        async with link:
            mcu_exchange.check_identity(link, spec, SETTINGS, "stm32f405", 168_000_000, "atmega328p")
            await drained()

            # 10 kHz: a state frame every control tick, the first 500 answered by a PWM frame each
            exchange.answers = 500
            link.send_config(watchdog_ms=EXCHANGE_WATCHDOG_MS, state_div=1, max_on_ms=0)
            await until(lambda: len(states), 60, "state frames", ok=lambda n: n >= 3000, interval=0.05)
            # the stamps as sent, modulo the 16 bits protocol v1 carries (the host's v1 placement
            # slack is sized for 16 MHz ticks; v2 carries 32 bits)
            periods = [
                (b.mcu_ticks - a.mcu_ticks) % 65536
                for a, b in zip(states[-2000:], states[-1999:], strict=False)
            ]
            # Whole control ticks only. `-icount sleep=on` lets an idle guest's clock follow the
            # host's, so a host stall of the QEMU process while the board sleeps between ticks
            # comes back as one SysTick for several periods (seen beside a busy loop: 10 periods,
            # 36928 ticks mod 2^16; 1-2 in 2000): the board's clock skipped, no frame was lost
            # (the link's lost_frames == 0 below, by SEQ). A stamp off the tick grid is a bug.
            grid = {k * TICKS_PER_CONTROL_TICK % 65536 for k in range(1, 100)}
            off = sorted({p for p in periods if p not in grid})
            assert not off, f"state periods off the control tick grid (ticks): {off[:10]}"
            exact = sum(p == TICKS_PER_CONTROL_TICK for p in periods) / len(periods)
            print(f"state periods at exactly one control tick: {100 * exact:.2f} % of {len(periods)}")
            await drained()
            assert q.load().pwm_duty == want
            mcu = await link.request_stats(timeout_s=30.0)
            assert mcu.rx_frames >= 500 and mcu.crc_errors == 0, mcu
            st = link.stats()
            assert st.crc_errors == 0 and st.lost_frames == 0 and st.nacks == 0, (st, list(link.refusals))
            link.send_laser(True)
            await drained()
            assert q.load().laser

            # heartbeats stop: the board's watchdog cuts PWM and laser and says so
            async def outputs_cut() -> None:
                cut = q.load()
                assert (cut.pwm_duty, cut.laser) == (0, False)

            async def pwm_on() -> None:
                assert q.load().pwm_duty == want

            await mcu_exchange.check_watchdog_cut(
                link, SETTINGS, duty, state_div=0, timeout_s=30, drained=drained,
                outputs_cut=outputs_cut, pwm_on=pwm_on,
            )  # fmt: skip

        # the daemon's drive link refuses this board when the config names the ATmega
        cfg = load_config()
        cfg = replace(cfg, mcu=replace(cfg.mcu, port=q.port, board="atmega328p", identify_timeout_ms=6000))
        drive = DriveLink(cfg, None, "hardware", on_pulse=print, on_link=print, on_fault=print)  # type: ignore[arg-type]
        with pytest.raises(
            DeviceError, match=r"reports board stm32f405 but mcu\.board is atmega328p: set mcu\.board"
        ):
            await drive.start()
        assert drive.link is None

    mcu_exchange.run_on(qemu_mcu.QemuMcu(image, icount=True), run)


def test_missing_image_is_one_clear_error(tmp_path: qemu_mcu.Path) -> None:
    with pytest.raises(qemu_mcu.QemuMcuError, match="no firmware image"):
        qemu_mcu.QemuMcu(tmp_path / "none.elf").start()
