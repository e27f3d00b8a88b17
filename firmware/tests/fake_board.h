/* Test double of board.h: time is set by the test, outputs are recorded. */
#ifndef FAKE_BOARD_H
#define FAKE_BOARD_H
#include <stdbool.h>
#include <stdint.h>

#include "core.h"

#define FAKE_MAX_STEPS 4096

typedef struct {
    uint32_t now;
    int32_t encoder;
    int16_t pwm;
    bool laser;
    int32_t pos[STEPPER_AXES];       /* the mechanism's own position, from the pulses */
    bool limit_on[STEPPER_AXES];     /* a home switch exists at limit_pos (closed at or below) */
    int32_t limit_pos[STEPPER_AXES];
    bool dir_negative[STEPPER_AXES];
    uint32_t step_count[STEPPER_AXES];
    uint32_t step_time[STEPPER_AXES][FAKE_MAX_STEPS]; /* time of each step pulse */
    bool stepper_wake;
} fake_board_t;

extern fake_board_t fb;

void fake_reset(void);
/* Run the core up to fb.now + dt: control ticks every CORE_TICKS_PER_TICK and the stepper
 * service at each due time, in time order, as the timer ISRs would. */
void fake_advance(uint32_t dt);

/* Host->MCU frame into the core. */
void fake_send(uint8_t id, const uint8_t *payload, uint8_t len);
/* Next MCU->host frame from the TX ring; returns its id or -1. */
typedef struct {
    uint16_t seq;
    uint8_t id, len;
    uint8_t payload[64];
} fake_frame_t;
int fake_recv(fake_frame_t *f);
/* Receive until a frame of `id` (skipping others); returns 1 if found. */
int fake_recv_id(uint8_t id, fake_frame_t *f);
/* Encode a frame into buf, return its length. */
uint8_t fake_encode(uint8_t *buf, uint16_t seq, uint8_t id, const uint8_t *payload, uint8_t len);

/* Protocol helpers: a heartbeat, a config_set, and the status of the next ack (-1: none). */
void fake_heartbeat(uint32_t host_us);
void fake_config(uint16_t watchdog_ms, uint16_t state_div, uint16_t max_on_ms);
int fake_ack_status(void);

#endif
