"""The STM32F405 image's budget per state + PWM exchange, measured in QEMU (`tvsctl bench --only
mcu_stm32`, `make -C firmware bench-stm32`).

QEMU runs the real image with ``-icount shift=0``: the guest's clock advances 1 ns per executed
instruction, so the time the firmware spends awake (its 168 MHz SysTick read around each WFI,
``board_load``) in ns is the number of instructions it executed, whatever this machine's load.
Three phases of the same length in control ticks, the host answering as the daemon does:
  ticks   control ticks only (no state frames)
  state   a state frame every tick (10 kHz)
  exchange  a state frame every tick, each answered by a pwm_set (the 10 kHz exchange)
Instructions become cycles by a CPI of 1.0-1.5 (Cortex-M4: most instructions take 1 cycle, loads
2, taken branches 2-4; at 168 MHz the flash's 5 wait states are hidden by the ART cache for a loop
this small), plus 24 cycles of exception entry and exit per interrupt in the upper figure: an
estimate, stated as a range. One difference from the chip is counted apart: QEMU
raises no TXE interrupt, so the image sends by polling there, while on the chip every byte out
costs a TXE interrupt (~40 cycles with entry and exit), added to the upper figure.
The exchange phase runs three times: instruction counts vary with how the pty batches the host's
bytes (one wake-up per burst in QEMU, one per byte at 2 Mbaud on the chip); the upper figure
charges every wake-up QEMU saved (see _bench). The line budget is the frames' bytes at 10 bits
each (8N1) against the firmware's baud rate.
"""

from __future__ import annotations

import asyncio
import statistics
from dataclasses import dataclass, replace
from typing import Any

from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import FRAME_OVERHEAD, load_spec
from tvsd.sim import emulator, qemu_mcu

EXCHANGE_HZ = 10_000
BAUD = 2_000_000  # the image's (BOARD_BAUD in firmware/board/stm32f405/board.c)
BITS_PER_BYTE = 10  # 8N1
CPI = (1.0, 1.5)
TXE_ISR_CYCLES = 40
PHASE_TICKS = 4000  # 0.4 s of the board's time per phase
# QEMU feeds the pty's bytes to the USART one main-loop turn at a time, far slower in real time
# than 2 Mbaud under -icount: the host answers every 4th state frame, and the cost of a pwm_set
# is the difference to the state-only phase per frame parsed.
ANSWER_EVERY = 4
NS_PER_TICK = 1e9 / qemu_mcu.CLOCK_HZ


def bench_stm32(phase_ticks: int = PHASE_TICKS, pings: int = 50, repeats: int = 3) -> dict[str, Any]:
    missing = qemu_mcu.missing_tools()
    if missing:
        return {"mcu_stm32_skipped": f"missing {' '.join(missing)} (make system-deps)"}
    if not emulator.have_firmware_tree():  # an installed wheel: no firmware/ to build the image from
        return {"mcu_stm32_skipped": "needs a source checkout's firmware/ (make -C firmware bench-stm32)"}
    image = qemu_mcu.build_image()
    with qemu_mcu.QemuMcu(image, icount=True) as q:
        return asyncio.run(_bench(q, phase_ticks, pings, repeats))


@dataclass(frozen=True)
class Phase:
    insns_per_tick: float  # awake, per control tick
    wakeups_per_tick: float
    frames_per_tick: float  # frames the MCU parsed


async def _phase(q: qemu_mcu.QemuMcu, link: McuLink, ticks: int) -> Phase:
    rx0 = (await link.request_stats(timeout_s=10)).rx_frames
    a = q.load()
    while (b := q.load()).ticks_run < a.ticks_run + ticks:
        await asyncio.sleep(0.05)
    rx1 = (await link.request_stats(timeout_s=10)).rx_frames
    n = b.ticks_run - a.ticks_run
    span = (b.now - a.now) & 0xFFFF_FFFF
    idle = (b.idle_ticks - a.idle_ticks) & 0xFFFF_FFFF
    wakeups = (b.wakeups - a.wakeups) & 0xFFFF_FFFF
    return Phase((span - idle) * NS_PER_TICK / n, wakeups / n, (rx1 - rx0) / n)


