/* Checksums of protocol v1 (docs/protocol.md § Serial framing; docs/device-loop.md § Run description). */
#ifndef LAB_CRC_H
#define LAB_CRC_H
#include "lab_config.h"

/* CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final XOR ("123456789" -> 0x29B1). */
uint16_t lab_crc16(const uint8_t *data, size_t n);
/* CRC-32/ISO-HDLC (zlib's): continue from crc (0 to start) ("123456789" -> 0xCBF43926). */
uint32_t lab_crc32(uint32_t crc, const uint8_t *data, size_t n);

#endif
