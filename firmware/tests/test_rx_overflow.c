/* A host burst past the board's RX ring and a main loop held up past its tick queue: what the
 * boards' ISRs count (core_rx_overflows, core_ticks_dropped) reaches the host in stats, and
 * after the bytes a full ring throws away the parser resynchronises and delivers every frame
 * that arrived whole, never a torn one. */
#include <string.h>

#include "check.h"
#include "core.h"
#include "fake_board.h"
#include "protocol_gen.h"

static msg_stats_t stats(void)
{
    fake_send(MSG_STATS_REQ_ID, NULL, 0);
    fake_frame_t f;
    msg_stats_t m;
    memset(&m, 0, sizeof m);
    CHECK(fake_recv_id(MSG_STATS_ID, &f), "a stats reply");
    CHECK_EQ(f.len, MSG_STATS_LEN);
    msg_stats_unpack(f.payload, &m);
    return m;
}

void test_stats_carry_the_boards_overflow_counts(void)
{
    fake_reset();
    msg_stats_t m = stats();
    CHECK_EQ(m.rx_overflows, 0);
    CHECK_EQ(m.ticks_dropped, 0);
    core_rx_overflows = 700; /* as the boards' RX and tick ISRs count them */
    core_ticks_dropped = 45;
    m = stats();
    CHECK_EQ(m.rx_overflows, 700);
    CHECK_EQ(m.ticks_dropped, 45);
    core_init(); /* a boot starts them over */
    m = stats();
    CHECK_EQ(m.rx_overflows, 0);
    CHECK_EQ(m.ticks_dropped, 0);
}

/* The ATmega's receive path: a 64-byte ring filled by the RX ISR (a byte without room is
 * counted and lost), emptied 16 bytes a main-loop pass. */
#define RING 64u
static uint8_t ring[RING];
static uint8_t head, tail;

static void rx_isr(uint8_t b)
{
    if ((uint8_t)(head - tail) < RING) {
        ring[head & (RING - 1u)] = b;
        head = (uint8_t)(head + 1u);
    } else {
        core_rx_overflows++;
    }
}

static void main_pass(void)
{
    for (uint8_t i = 0; i < 16u && tail != head; i++, tail = (uint8_t)(tail + 1u))
        core_rx_byte(ring[tail & (RING - 1u)]);
}

void test_a_burst_past_the_rx_ring_is_counted_and_the_parser_resyncs(void)
{
    fake_reset();
    fake_heartbeat(1); /* armed: pwm_set runs (and is not acked) */
    fake_frame_t f;
    while (fake_recv(&f) >= 0) {
    }
    head = tail = 0;
    uint32_t rx0 = core_parser.rx_frames;
    /* 300 pwm_set frames, 11 bytes each, arriving 4 bytes for each 1 the loop takes (the
     * ATmega parses a pwm_set in ~2200 cycles, the line brings one in 880): the ring fills and
     * runs over again and again. Whether each frame arrived whole is recorded as it goes. */
    enum { N = 300 };
    static bool whole[N];
    uint8_t buf[PROTO_MAX_FRAME], pl[MSG_PWM_SET_LEN];
    unsigned lost_bytes = 0, arrived = 0;
    int16_t last_whole_duty = 0;
    for (int k = 0; k < N; k++) {
        msg_pwm_set_t m = {(int16_t)(100 + k)};
        msg_pwm_set_pack(pl, &m);
        uint8_t n = fake_encode(buf, (uint16_t)(1000 + k), MSG_PWM_SET_ID, pl, sizeof pl);
        uint16_t before = core_rx_overflows;
        for (uint8_t i = 0; i < n; i++) {
            rx_isr(buf[i]);
            if (++arrived % 64u == 0) /* 4 bytes in for each 1 the loop takes */
                main_pass();
        }
        whole[k] = core_rx_overflows == before;
        lost_bytes += (uint16_t)(core_rx_overflows - before);
    }
    for (int pass = 0; pass < 64; pass++) /* the line goes quiet: the loop catches up */
        main_pass();
    int n_whole = 0;
    for (int k = 0; k < N; k++)
        if (whole[k]) {
            n_whole++;
            last_whole_duty = (int16_t)(100 + k);
        }
    CHECK_EQ(core_rx_overflows, lost_bytes);
    CHECK(lost_bytes > 1000, "the burst overflowed the ring (%u bytes lost)", lost_bytes);
    CHECK(n_whole > 0 && n_whole < N, "%d of %d frames arrived whole", n_whole, N);
    /* Every whole frame delivered, no torn one (its CRC fails), and the parser says it resynced. */
    CHECK_EQ(core_parser.rx_frames - rx0, (uint32_t)n_whole);
    CHECK(core_parser.resyncs > 0, "resyncs %u", core_parser.resyncs);
    CHECK_EQ(core_parser.duplicates, 0);
    CHECK_EQ(fb.pwm, last_whole_duty);
    /* and the next frame after the burst is taken at once, as if nothing had happened */
    msg_pwm_set_t m = {-123};
    msg_pwm_set_pack(pl, &m);
    uint8_t n = fake_encode(buf, 5000, MSG_PWM_SET_ID, pl, sizeof pl);
    for (uint8_t i = 0; i < n; i++)
        core_rx_byte(buf[i]);
    CHECK_EQ(fb.pwm, -123);
    CHECK_EQ(core_parser.rx_frames - rx0, (uint32_t)n_whole + 1u);
}

/* Each heartbeat watchdog expiry is counted once (not once per tick while it stays expired), the
 * count reaches the host in stats even when the fault frame itself was lost, and a boot clears
 * it. */
void test_stats_count_watchdog_expiries(void)
{
    fake_reset();
    CHECK_EQ(stats().watchdog_expiries, 0);
    fake_config(20, 0, 0);
    for (int k = 1; k <= 3; k++) {
        fake_heartbeat(1);
        fake_advance(100 * CORE_TICKS_PER_MS); /* 100 ms: 5 x the watchdog, one expiry */
        fake_frame_t f;
        while (fake_recv(&f) >= 0) { /* the fault frames: drained, as if lost on the line */
        }
        CHECK_EQ(stats().watchdog_expiries, k);
    }
    core_init(); /* a boot starts it over */
    CHECK_EQ(stats().watchdog_expiries, 0);
}
