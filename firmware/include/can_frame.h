/* CAN identifiers and CAN FD lengths (docs/protocol.md § CAN identifiers, § Messages). */
#ifndef LAB_CAN_FRAME_H
#define LAB_CAN_FRAME_H
#include "protocol.h"

/* 11-bit identifier code << 7 | node (node 1..127). */
static inline uint16_t lab_can_id(uint8_t code, uint8_t node) { return (uint16_t)(code << 7 | node); }
static inline uint8_t lab_can_node(uint16_t id) { return (uint8_t)(id & 0x7Fu); }
static inline uint8_t lab_can_code(uint16_t id) { return (uint8_t)(id >> 7); }
/* The CAN FD data length a payload of n bytes is padded to with 0x00 (0..8, 12, 16, 20, 24, 32, 48, 64). */
uint8_t lab_canfd_length(uint8_t n);
/* Whether a frame of this code and node is for this device: its node, a host code; frames of
 * other nodes, extended ids and device codes (own echoes) are not (docs/protocol.md § Own frames). */
int lab_can_accept(uint32_t id, int extended, uint8_t node);

#endif
