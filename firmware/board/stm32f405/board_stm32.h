/* What main.c needs from this board beyond board.h. */
#ifndef BOARD_STM32_H
#define BOARD_STM32_H
#include <stdbool.h>
#include <stdint.h>

/* Processor load and the outputs as driven, read through the QEMU monitor by the emulated runs
 * (tvsd/sim/qemu_mcu.py: QEMU models neither TIM1 nor the GPIOs). Layout fixed: 6 words. */
typedef struct {
    uint32_t now;        /* board_ticks() at the last control tick */
    uint32_t idle_ticks; /* ticks spent asleep in WFI, wraps at 2^32 */
    uint32_t ticks_run;  /* control ticks run by the main loop */
    int32_t pwm_duty;    /* last board_set_pwm() */
    uint32_t laser;      /* last board_set_laser() */
    uint32_t wakeups;    /* WFI exits */
} board_load_t;
extern volatile board_load_t board_load;

bool board_init(void);  /* false: the clock did not come up (outputs stay off) */
void board_start(void); /* interrupts, control tick and watchdog on */
/* The oldest control tick due (its time and encoder count, sampled by the SysTick ISR). */
bool board_tick_pop(uint32_t *t, int32_t *encoder);
bool board_tick_pending(void);
bool board_rx_pop(uint8_t *b);
bool board_rx_pending(void);
void board_tx_service(void);
void board_watchdog_kick(void);

#endif
