/* docs/protocol.md § CAN identifiers. */
#include "can_frame.h"

uint8_t lab_canfd_length(uint8_t n)
{
    static const uint8_t sizes[] = {12, 16, 20, 24, 32, 48, 64};
    if (n <= 8)
        return n;
    for (unsigned i = 0; i < sizeof sizes; i++)
        if (n <= sizes[i])
            return sizes[i];
    return 64;
}

int lab_can_accept(uint32_t id, int extended, uint8_t node)
{
    if (extended || id > 0x7FFu || lab_can_node((uint16_t)id) != node)
        return 0;
    uint8_t code = lab_can_code((uint16_t)id);
    switch (code) {
    case LAB_SAFE: case LAB_STOP: case LAB_INPUT: case LAB_HEARTBEAT: case LAB_SETUP: case LAB_HELLO:
    case LAB_BULK_TO_DEVICE: case LAB_BULK_ACK_HOST:
        return 1;
    default:
        return 0; /* a device code: our own echo or a spoofed frame, never data */
    }
}
