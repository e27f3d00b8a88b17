/* The corruption model (the same as tvsd/hw/mcu/fuzz.py's, for the host's decoder): random
 * valid h2m frames with SEQ counting up; every other frame on average is damaged by one of
 *   flip      1..3 random bits anywhere in the frame
 *   drop      one byte removed
 *   insert    one byte inserted (a SYNC half of the time: false frame starts)
 *   duplicate the whole frame sent twice (half the time) or one byte repeated
 *   truncate  the frame cut short at a random point (the next frame follows at once)
 *   burst     a run of 2..8 bytes overwritten with random ones
 * and the stream goes to the parser. A frame handed over is a false accept unless it is
 * byte-identical to the frame sent under that SEQ. */
#include "fuzz.h"

#include <string.h>

#include "crc32.h"
#include "frame.h"

const char *const fuzz_op_names[6] = {"flip", "drop", "insert", "duplicate", "truncate", "burst"};

static uint64_t rng_state;
static uint32_t rnd(void) /* splitmix64, upper half */
{
    uint64_t z = (rng_state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return (uint32_t)((z ^ (z >> 31)) >> 32);
}
static uint32_t below(uint32_t n) { return rnd() % n; }

typedef struct {
    uint8_t id, len, payload[PROTO_MAX_PAYLOAD];
    uint8_t delivered;
} sent_t;
static sent_t sent[65536]; /* by SEQ: the last frame sent under it */
static fuzz_result_t res;
static int have_last;
static uint16_t last_seq;
static uint8_t last_bytes[PROTO_MAX_FRAME];
static uint8_t last_len;

static void on_frame(const frame_t *f)
{
    const sent_t *s = &sent[f->seq];
    if (s->id != f->id || s->len != f->len || memcmp(s->payload, f->payload, f->len) != 0) {
        res.false_accepts++;
        return;
    }
    if (have_last && f->seq == last_seq && f->len == last_len &&
        memcmp(last_bytes, f->payload, f->len) == 0 && f->id != MSG_IDENTIFY_REQ_ID) {
        res.duplicates_run++;
        return;
    }
    have_last = 1;
    last_seq = f->seq;
    last_len = f->len;
    memcpy(last_bytes, f->payload, f->len);
    res.delivered++;
}

static const uint8_t h2m_ids[] = {
#define X(id, name, len) id,
    PROTO_H2M_LIST(X)
#undef X
};

fuzz_result_t fuzz_frames(uint32_t seed, uint64_t corrupted)
{
    static frame_parser_t p;
    memset(&res, 0, sizeof res);
    memset(sent, 0, sizeof sent);
    have_last = 0;
    rng_state = seed;
    frame_parser_init(&p, on_frame);
    uint16_t seq = 0;
    uint8_t out[2 * (PROTO_MAX_FRAME + 8)];
    while (res.corrupted < corrupted) {
        uint8_t id = h2m_ids[below(sizeof h2m_ids)];
        uint8_t len = proto_h2m_len(id);
        sent_t *s = &sent[seq];
        s->id = id;
        s->len = len;
        for (uint8_t i = 0; i < len; i++)
            s->payload[i] = (uint8_t)rnd();
        uint8_t f[PROTO_MAX_FRAME];
        f[0] = PROTO_SYNC;
        f[PROTO_OFF_LEN] = len;
        proto_put_u16(f + PROTO_OFF_SEQ, seq);
        f[PROTO_OFF_ID] = id;
        memcpy(f + PROTO_HEADER, s->payload, len);
        uint8_t body = (uint8_t)(PROTO_HEADER + len);
        proto_put_u32(f + body, crc32(f, body));
        unsigned n = body + PROTO_CRC_BYTES, m = 0;
        seq++;
        res.frames++;
        if (below(2)) {
            memcpy(out, f, n);
            m = n;
            res.intact++;
        } else {
            unsigned op = below(6), at = below(n);
            res.corrupted++;
            res.by_op[op]++;
            memcpy(out, f, n);
            m = n;
            switch (op) {
            case 0:
                for (unsigned k = 1 + below(3); k; k--)
                    out[below(n)] ^= (uint8_t)(1u << below(8));
                break;
            case 1:
                memmove(out + at, out + at + 1, n - at - 1);
                m = n - 1;
                break;
            case 2:
                memmove(out + at + 1, out + at, n - at);
                out[at] = below(2) ? PROTO_SYNC : (uint8_t)rnd();
                m = n + 1;
                break;
            case 3:
                if (below(2)) {
                    memcpy(out + n, f, n);
                    m = 2 * n;
                } else {
                    memmove(out + at + 1, out + at, n - at);
                    m = n + 1;
                }
                break;
            case 4:
                m = at; /* 0..n-1 bytes of it */
                break;
            default: {
                unsigned k = 2 + below(7);
                for (unsigned i = at; i < at + k && i < n; i++)
                    out[i] = (uint8_t)rnd();
            }
            }
        }
        uint16_t c0 = p.crc_errors, r0 = p.resyncs, d0 = p.duplicates;
        for (unsigned i = 0; i < m; i++)
            frame_parser_feed(&p, out[i]);
        /* the parser's counters are 16-bit (as in the stats frame): sum their steps */
        res.crc_errors += (uint16_t)(p.crc_errors - c0);
        res.resyncs += (uint16_t)(p.resyncs - r0);
        res.dup_dropped += (uint16_t)(p.duplicates - d0);
    }
    return res;
}
