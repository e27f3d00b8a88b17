"""The ATmega328P image (firmware/board/atmega328p) in simavr, driven by the real McuLink over a pty.

The image is the one `make -C firmware sim-pty` builds with avr-gcc; firmware/sim/simavr_pty.c
runs it at 16 MHz with USART0 on a pseudo-terminal, paced to wall time (never faster: the
firmware's watchdog and the host's timeouts are both in real ms), and reports what the board
drives onto the PWM, direction and laser pins, read from Timer0's and PORTD's registers.

Timing on this shared machine: the checks on the board's own clock are exact (state stamps on the
grid of control ticks, 1600 ticks of 16 MHz each, one state every state_div of them, never early,
none lost: `_lateness`); the waits are host seconds with a wide margin for the load. The watchdog
is 100 ms against heartbeats every 25 ms: an event-loop stall under 75 ms cannot trip it. The
link timeouts are widened where the test is not about them (link_lost_ms 2 s), since a runner
that falls behind wall time delays every frame.

The exchange answers state frames with a pwm_set, but never two within 0.8 exchange periods of
host time. Answering every one, as the daemon does, overflows the board when the host's event loop
is late: it reads a batch of states and answers them back-to-back, and the ATmega's 64-byte RX
ring (5 pwm_set frames; CRC-32 costs the CPU ~80 % at 2 kHz) overflows; a larger ring would hold
the main loop past its 16-slot tick queue instead (control ticks lost). The board counts both
(stats rx_overflows, ticks_dropped; firmware/sim/simavr_smoke.c floods it on purpose). Those are
the board's limits under host bursts (a firmware matter), not the link's; this test checks the
link: every loss seen by the board, none on the way back, the duty on the pin.
"""

from __future__ import annotations

import itertools
from collections import Counter
from dataclasses import replace

import mcu_exchange
import pytest
from conftest import until

from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec
from tvsd.sim import simavr_mcu

pytestmark = pytest.mark.slow

SETTINGS = replace(
    McuSettings(board="atmega328p"),
    watchdog_ms=100,
    identify_timeout_ms=3000,
    link_timeout_ms=500,
    link_lost_ms=2000,
)
CONTROL_TICK_HZ = 10_000
TICKS_PER_CONTROL_TICK = simavr_mcu.CLOCK_HZ // CONTROL_TICK_HZ  # 1600
STATE_DIV = round(CONTROL_TICK_HZ / SETTINGS.exchange_hz)  # the daemon's (drive_link): 5 at 2 kHz
# The board's watchdog while the exchange is under test: on a loaded host the runner falls behind
# wall time and drops the excess (simavr_pty.c), a jump past a 100 ms watchdog that is the host's
# starvation, not the board's; the watchdog's own cut is checked at SETTINGS.watchdog_ms below.
EXCHANGE_WATCHDOG_MS = 1000
EXCHANGES = 2000  # states in the checked window: one second at the board's rate


