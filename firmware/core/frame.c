#include "frame.h"

#include <string.h>

#include "board.h"
#include "crc16.h"

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
        uint8_t len = p->buf[1];
        if (len > PROTO_MAX_PAYLOAD) {
            lose_sync(p);
            drop(p, 1);
            continue;
        }
        uint8_t total = (uint8_t)(len + PROTO_OVERHEAD);
        if (p->n < total)
            return;
        uint16_t want = crc16(p->buf + 1, (uint8_t)(len + 3), CRC16_INIT);
        uint16_t got = proto_get_u16(p->buf + 4 + len);
        if (want != got) {
            p->crc_errors++;
            lose_sync(p);
            drop(p, 1);
            continue;
        }
        p->hunting = false;
        p->rx_frames++;
        frame_t f = {p->buf[2], p->buf[3], len, p->buf + 4};
        p->on_frame(&f);
        drop(p, total);
    }
}

/* ---- transmit ring: single producer (main), single consumer (UART ISR) ---- */
uint8_t frame_tx_buf[CORE_TX_RING];
volatile tx_index_t frame_tx_head, frame_tx_tail;
static uint8_t tx_seq;
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
    uint8_t seq = tx_seq++;
    frame_tx_buf[h++ & FRAME_TX_MASK] = PROTO_SYNC;
    frame_tx_buf[h++ & FRAME_TX_MASK] = len;
    frame_tx_buf[h++ & FRAME_TX_MASK] = seq;
    frame_tx_buf[h++ & FRAME_TX_MASK] = id;
    uint16_t crc = crc16_update(crc16_update(crc16_update(CRC16_INIT, len), seq), id);
    for (uint8_t i = 0; i < len; i++) {
        uint8_t b = payload[i];
        frame_tx_buf[h++ & FRAME_TX_MASK] = b;
        crc = crc16_update(crc, b);
    }
    frame_tx_buf[h++ & FRAME_TX_MASK] = (uint8_t)crc;
    frame_tx_buf[h++ & FRAME_TX_MASK] = (uint8_t)(crc >> 8);
    frame_tx_head = h; /* publish the whole frame at once */
    board_tx_kick();
    return true;
}
