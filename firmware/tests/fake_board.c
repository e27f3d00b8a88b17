#include "fake_board.h"

#include <string.h>

#include "crc32.h"
#include "protocol_gen.h"
#include "stepper.h"

fake_board_t fb;
static uint32_t next_tick;
static uint32_t step_due;
static bool step_active;
static uint16_t host_seq;

uint32_t board_ticks(void) { return fb.now; }
int32_t board_encoder(void) { return fb.encoder; }
void board_set_pwm(int16_t duty) { fb.pwm = duty; }
void board_set_laser(bool on) { fb.laser = on; }
void board_step_dir(uint8_t axis, bool negative) { fb.dir_negative[axis] = negative; }
bool board_limit(uint8_t axis) { return fb.limit_on[axis] && fb.pos[axis] <= fb.limit_pos[axis]; }
void board_tx_kick(void) {}
uint8_t board_irq_save(void) { return 0; }
void board_irq_restore(uint8_t s) { (void)s; }

void board_step_pulse(uint8_t axis)
{
    if (fb.step_count[axis] < FAKE_MAX_STEPS)
        fb.step_time[axis][fb.step_count[axis]] = fb.now;
    fb.step_count[axis]++;
    fb.pos[axis] += fb.dir_negative[axis] ? -1 : 1;
}

void board_stepper_wake(void)
{
    step_active = stepper_service(fb.now, &step_due);
}

void fake_reset(void)
{
    memset(&fb, 0, sizeof fb);
    fb.now = 1000; /* not 0: catches code that treats time 0 as "never" */
    next_tick = fb.now + CORE_TICKS_PER_TICK;
    step_active = false;
    host_seq = 0;
    core_init();
}

void fake_advance(uint32_t dt)
{
    uint32_t end = fb.now + dt;
    for (;;) {
        uint32_t t = next_tick;
        bool is_step = step_active && (int32_t)(step_due - t) < 0;
        if (is_step)
            t = step_due;
        if ((int32_t)(t - end) > 0)
            break;
        fb.now = t;
        if (is_step) {
            step_active = stepper_service(fb.now, &step_due);
        } else {
            next_tick += CORE_TICKS_PER_TICK;
            core_tick(fb.now, fb.encoder);
        }
        core_poll();
    }
    fb.now = end;
}

uint8_t fake_encode(uint8_t *buf, uint16_t seq, uint8_t id, const uint8_t *payload, uint8_t len)
{
    buf[0] = PROTO_SYNC;
    buf[PROTO_OFF_LEN] = len;
    proto_put_u16(buf + PROTO_OFF_SEQ, seq);
    buf[PROTO_OFF_ID] = id;
    if (len)
        memcpy(buf + PROTO_HEADER, payload, len);
    proto_put_u32(buf + PROTO_HEADER + len, crc32(buf, (uint8_t)(PROTO_HEADER + len)));
    return (uint8_t)(len + PROTO_OVERHEAD);
}

void fake_send(uint8_t id, const uint8_t *payload, uint8_t len)
{
    uint8_t buf[PROTO_MAX_FRAME + 16];
    uint8_t n = fake_encode(buf, host_seq++, id, payload, len);
    for (uint8_t i = 0; i < n; i++)
        core_rx_byte(buf[i]);
    core_poll();
}

int fake_recv(fake_frame_t *f)
{
    uint8_t raw[PROTO_HEADER + 64 + PROTO_CRC_BYTES];
    for (;;) {
        if (!core_tx_pop(&raw[0]))
            return -1;
        if (raw[0] == PROTO_SYNC)
            break;
    }
    for (unsigned i = 1; i < PROTO_HEADER; i++)
        if (!core_tx_pop(&raw[i]))
            return -1;
    f->len = raw[PROTO_OFF_LEN];
    f->seq = proto_get_u16(raw + PROTO_OFF_SEQ);
    f->id = raw[PROTO_OFF_ID];
    if (f->len > 64)
        return -2;
    for (uint8_t i = 0; i < f->len + PROTO_CRC_BYTES; i++)
        if (!core_tx_pop(&raw[PROTO_HEADER + i]))
            return -1;
    memcpy(f->payload, raw + PROTO_HEADER, f->len);
    uint8_t body = (uint8_t)(PROTO_HEADER + f->len);
    if (crc32(raw, body) != proto_get_u32(raw + body))
        return -2;
    return f->id;
}

int fake_recv_id(uint8_t id, fake_frame_t *f)
{
    int r;
    while ((r = fake_recv(f)) >= 0)
        if (r == id)
            return 1;
    return 0;
}

void fake_heartbeat(uint32_t host_us)
{
    uint8_t p[MSG_HEARTBEAT_LEN];
    proto_put_u32(p, host_us);
    fake_send(MSG_HEARTBEAT_ID, p, sizeof p);
}

void fake_config(uint16_t watchdog_ms, uint16_t state_div, uint16_t max_on_ms)
{
    uint8_t p[MSG_CONFIG_SET_LEN];
    msg_config_set_t m = {watchdog_ms, state_div, max_on_ms};
    msg_config_set_pack(p, &m);
    fake_send(MSG_CONFIG_SET_ID, p, sizeof p);
}

int fake_ack_status(void)
{
    fake_frame_t f;
    if (!fake_recv_id(MSG_ACK_ID, &f))
        return -1;
    return f.payload[MSG_ACK_STATUS_OFF];
}
