#include "crc16.h"

uint16_t crc16(const uint8_t *p, uint8_t n, uint16_t crc)
{
    while (n--)
        crc = crc16_update(crc, *p++);
    return crc;
}
