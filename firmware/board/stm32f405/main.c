/* STM32F405 main loop: bytes in, control ticks, events out; kicks the hardware watchdog (IWDG,
 * 30 ms: a stalled loop resets the chip, and a reset leaves every output off until the host
 * arms the core again with a heartbeat). Sleeps in WFI between interrupts and counts the time
 * asleep (board_load) for `make bench-stm32`. */
#include "board.h"
#include "board_stm32.h"
#include "core.h"

int main(void)
{
    if (!board_init())
        for (;;) { /* no crystal: outputs stay off, the host's identify times out */
        }
    core_init();
    board_start();
    for (;;) {
        board_watchdog_kick();
        /* Bounded work per pass: at most 64 received bytes, then one control tick, so an input
         * flood cannot starve the ticks (and with them the heartbeat watchdog). */
        uint8_t b;
        for (uint32_t i = 0; i < 64u && board_rx_pop(&b); i++)
            core_rx_byte(b);
        uint32_t t;
        int32_t enc;
        if (board_tick_pop(&t, &enc)) {
            core_tick(t, enc);
            board_load.now = t;
            board_load.ticks_run++;
        }
        core_poll();
        board_tx_service();
        /* Sleep until the next interrupt with interrupts masked: WFI still wakes on a pending
         * one, and the time asleep is read before its handler runs (handlers count as busy). */
        __asm volatile("cpsid i" ::: "memory");
        if (!board_tick_pending() && !board_rx_pending()) {
            uint32_t t0 = board_ticks();
            __asm volatile("dsb\n\twfi" ::: "memory");
            board_load.idle_ticks += board_ticks() - t0;
            board_load.wakeups++;
        }
        __asm volatile("cpsie i" ::: "memory");
    }
}
