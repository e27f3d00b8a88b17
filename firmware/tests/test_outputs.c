/* Fail-safes: the heartbeat watchdog and the max-on duration of every output. The core checks
 * them once per control tick, so an output goes off between T and T + one tick (100 us) after
 * its deadline T: that is the tolerance used below. */
#include "check.h"
#include "fake_board.h"
#include "outputs.h"
#include "protocol_gen.h"
#include "stepper.h"

#define MS CORE_TICKS_PER_MS
#define TICK CORE_TICKS_PER_TICK

static void pwm(int16_t duty)
{
    uint8_t p[2];
    proto_put_u16(p, (uint16_t)duty);
    fake_send(MSG_PWM_SET_ID, p, 2);
}

static void laser(uint8_t on)
{
    fake_send(MSG_LASER_SET_ID, &on, 1);
}

static void drain(void)
{
    fake_frame_t f;
    while (fake_recv(&f) >= 0) {
    }
}

/* Advance in single timer ticks until `cond` holds; returns the time taken, or ~0u. */
#define TIME_UNTIL(cond, limit)                                                            \
    ({                                                                                     \
        uint32_t t0_ = fb.now, r_ = ~0u;                                                   \
        while (fb.now - t0_ <= (limit)) {                                                  \
            if (cond) {                                                                    \
                r_ = fb.now - t0_;                                                         \
                break;                                                                     \
            }                                                                              \
            fake_advance(16);                                                              \
        }                                                                                  \
        r_;                                                                                \
    })

void test_watchdog_cutoff(void)
{
    fake_reset();
    fake_config(50, 0, 0);
    fake_heartbeat(1);
    pwm(30000);
    laser(1);
    CHECK_EQ(stepper_move(0, 100000, 1000, 1000, fb.now), ACK_OK);
    drain();
    uint32_t t = TIME_UNTIL(fb.pwm == 0, 60 * MS);
    CHECK(t >= 50 * MS && t <= 50 * MS + TICK, "PWM cut after %u ticks, want 50 ms (+1 tick)", t);
    CHECK(!fb.laser, "laser must be off with the PWM");
    CHECK(!stepper_moving(0), "stepper must stop on watchdog");
    fake_frame_t f;
    CHECK_EQ(fake_recv_id(MSG_FAULT_ID, &f), 1);
    CHECK_EQ(f.payload[0], FAULT_WATCHDOG_EXPIRED);
    CHECK_EQ(proto_get_u16(f.payload + 1), 50);
    drain();
    fake_advance(200 * MS);
    CHECK_EQ(fake_recv_id(MSG_FAULT_ID, &f), 0); /* one fault per expiry, not one per tick */
    pwm(1000);
    CHECK_EQ(fake_ack_status(), ACK_NO_HEARTBEAT);
    CHECK_EQ(fb.pwm, 0);
}

/* The tick's time is sampled when it falls due; a heartbeat handled between that moment and
 * the tick's processing is "newer" than the tick and must not read as 2^32 ticks old. */
void test_watchdog_sample_before_heartbeat(void)
{
    fake_reset();
    fake_config(50, 0, 0);
    fake_heartbeat(1);
    pwm(1000);
    core_tick(fb.now - 10, 0);
    CHECK_EQ(fb.pwm, 1000);
    CHECK(outputs_armed(), "watchdog expired on a tick sampled just before the heartbeat");
}

void test_watchdog_kept_alive(void)
{
    fake_reset();
    fake_config(50, 0, 0);
    fake_heartbeat(1);
    pwm(-12000);
    for (int i = 0; i < 25; i++) { /* 1 s of heartbeats every 40 ms */
        fake_advance(40 * MS);
        fake_heartbeat((uint32_t)i);
    }
    CHECK_EQ(fb.pwm, -12000);
    fake_frame_t f;
    CHECK_EQ(fake_recv_id(MSG_FAULT_ID, &f), 0);
}

void test_max_on(void)
{
    fake_reset();
    fake_config(1000, 0, 20);
    fake_heartbeat(1);
    laser(1);
    pwm(5000);
    drain();
    /* PWM re-commanded every 5 ms stays on; the laser, commanded once, goes off at 20 ms. */
    uint32_t t0 = fb.now, laser_off = 0;
    for (int i = 0; i < 20; i++) {
        for (uint32_t k = 0; k < 5 * MS / 16; k++) {
            fake_advance(16);
            if (!fb.laser && !laser_off)
                laser_off = fb.now - t0;
        }
        pwm(5000);
    }
    CHECK(laser_off >= 20 * MS && laser_off <= 20 * MS + TICK, "laser off after %u ticks",
          laser_off);
    CHECK_EQ(fb.pwm, 5000);
    fake_frame_t f;
    CHECK_EQ(fake_recv_id(MSG_FAULT_ID, &f), 1);
    CHECK_EQ(f.payload[0], FAULT_OUTPUT_TIMEOUT);
    CHECK_EQ(proto_get_u16(f.payload + 1), OUTPUT_LASER);
    fake_heartbeat(2);
    uint32_t t = TIME_UNTIL(fb.pwm == 0, 30 * MS);
    CHECK(t >= 20 * MS && t <= 20 * MS + TICK, "PWM off after %u ticks", t);
    /* A stepper move longer than max-on is stopped too. */
    CHECK_EQ(stepper_move(1, 100000, 1000, 1000, fb.now), ACK_OK);
    fake_heartbeat(3);
    drain();
    t = TIME_UNTIL(!stepper_moving(1), 30 * MS);
    CHECK(t >= 20 * MS && t <= 20 * MS + TICK, "stepper stopped after %u ticks", t);
    CHECK_EQ(fake_recv_id(MSG_FAULT_ID, &f), 1);
    CHECK_EQ(proto_get_u16(f.payload + 1), OUTPUT_STEPPER0 + 1);
}
