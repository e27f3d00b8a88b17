/* Command table, replies, state frames, TX overflow accounting and pulse event sequence. */
#include "check.h"
#include "core.h"
#include "dispatch.h"
#include "fake_board.h"
#include "outputs.h"
#include "protocol_gen.h"

static void drain(void)
{
    fake_frame_t f;
    while (fake_recv(&f) >= 0) {
    }
}

void test_dispatch_identify(void)
{
    fake_reset();
    fake_send(MSG_IDENTIFY_REQ_ID, NULL, 0);
    fake_frame_t f;
    CHECK_EQ(fake_recv(&f), MSG_IDENTIFY_ID);
    msg_identify_t m;
    msg_identify_unpack(f.payload, &m);
    CHECK_EQ(f.len, MSG_IDENTIFY_LEN);
    CHECK_EQ(m.proto_version, PROTOCOL_VERSION);
    CHECK_EQ(m.clock_hz, 16000000);
    CHECK_EQ(m.table_hash, PROTOCOL_TABLE_HASH);
    CHECK_EQ(m.board, BOARD_ID);
    CHECK_EQ(f.seq, 0);
}

void test_dispatch_bad_frame(void)
{
    fake_reset();
    uint8_t p[3] = {1, 2, 3};
    /* The parser's length check refuses both before the CRC: nothing runs, no reply. */
    fake_send(0x7E, p, 1);           /* unknown id */
    fake_send(MSG_PWM_SET_ID, p, 3); /* known id, wrong length */
    fake_frame_t f;
    CHECK_EQ(fake_recv(&f), -1);
    CHECK_EQ(core_parser.rx_frames, 0);
    CHECK(core_parser.resyncs >= 2, "resyncs %u", core_parser.resyncs);
    /* A frame that reaches the command table some other way is still refused with a fault. */
    frame_t bad = {9, 0x7E, 1, p};
    dispatch_frame(&bad);
    CHECK_EQ(fake_recv(&f), MSG_FAULT_ID);
    CHECK_EQ(f.payload[0], FAULT_BAD_FRAME);
    CHECK_EQ(proto_get_u16(f.payload + 1), 0x7E01);
    CHECK_EQ(fb.pwm, 0);
}

/* The same SEQ twice in a row (a repeated frame on the line) runs once; identify_req is exempt. */
void test_dispatch_duplicates(void)
{
    fake_reset();
    fake_heartbeat(1);
    drain();
    uint8_t buf[PROTO_MAX_FRAME], pl[MSG_STEPPER_MOVE_LEN];
    msg_stepper_move_t mv = {0, 100, 1000, 1000};
    msg_stepper_move_pack(pl, &mv);
    uint8_t n = fake_encode(buf, 500, MSG_STEPPER_MOVE_ID, pl, sizeof pl);
    for (int rep = 0; rep < 2; rep++)
        for (uint8_t i = 0; i < n; i++)
            core_rx_byte(buf[i]);
    fake_frame_t f;
    int acks = 0;
    while (fake_recv_id(MSG_ACK_ID, &f))
        acks++;
    CHECK_EQ(acks, 1);
    CHECK_EQ(core_parser.duplicates, 1);
    n = fake_encode(buf, 501, MSG_IDENTIFY_REQ_ID, NULL, 0);
    for (int rep = 0; rep < 2; rep++)
        for (uint8_t i = 0; i < n; i++)
            core_rx_byte(buf[i]);
    int ids = 0;
    while (fake_recv_id(MSG_IDENTIFY_ID, &f))
        ids++;
    CHECK_EQ(ids, 2);
    CHECK_EQ(core_parser.duplicates, 1);
}

void test_dispatch_heartbeat_pwm(void)
{
    fake_reset();
    uint8_t p[2];
    proto_put_u16(p, 1000);
    fake_send(MSG_PWM_SET_ID, p, 2);
    CHECK_EQ(fake_ack_status(), ACK_NO_HEARTBEAT); /* outputs refused before the first heartbeat */
    CHECK_EQ(fb.pwm, 0);

    fake_advance(12345);
    fake_heartbeat(0xDEADBEEF);
    fake_frame_t f;
    CHECK_EQ(fake_recv(&f), MSG_HEARTBEAT_ACK_ID);
    CHECK_EQ(proto_get_u32(f.payload), 0xDEADBEEF);
    CHECK_EQ(proto_get_u32(f.payload + 4), fb.now);

    proto_put_u16(p, (uint16_t)-20000);
    fake_send(MSG_PWM_SET_ID, p, 2);
    CHECK_EQ(fb.pwm, -20000);
    CHECK_EQ(fake_recv(&f), -1); /* accepted pwm_set is not acked */
    proto_put_u16(p, 0x8000);
    fake_send(MSG_PWM_SET_ID, p, 2);
    CHECK_EQ(fake_ack_status(), ACK_BAD_ARG);
    CHECK_EQ(fb.pwm, -20000);

    uint8_t on = 1;
    fake_send(MSG_LASER_SET_ID, &on, 1);
    CHECK_EQ(fake_ack_status(), ACK_OK);
    CHECK(fb.laser, "laser should be on");
}

