#include "pulse.h"

#include "core_config.h"

#define MASK (CORE_PULSE_QUEUE - 1u)
static pulse_event_t queue[CORE_PULSE_QUEUE];
static volatile uint8_t head, tail; /* free-running, single byte = atomic on AVR */
static uint16_t next_seq, dropped;

void pulse_reset(void)
{
    head = tail = 0;
    next_seq = 0;
    dropped = 0;
}

void pulse_record(uint8_t channel, uint32_t ticks)
{
    uint16_t seq = next_seq++;
    uint8_t h = head;
    if ((uint8_t)(h - tail) >= CORE_PULSE_QUEUE) {
        dropped++;
        return;
    }
    queue[h & MASK] = (pulse_event_t){channel, seq, ticks};
    head = (uint8_t)(h + 1u);
}

bool pulse_pop(pulse_event_t *ev)
{
    uint8_t t = tail;
    if (t == head)
        return false;
    *ev = queue[t & MASK];
    tail = (uint8_t)(t + 1u);
    return true;
}

uint16_t pulse_queue_dropped(void) { return dropped; }
