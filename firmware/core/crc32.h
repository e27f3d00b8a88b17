#ifndef CRC32_H
#define CRC32_H
#include <stdint.h>

/* CRC-32/ISO-HDLC, the zlib/Ethernet CRC (poly 0x04C11DB7 reflected = 0xEDB88320, init and
 * xorout 0xFFFFFFFF): the frame check of protocol v2. Python: zlib.crc32(data). Byte-wise table
 * lookup: on the AVR the table lives in flash (1 KiB of 32; RAM is 2 KiB) and a step is four
 * LPM loads and byte moves (>> 8 costs nothing on an 8-bit core), ~30 cycles. Table entry i is
 * the CRC step of byte i: c = i; 8 times c = c & 1 ? (c >> 1) ^ 0xEDB88320 : c >> 1. */
#define CRC32_INIT 0xFFFFFFFFul
#define CRC32_XOROUT 0xFFFFFFFFul

#ifdef __AVR__
#include <avr/pgmspace.h>
#define CRC32_TABLE_ATTR PROGMEM
extern const uint32_t crc32_table[256] PROGMEM;
static inline __attribute__((always_inline)) uint32_t crc32_update(uint32_t crc, uint8_t b)
{
    return pgm_read_dword(&crc32_table[(uint8_t)crc ^ b]) ^ (crc >> 8);
}
#else
#define CRC32_TABLE_ATTR
extern const uint32_t crc32_table[256];
static inline __attribute__((always_inline)) uint32_t crc32_update(uint32_t crc, uint8_t b)
{
    return crc32_table[(uint8_t)(crc ^ b)] ^ (crc >> 8);
}
#endif

/* Running register over n bytes (start from CRC32_INIT, finish with ^ CRC32_XOROUT). */
uint32_t crc32_update_buf(uint32_t crc, const uint8_t *p, uint8_t n);
static inline uint32_t crc32(const uint8_t *p, uint8_t n)
{
    return crc32_update_buf(CRC32_INIT, p, n) ^ CRC32_XOROUT;
}

#endif