void test_dispatch_config(void)
{
    fake_reset();
    fake_config(100, CORE_MAX_STATE_DIV + 1, 0);
    CHECK_EQ(fake_ack_status(), ACK_BAD_ARG);
    fake_config(0, 1, 0);
    CHECK_EQ(fake_ack_status(), ACK_BAD_ARG);
    fake_config(150, 4, 300);
    CHECK_EQ(fake_ack_status(), ACK_OK);
    CHECK_EQ(core_cfg.watchdog_ms, 150);
    CHECK_EQ(core_cfg.state_div, 4);
    CHECK_EQ(core_cfg.max_on_ms, 300);

    fake_send(MSG_STATS_REQ_ID, NULL, 0);
    fake_frame_t f;
    CHECK_EQ(fake_recv_id(MSG_STATS_ID, &f), 1);
    msg_stats_t s;
    msg_stats_unpack(f.payload, &s);
    CHECK_EQ(s.rx_frames, 4); /* three config_set + this stats_req */
    CHECK_EQ(s.crc_errors, 0);
}

void test_state_frames(void)
{
    fake_reset();
    fake_config(100, 2, 0);
    drain();
    fb.encoder = -5;
    fake_advance(10 * CORE_TICKS_PER_TICK);
    fake_frame_t f;
    int n = 0;
    uint32_t last = 0;
    while (fake_recv_id(MSG_STATE_ID, &f)) {
        msg_state_t m;
        msg_state_unpack(f.payload, &m);
        CHECK_EQ(m.encoder16, -5);
        if (n)
            CHECK_EQ(m.ticks - last, 2 * CORE_TICKS_PER_TICK);
        last = m.ticks;
        n++;
    }
    CHECK_EQ(n, 5); /* 10 ticks / state_div 2 */
}

void test_tx_overflow(void)
{
    fake_reset();
    int sent = 0;
    for (int i = 0; i < 40; i++, sent++)
        fake_send(MSG_STATS_REQ_ID, NULL, 0); /* MSG_STATS_LEN + 9 B each, ring of CORE_TX_RING */
    int expect_kept = CORE_TX_RING / (MSG_STATS_LEN + PROTO_OVERHEAD);
    fake_frame_t f;
    int kept = 0, last_seq = -1;
    while (fake_recv(&f) == MSG_STATS_ID) {
        last_seq = f.seq;
        kept++;
    }
    CHECK_EQ(kept, expect_kept);
    CHECK_EQ(last_seq, expect_kept - 1);
    CHECK_EQ(frame_tx_dropped(), sent - expect_kept);
    fake_advance(CORE_TICKS_PER_TICK); /* room again: the drop is reported */
    CHECK_EQ(fake_recv_id(MSG_FAULT_ID, &f), 1);
    CHECK_EQ(f.payload[0], FAULT_TX_OVERFLOW);
    CHECK_EQ(proto_get_u16(f.payload + 1), sent - expect_kept);
    CHECK_EQ(f.seq, sent); /* dropped frames used up their SEQ numbers: the gap is visible */
}

void test_pulse_seq(void)
{
    fake_reset();
    for (uint32_t i = 0; i < 3; i++)
        core_pulse_isr((uint8_t)(i & 1), 5000 + i);
    core_poll();
    fake_frame_t f;
    for (uint32_t i = 0; i < 3; i++) {
        CHECK_EQ(fake_recv(&f), MSG_PULSE_ID);
        msg_pulse_t m;
        msg_pulse_unpack(f.payload, &m);
        CHECK_EQ(m.channel, i & 1);
        CHECK_EQ(m.event_seq, i);
        CHECK_EQ(m.mcu_ticks, 5000 + i);
    }
    /* A burst larger than the queue: the overflow shows as an event_seq gap. */
    for (uint32_t i = 0; i < CORE_PULSE_QUEUE + 3; i++)
        core_pulse_isr(1, 9000 + i);
    core_poll();
    int n = 0, last = 2;
    while (fake_recv_id(MSG_PULSE_ID, &f)) {
        msg_pulse_t m;
        msg_pulse_unpack(f.payload, &m);
        CHECK(m.event_seq == last + 1, "event_seq %u after %d", m.event_seq, last);
        last = m.event_seq;
        n++;
    }
    CHECK_EQ(n, CORE_PULSE_QUEUE);
    core_pulse_isr(0, 12000);
    core_poll();
    CHECK_EQ(fake_recv_id(MSG_PULSE_ID, &f), 1);
    CHECK_EQ(proto_get_u16(f.payload + 1), 3 + CORE_PULSE_QUEUE + 3); /* 3 lost: a gap of 3 */
}