def _lateness(stamps: list[int]) -> tuple[Counter[int], int]:
    """How many control ticks late each state's stamp is against the board's grid (a state every
    STATE_DIV ticks), and how many Timer1 stalls (below) were taken out first.

    A state frame carries the time of the newest control tick the main loop has caught up with:
    when a burst of pwm_set frames holds the loop up past a tick, the state goes out a tick or
    more late with that later tick's time and encoder count (a consistent pair for the host).
    So stamps sit on the tick grid, never early, and fall back onto the grid: a tick lost would
    shift every later stamp, which the last check catches.

    The stall: in simavr, when a control tick falls exactly on a Timer1 wrap (every 25 wraps,
    102.4 ms) the OCR1B = 0 compare match is at times missed for one full timer period, and the
    10 kHz tick stops for 65536 cycles (4.1 ms). It is counted and taken out of the grid here,
    only where a tick was due on a wrap (~1 in 10 such ticks here); any other stop fails.
    """
    per = STATE_DIV * TICKS_PER_CONTROL_TICK
    shift, stalls, offs = 0, 0, [0]
    for a, b in itertools.pairwise(stamps):
        if b - a > 65536:
            # only the simavr stall: a tick due exactly on the wrap (OCR1B = 0) fired a wrap late
            on_wrap = [j for j in range(1, STATE_DIV + 1) if (a + j * TICKS_PER_CONTROL_TICK) % 65536 == 0]
            assert on_wrap, f"the 10 kHz tick stopped for {b - a} ticks after stamp {a:#x}"
            shift, stalls = shift + 65536, stalls + 1
        offs.append(b - stamps[0] - shift - per * len(offs))
    base = min(offs)
    bad = [o for o in offs if (o - base) % TICKS_PER_CONTROL_TICK]
    assert not bad, f"state stamps off the {TICKS_PER_CONTROL_TICK}-tick grid: {bad[:10]}"
    late = Counter((o - base) // TICKS_PER_CONTROL_TICK for o in offs)
    assert min(offs[-200:]) == base, "the stamps stayed late: control ticks were lost"
    return late, stalls


@pytest.fixture(scope="module")
def image() -> simavr_mcu.Path:
    return mcu_exchange.built_image(simavr_mcu.missing_tools(), "AVR toolchain/simavr", simavr_mcu.build)


def test_atmega_image_in_simavr_through_mcu_link(image: simavr_mcu.Path) -> None:
    spec = load_spec(None)
    duty = 0.25
    want = round(duty * 32767)

    async def run(m: simavr_mcu.SimavrMcu) -> None:
        exchange = mcu_exchange.Exchange(duty, min_gap_s=0.8 / SETTINGS.exchange_hz)
        states = exchange.states

        async def drained() -> None:
            await mcu_exchange.drained(link, 10.0, lambda: m.pace())

        link = exchange.open_link(replace(SETTINGS, port=m.port))
        async with link:
            mcu_exchange.check_identity(link, spec, SETTINGS, "atmega328p", simavr_mcu.CLOCK_HZ, "stm32f405")
            rtts = [await link.ping(timeout_s=10.0) for _ in range(20)]
            assert all(r > 0 for r in rtts), rtts

            # the board's exchange rate: a state frame every STATE_DIV ticks, answered by PWM
            # frames (no bursts) for the first EXCHANGES of them, then 200 more states unanswered
            exchange.answers = EXCHANGES
            link.send_config(watchdog_ms=EXCHANGE_WATCHDOG_MS, state_div=STATE_DIV, max_on_ms=0)
            await until(lambda: len(states), 60, "state frames", ok=lambda n: n >= EXCHANGES, interval=0.05)
            answered, exchange.answers = EXCHANGES - exchange.answers, 0
            await until(
                lambda: len(states), 60, "state frames", ok=lambda n: n >= EXCHANGES + 200, interval=0.05
            )
            # one read of the pty per 10 ms at least, even on a loaded host: 100 answers per second
            assert answered >= 100, f"only {answered} of {EXCHANGES} states answered"
            try:
                late, stalls = _lateness([s.mcu_ticks for s in states[-EXCHANGES:]])
            except AssertionError as exc:  # dropped by the board (its counts) or on the way (the link's)?
                mcu = await link.request_stats(timeout_s=10.0)
                raise AssertionError(f"{exc}; board {mcu}; link {link.stats()}") from None
            print(f"state stamps: late by {dict(sorted(late.items()))} control ticks; {stalls} stall(s)")
            await drained()
            await until(
                m.outputs,
                10,
                "the duty on the PWM pin",
                ok=lambda o: o is not None and o.pwm and o.ocr0a == simavr_mcu.duty_to_ocr0a(want),
            )
            sent = link.stats().frames_tx + 1  # and the stats_req
            mcu = await link.request_stats(timeout_s=10.0)
            lost = max(0, sent - mcu.rx_frames)
            print(f"pwm exchange: {answered} pwm_set, {lost} of {sent} host frames lost in RX: {mcu}")
            assert mcu.tx_dropped == 0, mcu
            # each frame lost in the RX ring lost a byte there at least, and the board counted it
            assert lost <= mcu.rx_overflows, f"{lost} frames lost unseen by the board: {mcu}"
            st = link.stats()
            assert st.crc_errors == 0 and st.lost_frames == 0 and st.nacks == 0, (st, list(link.refusals))
            link.send_laser(True)
            await drained()
            await until(m.outputs, 10, "the laser pin high", ok=lambda o: o is not None and o.laser)

            # heartbeats stop: the board's watchdog cuts PWM and laser and says so
            await mcu_exchange.check_watchdog_cut(
                link, SETTINGS, duty, state_div=STATE_DIV, timeout_s=10, drained=drained,
                outputs_cut=lambda: until(
                    m.outputs, 10, "PWM and laser cut", ok=lambda o: o is not None and not (o.pwm or o.laser)
                ),
                pwm_on=lambda: until(m.outputs, 10, "PWM on again", ok=lambda o: o is not None and o.pwm),
            )  # fmt: skip
        rtts.sort()
        print(f"simavr round trip p50 {rtts[len(rtts) // 2] * 1e6:.0f} µs; pace {m.pace()}")

    mcu_exchange.run_on(simavr_mcu.SimavrMcu(image), run)


def test_missing_image_is_one_clear_error(tmp_path: simavr_mcu.Path) -> None:
    with pytest.raises(simavr_mcu.SimavrMcuError, match="no firmware image"):
        simavr_mcu.SimavrMcu(tmp_path / "none.elf").start()


def test_unreadable_image_is_one_clear_error(tmp_path: simavr_mcu.Path, image: simavr_mcu.Path) -> None:
    junk = tmp_path / "junk.elf"
    junk.write_bytes(b"not an ELF file")
    said = r"exited with status 2: (?s:.*)cannot read the firmware"
    with pytest.raises(simavr_mcu.SimavrMcuError, match=said):
        simavr_mcu.SimavrMcu(junk).start()
