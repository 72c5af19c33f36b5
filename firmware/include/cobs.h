/* COBS, consistent overhead byte stuffing (docs/protocol.md § Serial framing): 0x00 only delimits. */
#ifndef LAB_COBS_H
#define LAB_COBS_H
#include "lab_config.h"

/* Encode n < 254 bytes into out (n + 1 bytes, no delimiter); returns the encoded length. */
size_t lab_cobs_encode(const uint8_t *in, size_t n, uint8_t *out);
/* Decode n bytes into out (at most n - 1 bytes); returns the decoded length or -1 if invalid. */
int lab_cobs_decode(const uint8_t *in, size_t n, uint8_t *out);

#endif
