/* Wire framing (protocol v2): the receive parser (with resync and duplicate suppression) and
 * the transmit ring writer. Frame: SYNC | LEN | SEQ u16 | ID | PAYLOAD | CRC32 (over SYNC..). */
#ifndef FRAME_H
#define FRAME_H
#include <stdbool.h>
#include <stdint.h>

#include "core_config.h"
#include "protocol_gen.h"

typedef struct {
    uint16_t seq;
    uint8_t id, len;
    const uint8_t *payload;
} frame_t;

typedef void (*frame_handler_t)(const frame_t *f);

typedef struct {
    uint8_t buf[PROTO_MAX_FRAME];
    uint8_t n;          /* bytes buffered, buf[0] is a SYNC candidate once n > 0 */
    bool hunting;       /* sync lost; junk is counted once per run, not per byte */
    bool have_seq;      /* last_seq is valid */
    uint16_t last_seq;  /* SEQ of the last frame delivered */
    uint32_t rx_frames; /* frames with a good CRC (duplicates included) */
    uint16_t crc_errors;
    uint16_t resyncs;    /* bad CRC + impossible header + runs of junk where a SYNC was due */
    uint16_t duplicates; /* good frames repeating the last SEQ: dropped, not executed */
    frame_handler_t on_frame;
} frame_parser_t;

void frame_parser_init(frame_parser_t *p, frame_handler_t on_frame);
/* Decide on the buffered bytes: deliver, resync, or wait for more. */
void frame_parser_scan(frame_parser_t *p);

/* Feed one received byte; calls on_frame for each good frame (main context). Inline fast
 * path for every byte of a frame whose header looks sane (SYNC, LEN, then LEN = size of ID):
 * the out-of-line scan runs only on the last byte or on a bad one. On AVR a call to it costs
 * ~90 cycles of register saves alone, more than a byte time at 2 Mbaud. */
static inline void frame_parser_feed(frame_parser_t *p, uint8_t b)
{
    uint8_t n = p->n;
    p->buf[n++] = b;
    p->n = n;
    if (p->buf[0] == PROTO_SYNC) {
        if (n < 2)
            return;
        uint8_t len = p->buf[PROTO_OFF_LEN];
        if (len <= PROTO_MAX_PAYLOAD && n < (uint8_t)(len + PROTO_OVERHEAD) &&
            (n != PROTO_HEADER || proto_h2m_len(p->buf[PROTO_OFF_ID]) == len))
            return;
    }
    frame_parser_scan(p);
}

#if CORE_TX_RING <= 128u
typedef uint8_t tx_index_t; /* single byte: atomic for the AVR UART ISR */
#else
typedef uint16_t tx_index_t;
#endif

/* Queue one frame (main context only). Whole frame or nothing: a frame that does not fit is
 * dropped and counted in tx_dropped, so the host sees a SEQ gap, never a torn frame. */
bool frame_send(uint8_t id, const uint8_t *payload, uint8_t len);
/* The ring is visible so the UART ISR can pop inline: at 2 Mbaud a byte leaves every 80 CPU
 * cycles, and a function call from the ISR (register saves) costs about that much. */
#define FRAME_TX_MASK ((tx_index_t)(CORE_TX_RING - 1u))
extern uint8_t frame_tx_buf[CORE_TX_RING];
extern volatile tx_index_t frame_tx_head, frame_tx_tail; /* free-running; used = head - tail */

/* Take the next byte to transmit (UART ISR). */
static inline bool frame_tx_pop(uint8_t *b)
{
    tx_index_t t = frame_tx_tail;
    if (t == frame_tx_head)
        return false;
    *b = frame_tx_buf[t & FRAME_TX_MASK];
    frame_tx_tail = (tx_index_t)(t + 1u);
    return true;
}
uint16_t frame_tx_free(void);
uint16_t frame_tx_dropped(void);
void frame_tx_reset(void);

#endif
