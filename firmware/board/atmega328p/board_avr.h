/* What main.c needs from this board beyond board.h. */
#ifndef BOARD_AVR_H
#define BOARD_AVR_H
#include <stdbool.h>
#include <stdint.h>

/* Control ticks due, each with its own time and encoder count, queued by the Timer1 compare ISR:
 * when the main loop runs late by a tick or more (a burst of frames, a stepper_move's planning),
 * every tick still reports its own sample. Beyond BOARD_TICK_QUEUE behind, ticks are dropped (the
 * host sees a stamp gap; stats ticks_dropped counts them): a long stall costs at most 16 late
 * ticks, never a replay of all it missed. 8-bit indices: the AVR reads and writes each in one
 * instruction, so neither side needs cli(). Inline: the pop runs 10,000 times a second on a
 * busy chip. */
/* A full RX ring (64 B: 5 pwm_set, ~11 000 cycles to parse) holds the loop ~7 ticks, more with
 * the encoder's interrupts (the smoke test's burst: 6.6): 16 slots, 128 B of RAM. */
#define BOARD_TICK_QUEUE 16u
typedef struct {
    uint32_t time;
    int32_t encoder;
} board_tick_t;
extern board_tick_t board_tq[BOARD_TICK_QUEUE];
extern volatile uint8_t board_tq_head, board_tq_tail;

static inline bool board_tick_pending(void) { return board_tq_head != board_tq_tail; }

/* The oldest tick due: its own time and encoder count; false if none. */
static inline bool board_tick_pop(uint32_t *t, int32_t *encoder)
{
    uint8_t tail = board_tq_tail;
    if (tail == board_tq_head)
        return false;
    __asm__ volatile("" ::: "memory");
    const board_tick_t *slot = &board_tq[tail & (BOARD_TICK_QUEUE - 1u)];
    *t = slot->time; /* the ISR writes a slot only once the tail has passed it */
    *encoder = slot->encoder;
    __asm__ volatile("" ::: "memory");
    board_tq_tail = (uint8_t)(tail + 1u);
    return true;
}
void board_init(void);
bool board_rx_pop(uint8_t *b);
extern volatile uint8_t board_rx_head, board_rx_tail; /* UART RX ring, ISR -> main */
static inline bool board_rx_pending(void) { return board_rx_head != board_rx_tail; }

#endif
