/* What main.c needs from this board beyond board.h. */
#ifndef BOARD_AVR_H
#define BOARD_AVR_H
#include <stdbool.h>
#include <stdint.h>

extern volatile uint8_t board_tick_pending; /* control ticks due, set by the Timer1 ISR */
/* Time and encoder count sampled by the tick ISR for the latest tick. */
void board_tick_sample(uint32_t *t, int32_t *encoder);
void board_init(void);
bool board_rx_pop(uint8_t *b);
extern volatile uint8_t board_rx_head, board_rx_tail; /* UART RX ring, ISR -> main */
static inline bool board_rx_pending(void) { return board_rx_head != board_rx_tail; }

#endif
