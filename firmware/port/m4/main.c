/* The Cortex-M4F port (QEMU mps2-an386): the device core on UART0, serial framing, node 1; the
 * motor image closes the loop on the built-in twin. The kind is a build option (-DLAB_M4_KIND). */
#include "board.h"
#include "device.h"
#include "frame.h"
#include "plant.h"
#include "port.h"

#ifndef LAB_M4_KIND
#define LAB_M4_KIND LAB_DCMOTOR
#endif
#define NODE 1u

static lab_device device;
static lab_serial_decoder decoder;
static lab_plant plant;
static int has_plant;

uint64_t lab_port_now_us(void) { return board_ticks() / (BOARD_CLOCK_HZ / 1000000u); }

/* Sleep in WFI until t, a received byte or 1 ms, whichever comes first (the caller loops on the
 * clock). Under QEMU a guest that polls without pause also takes the CPU its I/O thread needs to
 * hand it the next received byte. */
void lab_port_wait_until(uint64_t t_us)
{
    uint64_t now = lab_port_now_us();
    if (t_us > now)
        board_sleep(t_us - now < 1000u ? (uint32_t)(t_us - now) : 1000u);
}

int lab_port_recv(lab_frame *f)
{
    uint8_t node;
    for (int c = board_uart_getc(); c >= 0; c = board_uart_getc())
        if (lab_serial_feed(&decoder, (uint8_t)c, &node, f) && node == NODE)
            return 1;
    return 0;
}

void lab_port_send(const lab_frame *f)
{
    uint8_t wire[LAB_SERIAL_MAX_WIRE];
    size_t n = lab_serial_encode(NODE, f, wire);
    for (size_t i = 0; i < n; i++)
        board_uart_putc(wire[i]);
}

int lab_port_begin_run(uint32_t seed, double fs)
{
    if (has_plant)
        lab_plant_reset(&plant, seed, fs);
    return has_plant;
}

void lab_port_read_sensors(lab_real *y) { lab_plant_measure(&plant, y); }
void lab_port_write_actuators(const lab_real *u) { lab_plant_apply(&plant, u); }
void lab_port_safe(void)
{
    if (has_plant)
        lab_plant_safe(&plant);
}

int main(void)
{
    board_init();
    lab_serial_init(&decoder);
    has_plant = lab_plant_init(&plant, LAB_M4_KIND) == 0;
    lab_device_init(&device, LAB_M4_KIND, LAB_MAX_PAYLOAD, 0, has_plant, 0x4C4D0001u);
    for (;;)
        lab_device_poll(&device);
}
