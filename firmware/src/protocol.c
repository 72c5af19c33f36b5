/* docs/protocol.md § Messages: every multi-byte field little-endian, IEEE 754 floats. */
#include <string.h>
#include "protocol.h"

double lab_getf64(const uint8_t *p)
{
    uint64_t u = lab_get64(p);
    double v;
    memcpy(&v, &u, sizeof v);
    return v;
}

float lab_getf32(const uint8_t *p)
{
    uint32_t u = lab_get32(p);
    float v;
    memcpy(&v, &u, sizeof v);
    return v;
}

void lab_putf64(uint8_t *p, double v)
{
    uint64_t u;
    memcpy(&u, &v, sizeof u);
    lab_put64(p, u);
}

void lab_putf32(uint8_t *p, float v)
{
    uint32_t u;
    memcpy(&u, &v, sizeof u);
    lab_put32(p, u);
}
