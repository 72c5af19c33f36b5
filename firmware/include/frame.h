/* Serial framing: 0x00 | COBS(node, code, payload, crc16_lo, crc16_hi) | 0x00 (docs/protocol.md § Serial framing). */
#ifndef LAB_FRAME_H
#define LAB_FRAME_H
#include "protocol.h"

#define LAB_SERIAL_MAX_BODY (2 + LAB_MAX_PAYLOAD + 2)
#define LAB_SERIAL_MAX_ENCODED (LAB_SERIAL_MAX_BODY + 1) /* 69 bytes between delimiters at most */
#define LAB_SERIAL_MAX_WIRE (LAB_SERIAL_MAX_ENCODED + 2)

/* The wire bytes of one frame, both delimiters included; returns their count. */
size_t lab_serial_encode(uint8_t node, const lab_frame *f, uint8_t out[LAB_SERIAL_MAX_WIRE]);

/* Streaming decoder: feed bytes as they arrive; a chunk between delimiters that is not valid COBS,
 * shorter than 4 bytes, longer than any frame or with a bad CRC is dropped and counted. */
typedef struct {
    uint8_t buf[LAB_SERIAL_MAX_ENCODED];
    size_t n;
    int overflow;           /* the chunk in progress is longer than any frame: garbage */
    uint32_t malformed, crc_errors;
} lab_serial_decoder;

void lab_serial_init(lab_serial_decoder *d);
/* Feed one byte; returns 1 with *node and *f set when it completes a good frame, else 0. */
int lab_serial_feed(lab_serial_decoder *d, uint8_t byte, uint8_t *node, lab_frame *f);

#endif
