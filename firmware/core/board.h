/* The only things the portable core asks of a board. One implementation per folder in
 * firmware/board/<name>/; the core never touches registers. Functions marked ISR-safe may be
 * called from interrupt context. */
#ifndef BOARD_H
#define BOARD_H
#include <stdbool.h>
#include <stdint.h>

/* Free-running timestamp counter at BOARD_CLOCK_HZ (see core_config.h), wraps at 2^32. */
uint32_t board_ticks(void);
/* Quadrature encoder count (4 counts per line), signed, wraps at 2^32. */
int32_t board_encoder(void);
/* Motor H-bridge: duty -32767..32767 = -100..100 %, sign = direction. */
void board_set_pwm(int16_t duty);
void board_set_laser(bool on);
/* Steppers (axis 0 = mirror phi, 1 = rod gamma). ISR-safe. */
void board_step_dir(uint8_t axis, bool negative);
void board_step_pulse(uint8_t axis);
/* Home/limit switch of an axis, true when pressed. ISR-safe. */
bool board_limit(uint8_t axis);
/* The stepper plan changed: arrange for core_stepper_service() to run now. */
void board_stepper_wake(void);
/* Bytes were queued for transmission: start draining with core_tx_pop(). */
void board_tx_kick(void);
/* Critical sections around state shared with interrupt handlers. */
uint8_t board_irq_save(void);
void board_irq_restore(uint8_t state);

#endif
