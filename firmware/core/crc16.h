#ifndef CRC16_H
#define CRC16_H
#include <stdint.h>

#define CRC16_INIT 0xFFFFu
/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xorout), one byte. */
#ifdef __AVR__
/* avr-libc's hand-written XMODEM step is the same polynomial, unreflected (XMODEM only
 * starts from 0): ~20 cycles a byte where the C form below costs ~75 on AVR. */
#include <util/crc16.h>
static inline uint16_t crc16_update(uint16_t crc, uint8_t b) { return _crc_xmodem_update(crc, b); }
#else
static inline uint16_t crc16_update(uint16_t crc, uint8_t b)
{
    /* Table-free byte step (shift-and-xor form of the 0x1021 polynomial): a few cycles on
     * AVR, no 512-byte table in flash. */
    crc = (uint16_t)((crc >> 8) | (crc << 8));
    crc ^= b;
    crc ^= (uint16_t)((crc & 0xFFu) >> 4);
    crc ^= (uint16_t)(crc << 12);
    crc ^= (uint16_t)((crc & 0xFFu) << 5);
    return crc;
}
#endif

uint16_t crc16(const uint8_t *p, uint8_t n, uint16_t crc);

#endif
