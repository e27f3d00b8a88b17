/* Pulse events (zero and optical sensors) from capture ISRs to the main loop. Every event gets
 * the next event_seq, even one dropped because the queue or the TX ring was full, so the host
 * counts losses from gaps. */
#ifndef PULSE_H
#define PULSE_H
#include <stdbool.h>
#include <stdint.h>

typedef struct {
    uint8_t channel;
    uint16_t event_seq;
    uint32_t ticks;
} pulse_event_t;

void pulse_reset(void);
/* ISR context (AVR ISRs do not nest, so the two capture ISRs never race each other). */
void pulse_record(uint8_t channel, uint32_t ticks);
/* Main context. */
bool pulse_pop(pulse_event_t *ev);
uint16_t pulse_queue_dropped(void);

#endif
