/* Command table: one handler per host->MCU message, built from protocol_gen.h's list, so a
 * message added to protocol.yaml without a handler here fails to compile. */
#include "dispatch.h"

#include "board.h"
#include "core.h"
#include "outputs.h"
#include "protocol_gen.h"
#include "stepper.h"

#define X(id, name, len) static void handle_##name(const frame_t *f);
PROTO_H2M_LIST(X)
#undef X

typedef struct {
    uint8_t id, len;
    void (*fn)(const frame_t *f);
} command_t;

static const command_t commands[] = {
#define X(id, name, len) {id, len, handle_##name},
    PROTO_H2M_LIST(X)
#undef X
};

void dispatch_frame(const frame_t *f)
{
    for (uint8_t i = 0; i < sizeof commands / sizeof commands[0]; i++) {
        if (commands[i].id != f->id)
            continue;
        if (commands[i].len == f->len) {
            commands[i].fn(f);
            return;
        }
        break;
    }
    core_fault(FAULT_BAD_FRAME, (uint16_t)((f->id << 8) | f->len));
}

static void send_ack(const frame_t *f, uint8_t status)
{
    uint8_t p[MSG_ACK_LEN];
    msg_ack_t m = {f->seq, status};
    msg_ack_pack(p, &m);
    frame_send(MSG_ACK_ID, p, sizeof p);
}

void dispatch_send_stepper_state(uint8_t axis)
{
    uint8_t p[MSG_STEPPER_STATE_LEN];
    msg_stepper_state_t m = {axis, stepper_position(axis), stepper_flags(axis)};
    msg_stepper_state_pack(p, &m);
    frame_send(MSG_STEPPER_STATE_ID, p, sizeof p);
}

static void handle_identify_req(const frame_t *f)
{
    (void)f;
    uint8_t p[MSG_IDENTIFY_LEN];
    msg_identify_t m = {PROTOCOL_VERSION, BOARD_CLOCK_HZ, PROTOCOL_TABLE_HASH, BOARD_ID};
    msg_identify_pack(p, &m);
    frame_send(MSG_IDENTIFY_ID, p, sizeof p);
}

static void handle_heartbeat(const frame_t *f)
{
    msg_heartbeat_t in;
    msg_heartbeat_unpack(f->payload, &in);
    uint32_t now = board_ticks();
    outputs_heartbeat(now);
    uint8_t p[MSG_HEARTBEAT_ACK_LEN];
    msg_heartbeat_ack_t m = {in.host_us, now};
    msg_heartbeat_ack_pack(p, &m);
    frame_send(MSG_HEARTBEAT_ACK_ID, p, sizeof p);
}

/* pwm_set comes every control tick: it is acked only when refused, to keep the MCU->host
 * line for state frames (see PROTOCOL.md, budget). */
static void handle_pwm_set(const frame_t *f)
{
    msg_pwm_set_t m;
    msg_pwm_set_unpack(f->payload, &m);
    if (!outputs_armed())
        send_ack(f, ACK_NO_HEARTBEAT);
    else if (m.duty == INT16_MIN)
        send_ack(f, ACK_BAD_ARG);
    else
        outputs_set_pwm(m.duty, board_ticks());
}

static void handle_stepper_move(const frame_t *f)
{
    msg_stepper_move_t m;
    msg_stepper_move_unpack(f->payload, &m);
    uint8_t status = outputs_armed()
                         ? stepper_move(m.axis, m.steps, m.rate_sps, m.accel_sps2, board_ticks())
                         : ACK_NO_HEARTBEAT;
    send_ack(f, status);
}

static void handle_stepper_home(const frame_t *f)
{
    msg_stepper_home_t m;
    msg_stepper_home_unpack(f->payload, &m);
    send_ack(f, outputs_armed() ? stepper_home(m.axis, board_ticks()) : ACK_NO_HEARTBEAT);
}

static void handle_laser_set(const frame_t *f)
{
    msg_laser_set_t m;
    msg_laser_set_unpack(f->payload, &m);
    uint8_t status = ACK_OK;
    if (m.on > 1)
        status = ACK_BAD_ARG;
    else if (m.on && !outputs_armed())
        status = ACK_NO_HEARTBEAT; /* switching off is always allowed */
    else
        outputs_set_laser(m.on != 0, board_ticks());
    send_ack(f, status);
}

static void handle_config_set(const frame_t *f)
{
    msg_config_set_t m;
    msg_config_set_unpack(f->payload, &m);
    /* The watchdog cannot be disabled; state_div is capped (core_config.h). */
    if (m.watchdog_ms == 0 || m.state_div > CORE_MAX_STATE_DIV) {
        send_ack(f, ACK_BAD_ARG);
        return;
    }
    core_cfg.watchdog_ms = m.watchdog_ms;
    core_cfg.state_div = m.state_div;
    core_cfg.max_on_ms = m.max_on_ms;
    send_ack(f, ACK_OK);
}

static void handle_stats_req(const frame_t *f)
{
    (void)f;
    core_stats_t s;
    core_stats(&s);
    uint8_t p[MSG_STATS_LEN];
    msg_stats_t m = {s.rx_frames,  s.crc_errors,   s.resyncs,       s.tx_dropped,
                     s.duplicates, s.rx_overflows, s.ticks_dropped, s.watchdog_expiries};
    msg_stats_pack(p, &m);
    frame_send(MSG_STATS_ID, p, sizeof p);
}
