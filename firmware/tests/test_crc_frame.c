/* CRC vectors and the receive parser: good frames, resync under corruption, bad LEN. */
#include <stdint.h>
#include <string.h>

#include "check.h"
#include "crc16.h"
#include "fake_board.h"
#include "frame.h"

/* Bit-by-bit CRC-16/CCITT-FALSE straight from the definition, to check the fast form. */
static uint16_t crc_ref(const uint8_t *p, int n)
{
    uint16_t crc = 0xFFFF;
    for (int i = 0; i < n; i++) {
        crc ^= (uint16_t)(p[i] << 8);
        for (int b = 0; b < 8; b++)
            crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

void test_crc_vectors(void)
{
    const uint8_t check[] = "123456789";
    CHECK_EQ(crc16(check, 9, CRC16_INIT), 0x29B1);   /* the catalogued check value */
    CHECK_EQ(crc16(check, 0, CRC16_INIT), 0xFFFF);
    uint8_t buf[256];
    for (int i = 0; i < 256; i++)
        buf[i] = (uint8_t)(i * 37 + 11);
    for (int n = 1; n < 256; n += 17)
        CHECK_EQ(crc16(buf, (uint8_t)n, CRC16_INIT), crc_ref(buf, n));
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
    uint8_t n = fake_encode(buf, 7, 0x03, pl, 2);
    for (uint8_t i = 0; i < n; i++)
        frame_parser_feed(&p, buf[i]);
    CHECK_EQ(n_got, 1);
    CHECK_EQ(got[0].seq, 7);
    CHECK_EQ(got[0].id, 0x03);
    CHECK_EQ(proto_get_u16(got[0].payload), 0x1234);
    CHECK_EQ(p.rx_frames, 1);
    CHECK_EQ(p.crc_errors + p.resyncs, 0);
}

/* 300 frames with varied lengths; every 7th has one payload bit flipped, every 11th is
 * preceded by junk that holds a false SYNC with LEN 32. Every intact frame must come out,
 * in order, and no damaged one. */
void test_frame_resync(void)
{
    frame_parser_t p;
    frame_parser_init(&p, collect);
    n_got = 0;
    int expect_seq[300], n_expect = 0, n_flipped = 0;
    uint32_t lcg = 12345;
    for (int k = 0; k < 300; k++) {
        uint8_t pl[PROTO_MAX_PAYLOAD], buf[64];
        uint8_t len = (uint8_t)(1 + k % PROTO_MAX_PAYLOAD);
        for (uint8_t i = 0; i < len; i++) {
            lcg = lcg * 1103515245u + 12345u;
            pl[i] = (uint8_t)(lcg >> 16);
        }
        uint8_t n = fake_encode(buf, (uint8_t)k, 0x10, pl, len);
        if (k % 11 == 5 && k < 290) {
            const uint8_t junk[] = {0x00, 0xFF, PROTO_SYNC, 0x20, 0x5A};
            for (unsigned i = 0; i < sizeof junk; i++)
                frame_parser_feed(&p, junk[i]);
        }
        if (k % 7 == 3) {
            buf[4 + k % len] ^= (uint8_t)(1u << (k % 8));
            n_flipped++;
        } else {
            expect_seq[n_expect++] = k & 0xFF;
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
    /* At least one CRC error per flipped frame and per false SYNC (more if a payload byte of a
     * dropped frame happens to look like a SYNC). */
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
    uint8_t n = fake_encode(buf, 1, 0x01, NULL, 0);
    for (uint8_t i = 0; i < n; i++)
        frame_parser_feed(&p, buf[i]);
    CHECK_EQ(n_got, 1);
    CHECK_EQ(p.crc_errors, 0);
    CHECK_EQ(p.resyncs, 1); /* the junk run after the bad LEN is the same event */
}
