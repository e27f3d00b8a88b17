/* The portable MCU core: what a board's main loop and ISRs call. */
#ifndef CORE_H
#define CORE_H
#include <stdbool.h>
#include <stdint.h>

#include "core_config.h"
#include "frame.h"

typedef struct {
    uint16_t watchdog_ms; /* no heartbeat for this long: PWM 0, laser off, steppers stop */
    uint16_t state_div;   /* state frame every state_div control ticks, 0 = none */
    uint16_t max_on_ms;   /* an output not re-commanded for this long is switched off, 0 = off */
} core_config_t;

extern core_config_t core_cfg;

typedef struct {
    uint32_t rx_frames;
    uint16_t crc_errors, resyncs, tx_dropped, duplicates, rx_overflows, ticks_dropped;
    uint16_t watchdog_expiries; /* heartbeat watchdog cuts since boot (outputs.c) */
} core_stats_t;

/* Counted by the board's ISRs, reported in stats (modulo 65536, like the others): a received
 * byte its RX ring had no room for (the frame check then throws the torn frame out and the parser
 * resyncs), and a control tick its tick queue had no room for (the main loop was held up past the
 * queue: the ticks beyond it are dropped, not replayed late, and the host sees a stamp gap). */
extern volatile uint16_t core_rx_overflows, core_ticks_dropped;

void core_init(void);
/* Main context. */
extern frame_parser_t core_parser;
static inline void core_rx_byte(uint8_t b) { frame_parser_feed(&core_parser, b); }
/* At CORE_TICK_HZ, with the tick's time and the encoder count sampled together when the tick
 * fell due (in the timer interrupt on a chip), so state frames carry exact periods even when
 * the main loop runs the tick late. */
void core_tick(uint32_t now, int32_t encoder);
void core_poll(void); /* as often as possible: pulse and stepper events to frames */
void core_stats(core_stats_t *s);
/* Send a fault frame (main context). */
void core_fault(uint8_t code, uint16_t detail);

/* Set by ISRs that leave work for core_poll (pulse, stepper event); main clears it. */
extern volatile bool core_events;

/* ISR context. */
static inline bool core_tx_pop(uint8_t *b) { return frame_tx_pop(b); }
void core_pulse_isr(uint8_t channel, uint32_t ticks);

#endif
