#include "frame.h"

#include <string.h>

#include "board.h"
#include "crc32.h"

void frame_parser_init(frame_parser_t *p, frame_handler_t on_frame)
{
    memset(p, 0, sizeof *p);
    p->on_frame = on_frame;
}

static void drop(frame_parser_t *p, uint8_t k)
{
    p->n = (uint8_t)(p->n - k);
    if (p->n)
        memmove(p->buf, p->buf + k, p->n);
}

static void lose_sync(frame_parser_t *p)
{
    p->resyncs++;
    p->hunting = true;
}

void frame_parser_scan(frame_parser_t *p)
{
    /* Rescan the buffer: after a bad frame, the bytes already received may hold the next one. */
    while (p->n) {
        if (p->buf[0] != PROTO_SYNC) {
            uint8_t i = 1;
            while (i < p->n && p->buf[i] != PROTO_SYNC)
                i++;
            if (!p->hunting)
                lose_sync(p);
            drop(p, i);
            continue;
        }
        if (p->n < 2)
            return;
        uint8_t len = p->buf[PROTO_OFF_LEN];
        /* The length check: LEN must fit, and once the ID is in, be the size of that id. A
         * false SYNC is thrown out here, after 5 bytes, most of the time. */
        if (len > PROTO_MAX_PAYLOAD ||
            (p->n >= PROTO_HEADER && proto_h2m_len(p->buf[PROTO_OFF_ID]) != len)) {
            lose_sync(p);
            drop(p, 1);
            continue;
        }
        uint8_t total = (uint8_t)(len + PROTO_OVERHEAD);
        if (p->n < total)
            return;
        uint8_t body = (uint8_t)(len + PROTO_HEADER);
        if (crc32(p->buf, body) != proto_get_u32(p->buf + body)) {
            p->crc_errors++;
            lose_sync(p);
            drop(p, 1);
            continue;
        }
        p->hunting = false;
        p->rx_frames++;
        uint16_t seq = proto_get_u16(p->buf + PROTO_OFF_SEQ);
        uint8_t id = p->buf[PROTO_OFF_ID];
        /* The host numbers every frame: the same SEQ twice in a row is the line repeating a
         * frame, and a stepper_move must not run twice. identify_req is exempt: a host that
         * reconnects starts its SEQ over with it, and it changes nothing. */
        if (p->have_seq && seq == p->last_seq && id != MSG_IDENTIFY_REQ_ID) {
            p->duplicates++;
        } else {
            p->have_seq = true;
            p->last_seq = seq;
            frame_t f = {seq, id, len, p->buf + PROTO_HEADER};
            p->on_frame(&f);
        }
        drop(p, total);
    }
}

/* ---- transmit ring: single producer (main), single consumer (UART ISR) ---- */
uint8_t frame_tx_buf[CORE_TX_RING];
volatile tx_index_t frame_tx_head, frame_tx_tail;
static uint16_t tx_seq;
static uint16_t tx_dropped;

uint16_t frame_tx_free(void)
{
    return (uint16_t)(CORE_TX_RING - (tx_index_t)(frame_tx_head - frame_tx_tail));
}

uint16_t frame_tx_dropped(void) { return tx_dropped; }

void frame_tx_reset(void)
{
    frame_tx_head = frame_tx_tail = 0;
    tx_seq = 0;
    tx_dropped = 0;
}

bool frame_send(uint8_t id, const uint8_t *payload, uint8_t len)
{
    if (frame_tx_free() < (uint16_t)(len + PROTO_OVERHEAD)) {
        tx_dropped++;
        tx_seq++; /* the lost frame keeps its SEQ: the host counts the gap */
        return false;
    }
    /* One pass: copy into the ring and CRC on the way (this runs for every state frame). */
    tx_index_t h = frame_tx_head;
    uint16_t seq = tx_seq++;
    uint32_t crc = CRC32_INIT;
    /* A macro, not a function: -Os would not inline one, and the CRC register would go
     * through memory for every byte (~50 cycles a byte on the AVR). */
#define PUT(byte)                                 \
    do {                                          \
        uint8_t b_ = (byte);                      \
        frame_tx_buf[h++ & FRAME_TX_MASK] = b_;   \
        crc = crc32_update(crc, b_);              \
    } while (0)
    PUT(PROTO_SYNC);
    PUT(len);
    PUT((uint8_t)seq);
    PUT((uint8_t)(seq >> 8));
    PUT(id);
    for (uint8_t i = 0; i < len; i++)
        PUT(payload[i]);
#undef PUT
    crc ^= CRC32_XOROUT;
    for (uint8_t i = 0; i < 4; i++, crc >>= 8)
        frame_tx_buf[h++ & FRAME_TX_MASK] = (uint8_t)crc;
    frame_tx_head = h; /* publish the whole frame at once */
    board_tx_kick();
    return true;
}