async def _bench(q: qemu_mcu.QemuMcu, phase_ticks: int, pings: int, repeats: int) -> dict[str, Any]:
    spec = load_spec(None)
    by_name = {m.name: m for m in spec.messages}
    answer = False
    seen = 0

    def on_state(_: StateSample) -> None:
        nonlocal seen
        seen += 1
        if answer and seen % ANSWER_EVERY == 0:
            link.send_pwm(0.1)

    settings = replace(McuSettings(), port=q.port, watchdog_ms=1000, identify_timeout_ms=6000)
    settings = replace(settings, link_timeout_ms=1000, link_lost_ms=5000)
    link = McuLink(settings, on_state=on_state)
    async with link:
        rtts = [await link.ping(timeout_s=5) for _ in range(pings)]
        link.send_config(watchdog_ms=settings.watchdog_ms, state_div=0, max_on_ms=0)
        ticks = await _phase(q, link, phase_ticks)
        link.send_config(watchdog_ms=settings.watchdog_ms, state_div=1, max_on_ms=0)
        state = await _phase(q, link, phase_ticks)
        answer = True
        runs = [await _phase(q, link, phase_ticks) for _ in range(repeats)]
        answer = False
        link.send_config(watchdog_ms=settings.watchdog_ms, state_div=0, max_on_ms=0)
    state_bytes = FRAME_OVERHEAD + by_name["state"].size
    pwm_bytes = FRAME_OVERHEAD + by_name["pwm_set"].size

    def per_pwm(r: Phase) -> tuple[float, float]:  # instructions and wake-ups per pwm_set parsed
        frames = r.frames_per_tick - state.frames_per_tick
        return (r.insns_per_tick - state.insns_per_tick) / frames, (
            r.wakeups_per_tick - state.wakeups_per_tick
        ) / frames

    costs = [per_pwm(r) for r in runs]
    best = state.insns_per_tick + min(c for c, _ in costs)
    worst_c, worst_w = max(costs)
    # On the chip the pwm_set's bytes come 5 us apart, each waking the main loop; QEMU hands them
    # over in bursts. Each wake-up missing here is charged a whole idle control tick (interrupt,
    # main-loop pass and core_tick: more than a wake-up costs), so the upper figure is a bound.
    worst = state.insns_per_tick + worst_c + max(0.0, pwm_bytes - worst_w) * ticks.insns_per_tick
    lo = best * CPI[0]
    # plus what is no instruction: exception entry and exit (12 cycles each) of the SysTick and
    # every received byte's interrupt, and the TXE interrupt per byte sent on the chip
    hi = worst * CPI[1] + (pwm_bytes + 1) * 24 + state_bytes * TXE_ISR_CYCLES
    budget = qemu_mcu.CLOCK_HZ / EXCHANGE_HZ
    mhz = qemu_mcu.CLOCK_HZ / 1e6
    return {
        "mcu_stm32_insns_per_tick_idle": round(ticks.insns_per_tick),
        "mcu_stm32_insns_per_tick_state": round(state.insns_per_tick),
        "mcu_stm32_insns_per_pwm_set": "-".join(f"{c:.0f}" for c, _ in sorted(costs)),
        "mcu_stm32_wakeups_per_pwm_set": "-".join(f"{w:.1f}" for _, w in sorted(costs)),
        "mcu_stm32_insns_per_exchange": f"{best:.0f}-{state.insns_per_tick + worst_c:.0f}",
        "mcu_stm32_cycles_per_exchange_est": f"{lo:.0f}-{hi:.0f} of {budget:.0f}",
        "mcu_stm32_us_per_exchange_est": f"{lo / mhz:.1f}-{hi / mhz:.1f} of {1e6 / EXCHANGE_HZ:.0f}",
        "mcu_stm32_cpu_at_10khz_est_pct": f"{100 * lo / budget:.1f}-{100 * hi / budget:.1f}",
        "mcu_stm32_line_m2h_pct": round(100 * state_bytes * BITS_PER_BYTE * EXCHANGE_HZ / BAUD, 1),
        "mcu_stm32_line_h2m_pct": round(100 * pwm_bytes * BITS_PER_BYTE * EXCHANGE_HZ / BAUD, 1),
        "mcu_stm32_rtt_p50_ms_qemu": round(statistics.median(rtts) * 1e3, 2),
    }


if __name__ == "__main__":
    for k, v in bench_stm32().items():
        print(f"{k}: {v}")
