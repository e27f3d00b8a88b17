/* ATmega328P main loop: bytes in, control ticks, events out; kicks the hardware watchdog.
 * If this loop ever stalls for 30 ms the AVR watchdog resets the chip, and a reset leaves
 * every output off (pins low) until the host arms the core again with a heartbeat. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>

#include "board_avr.h"
#include "core.h"

int main(void)
{
    MCUSR = 0;
    wdt_disable();
    board_init();
    core_init();
    wdt_enable(WDTO_30MS);
    set_sleep_mode(SLEEP_MODE_IDLE); /* timers and UART keep running */
    sei();
    for (;;) {
        wdt_reset();
        /* Bounded work per pass: at most 16 received bytes, then one control tick. Under an
         * input flood the RX ring overflows (stats rx_overflows; the torn frames are CRC errors
         * and resyncs) but the ticks, and with them the heartbeat watchdog, keep running;
         * unbounded draining would starve them. */
        uint8_t b;
        for (uint8_t i = 0; i < 16u && board_rx_pop(&b); i++)
            core_rx_byte(b);
        uint32_t t;
        int32_t enc;
        if (board_tick_pop(&t, &enc))
            core_tick(t, enc);
        core_poll();
        /* Idle until an interrupt leaves work (the 10 kHz tick at the latest). Interrupts are
         * off while we look for work; SEI takes effect after SLEEP, so no wake-up is missed.
         * A wake-up that leaves no work (the UART-empty interrupt, one per byte sent: 15 per
         * state frame) goes straight back to sleep instead of running a whole pass. */
        cli();
        while (!board_tick_pending() && !board_rx_pending() && !core_events) {
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
            cli();
        }
        sei();
    }
}
