/* Protocol v1's message kinds, codes and little-endian field access (docs/protocol.md § Messages). */
#ifndef LAB_PROTOCOL_H
#define LAB_PROTOCOL_H
#include "lab_config.h"

#define LAB_PROTOCOL_VERSION 1
#define LAB_FIXED_PAYLOAD 8

enum lab_kind { /* the CAN function code of each kind (docs/protocol.md § Messages) */
    LAB_SAFE = 0, LAB_STOP = 1, LAB_ERROR = 2, LAB_INPUT = 3, LAB_MEASUREMENT = 4, LAB_HEARTBEAT = 5,
    LAB_STATUS = 6, LAB_SETUP = 7, LAB_HELLO = 8, LAB_IDENTITY = 9, LAB_BULK_TO_DEVICE = 10,
    LAB_BULK_TO_HOST = 11, LAB_BULK_ACK_HOST = 12, LAB_BULK_ACK_DEVICE = 13
};

enum lab_error { /* ERROR codes */
    LAB_E_NONE = 0, LAB_E_WATCHDOG = 1, LAB_E_BAD_FRAME = 2, LAB_E_NOT_RUNNING = 3, LAB_E_BAD_CHANNEL = 4,
    LAB_E_SEQUENCE = 5, LAB_E_DEVICE_FAULT = 6, LAB_E_BAD_SETUP = 7, LAB_E_VERSION = 8, LAB_E_UNSUPPORTED = 9
};

enum lab_state { LAB_IDLE = 0, LAB_RUNNING = 1, LAB_SAFE_STATE = 2 };

enum lab_device_kind { LAB_DCMOTOR = 1, LAB_VALVE = 2, LAB_PLATE = 3 };

/* IDENTITY record 1 capability bits; FLOAT32: the law runs in single precision (agreed with the host side) */
#define LAB_CAP_HOST_LOOP 0x01u
#define LAB_CAP_DEVICE_LOOP 0x02u
#define LAB_CAP_CAN_FD 0x04u
#define LAB_CAP_FLOAT32 0x08u

#define LAB_FLAG_COMMIT 0x01u
#define LAB_FLAG_LATE 0x01u
#define LAB_FLAG_OVERRUN 0x02u
#define LAB_TICK_CHANNEL 0xFFu

/* One frame on any link: its kind (function code) and payload. */
typedef struct {
    uint8_t code;
    uint8_t len;
    uint8_t payload[LAB_MAX_PAYLOAD];
} lab_frame;

static inline uint16_t lab_get16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }
static inline uint32_t lab_get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static inline uint64_t lab_get64(const uint8_t *p) { return lab_get32(p) | (uint64_t)lab_get32(p + 4) << 32; }
static inline void lab_put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static inline void lab_put32(uint8_t *p, uint32_t v)
{
    lab_put16(p, (uint16_t)v);
    lab_put16(p + 2, (uint16_t)(v >> 16));
}
static inline void lab_put64(uint8_t *p, uint64_t v) { lab_put32(p, (uint32_t)v); lab_put32(p + 4, (uint32_t)(v >> 32)); }
double lab_getf64(const uint8_t *p);
float lab_getf32(const uint8_t *p);
void lab_putf64(uint8_t *p, double v);
void lab_putf32(uint8_t *p, float v);

#endif
