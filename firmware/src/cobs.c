/* docs/protocol.md § Serial framing: COBS. */
#include "cobs.h"

size_t lab_cobs_encode(const uint8_t *in, size_t n, uint8_t *out)
{
    size_t code_at = 0, o = 1;
    uint8_t code = 1;
    for (size_t i = 0; i < n; i++) {
        if (in[i] == 0) {
            out[code_at] = code;
            code_at = o++;
            code = 1;
        } else {
            out[o++] = in[i];
            code++;
        }
    }
    out[code_at] = code;
    return o;
}

int lab_cobs_decode(const uint8_t *in, size_t n, uint8_t *out)
{
    size_t i = 0, o = 0;
    while (i < n) {
        uint8_t code = in[i];
        if (code == 0 || i + code > n)
            return -1;
        for (size_t j = 1; j < code; j++) {
            if (in[i + j] == 0)
                return -1;
            out[o++] = in[i + j];
        }
        i += code;
        if (i < n)
            out[o++] = 0;
    }
    return (int)o;
}
