/* CRC vectors and the receive parser: good frames, resync under corruption, bad LEN,
 * and a seeded fuzz of corrupted frames (the long run is `make fuzz`). */
#include <stdint.h>
#include <string.h>

#include "check.h"
#include "crc32.h"
#include "fake_board.h"
#include "frame.h"
#include "fuzz.h"

/* Bit-by-bit CRC-32 straight from the definition, to check the table. */
static uint32_t crc_ref(const uint8_t *p, int n)
{
    uint32_t crc = 0xFFFFFFFFu;
    for (int i = 0; i < n; i++) {
        crc ^= p[i];
        for (int b = 0; b < 8; b++)
            crc = (crc & 1u) ? (crc >> 1) ^ 0xEDB88320u : crc >> 1;
    }
    return ~crc;
}

void test_crc_vectors(void)
{
    const uint8_t check[] = "123456789";
    CHECK_EQ(crc32(check, 9), 0xCBF43926u); /* the catalogued check value (= zlib.crc32) */
    CHECK_EQ(crc32(check, 0), 0u);
    uint8_t buf[256];
    for (int i = 0; i < 256; i++)
        buf[i] = (uint8_t)i; /* every table entry is used */
    CHECK_EQ(crc32(buf, 255), crc_ref(buf, 255));
    for (int i = 0; i < 256; i++)
        buf[i] = (uint8_t)(i * 37 + 11);
    for (int n = 1; n < 256; n += 17)
        CHECK_EQ(crc32(buf, (uint8_t)n), crc_ref(buf, n));
}

#define MAX_GOT 512
static frame_t got[MAX_GOT];
static uint8_t got_payload[MAX_GOT][PROTO_MAX_PAYLOAD];
static int n_got;

static void collect(const frame_t *f)
{
    if (n_got < MAX_GOT) {
        got[n_got] = *f;
        memcpy(got_payload[n_got], f->payload, f->len);
        got[n_got].payload = got_payload[n_got];
    }
    n_got++;
}

void test_frame_good(void)
{
    frame_parser_t p;
    frame_parser_init(&p, collect);
    n_got = 0;
    uint8_t buf[64], pl[2] = {0x34, 0x12};
    uint8_t n = fake_encode(buf, 0x1234, MSG_PWM_SET_ID, pl, 2);
    CHECK_EQ(n, 2 + PROTO_OVERHEAD);
    for (uint8_t i = 0; i < n; i++)
        frame_parser_feed(&p, buf[i]);
    CHECK_EQ(n_got, 1);
    CHECK_EQ(got[0].seq, 0x1234);
    CHECK_EQ(got[0].id, MSG_PWM_SET_ID);
    CHECK_EQ(proto_get_u16(got[0].payload), 0x1234);
    CHECK_EQ(p.rx_frames, 1);
    CHECK_EQ(p.crc_errors + p.resyncs, 0);
    /* SYNC is under the CRC: the same bytes behind another SYNC value are refused. */
    CHECK(crc32(buf, 7) != crc32(buf + 1, 6), "crc covers SYNC");
}

/* The h2m messages with a payload, to build valid frames of varied length. */
static const uint8_t ids[] = {MSG_HEARTBEAT_ID, MSG_PWM_SET_ID, MSG_STEPPER_MOVE_ID,
                              MSG_STEPPER_HOME_ID, MSG_LASER_SET_ID, MSG_CONFIG_SET_ID};

/* 300 frames of every h2m size; every 7th has one payload bit flipped, every 11th is preceded
 * by junk that holds a false SYNC with a plausible LEN. Every intact frame must come out, in
 * order, and no damaged one. */
void test_frame_resync(void)
{
    frame_parser_t p;
    frame_parser_init(&p, collect);
    n_got = 0;
    int expect_seq[300], n_expect = 0, n_flipped = 0;
    uint32_t lcg = 12345;
    for (int k = 0; k < 300; k++) {
        uint8_t pl[PROTO_MAX_PAYLOAD], buf[64];
        uint8_t id = ids[k % sizeof ids], len = proto_h2m_len(id);
        for (uint8_t i = 0; i < len; i++) {
            lcg = lcg * 1103515245u + 12345u;
            pl[i] = (uint8_t)(lcg >> 16);
        }
        uint8_t n = fake_encode(buf, (uint16_t)(k * 300), id, pl, len);
        if (k % 11 == 5 && k < 290) {
            const uint8_t junk[] = {0x00, 0xFF, PROTO_SYNC, 0x04, 0x5A, 0x00, MSG_HEARTBEAT_ID, 0x11};
            for (unsigned i = 0; i < sizeof junk; i++)
                frame_parser_feed(&p, junk[i]);
        }
        if (k % 7 == 3) {
            buf[PROTO_HEADER + k % len] ^= (uint8_t)(1u << (k % 8));
            n_flipped++;
        } else {
            expect_seq[n_expect++] = (uint16_t)(k * 300);
        }
        for (uint8_t i = 0; i < n; i++)
            frame_parser_feed(&p, buf[i]);
    }
    CHECK_EQ(n_got, n_expect);
    int mismatches = 0;
    for (int i = 0; i < n_expect && i < n_got; i++)
        mismatches += got[i].seq != expect_seq[i];
    CHECK_EQ(mismatches, 0);
    CHECK_EQ(p.rx_frames, (uint32_t)n_expect);
    /* At least one CRC error per flipped frame and per false SYNC whose header passes. */
    CHECK(p.crc_errors >= n_flipped + 26, "crc_errors %u < %d", p.crc_errors, n_flipped + 26);
    CHECK(p.resyncs >= p.crc_errors, "resyncs %u < crc_errors %u", p.resyncs, p.crc_errors);
}

void test_frame_bad_len(void)
{
    frame_parser_t p;
    frame_parser_init(&p, collect);
    n_got = 0;
    uint8_t buf[64];
    frame_parser_feed(&p, PROTO_SYNC);
    frame_parser_feed(&p, PROTO_MAX_PAYLOAD + 1); /* impossible LEN: resync at once */
    CHECK_EQ(p.resyncs, 1);
    uint8_t n = fake_encode(buf, 1, MSG_IDENTIFY_REQ_ID, NULL, 0);
    for (uint8_t i = 0; i < n; i++)
        frame_parser_feed(&p, buf[i]);
    CHECK_EQ(n_got, 1);
    CHECK_EQ(p.crc_errors, 0);
    CHECK_EQ(p.resyncs, 1); /* the junk run after the bad LEN is the same event */
    /* LEN that is not the size of the id: refused after the header, before any CRC. */
    uint8_t pl[4] = {0};
    n = fake_encode(buf, 2, MSG_HEARTBEAT_ID, pl, 2);
    for (uint8_t i = 0; i < n; i++)
        frame_parser_feed(&p, buf[i]);
    CHECK_EQ(n_got, 1);
    CHECK_EQ(p.crc_errors, 0);
}

/* The seeded fuzz, 20 000 corrupted frames: no false accept, no duplicate executed. */
void test_frame_fuzz(void)
{
    fuzz_result_t r = fuzz_frames(1, 20000);
    CHECK(r.corrupted >= 20000, "corrupted %lu", (unsigned long)r.corrupted);
    CHECK_EQ(r.false_accepts, 0);
    CHECK_EQ(r.duplicates_run, 0);
    /* most intact frames survive their corrupted neighbours (a frame after a truncated one
     * can be lost with it: the length check waits for bytes that belong to the next) */
    CHECK(r.delivered * 10 >= r.intact * 9, "delivered %lu of %lu intact",
          (unsigned long)r.delivered, (unsigned long)r.intact);
}
