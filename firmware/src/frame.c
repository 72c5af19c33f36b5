/* docs/protocol.md § Serial framing. */
#include <string.h>
#include "frame.h"
#include "cobs.h"
#include "crc.h"

size_t lab_serial_encode(uint8_t node, const lab_frame *f, uint8_t out[LAB_SERIAL_MAX_WIRE])
{
    uint8_t body[LAB_SERIAL_MAX_BODY];
    size_t n = 2u + f->len;
    body[0] = node;
    body[1] = f->code;
    memcpy(body + 2, f->payload, f->len);
    uint16_t crc = lab_crc16(body, n);
    body[n++] = (uint8_t)crc;
    body[n++] = (uint8_t)(crc >> 8);
    out[0] = 0;
    size_t m = lab_cobs_encode(body, n, out + 1);
    out[1 + m] = 0;
    return m + 2;
}

void lab_serial_init(lab_serial_decoder *d) { memset(d, 0, sizeof *d); }

static int chunk(lab_serial_decoder *d, uint8_t *node, lab_frame *f)
{
    uint8_t body[LAB_SERIAL_MAX_ENCODED];
    int n = lab_cobs_decode(d->buf, d->n, body);
    if (n < 4 || (size_t)n > LAB_SERIAL_MAX_BODY) {
        d->malformed++;
        return 0;
    }
    if (lab_crc16(body, (size_t)n - 2) != lab_get16(body + n - 2)) {
        d->crc_errors++;
        return 0;
    }
    *node = body[0];
    f->code = body[1];
    f->len = (uint8_t)(n - 4);
    memcpy(f->payload, body + 2, f->len);
    return 1;
}

int lab_serial_feed(lab_serial_decoder *d, uint8_t byte, uint8_t *node, lab_frame *f)
{
    if (byte != 0) {
        if (d->n < sizeof d->buf)
            d->buf[d->n++] = byte;
        else
            d->overflow = 1;
        return 0;
    }
    int ok = 0;
    if (d->overflow)
        d->malformed++;
    else if (d->n > 0)
        ok = chunk(d, node, f);
    d->n = 0;
    d->overflow = 0;
    return ok;
}
