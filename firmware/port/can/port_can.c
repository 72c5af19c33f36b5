/* A CAN port of the device core, as a shared library: the frames go through two callbacks (a
 * python-can bus in firmware/port/can/can_bridge.py), the core's CAN layer does the rest — the
 * identifier plan, which frames are this node's, CAN FD padding (docs/protocol.md § CAN identifiers). */
#define _GNU_SOURCE
#include <string.h>
#include <time.h>
#include "can_frame.h"
#include "device.h"
#include "plant.h"
#include "port.h"

/* 1 with the next bus message in *id, *extended, data[0..*len) when one waits, else 0 */
typedef int (*lab_can_recv_fn)(uint32_t *id, int *extended, uint8_t *data, uint8_t *len);
/* send one message: 11-bit id, data padded to a valid CAN FD length when fd */
typedef void (*lab_can_send_fn)(uint32_t id, const uint8_t *data, uint8_t len, int fd);

static lab_device device;
static struct {
    lab_can_recv_fn recv;
    lab_can_send_fn send;
    uint8_t node;
    int fd, has_plant;
    lab_plant plant;
} port;

uint64_t lab_port_now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

void lab_port_wait_until(uint64_t t_us) /* the bus is polled through the callback: sleep in short slices */
{
    uint64_t now = lab_port_now_us();
    if (t_us > now) {
        uint64_t dt = t_us - now < 300u ? t_us - now : 300u;
        struct timespec ts = {0, (long)dt * 1000};
        nanosleep(&ts, NULL);
    }
}

int lab_port_recv(lab_frame *f)
{
    uint32_t id;
    int extended;
    uint8_t data[64], len;
    while (port.recv(&id, &extended, data, &len)) {
        if (!lab_can_accept(id, extended, port.node) || len > LAB_MAX_PAYLOAD)
            continue; /* another node's, an extended id, or our own echo */
        f->code = lab_can_code((uint16_t)id);
        f->len = len;
        memcpy(f->payload, data, len);
        return 1;
    }
    return 0;
}

void lab_port_send(const lab_frame *f)
{
    uint8_t data[64] = {0}, n = port.fd ? lab_canfd_length(f->len) : f->len;
    memcpy(data, f->payload, f->len);
    port.send(lab_can_id(f->code, port.node), data, n, port.fd);
}

int lab_port_begin_run(uint32_t seed, double fs)
{
    if (port.has_plant)
        lab_plant_reset(&port.plant, seed, fs);
    return port.has_plant;
}

void lab_port_read_sensors(lab_real *y) { lab_plant_measure(&port.plant, y); }
void lab_port_write_actuators(const lab_real *u) { lab_plant_apply(&port.plant, u); }
void lab_port_safe(void)
{
    if (port.has_plant)
        lab_plant_safe(&port.plant);
}

/* Set up the device of kind (1 dcmotor, 2 valve, 3 plate) as node 1..127 on a classic (fd 0) or
 * CAN FD bus; plant: run on the built-in twin; fault_key, fault_factor: a deliberately wrong law
 * (the LAW constant fault_key x fault_factor, as --fault-law KEY=FACTOR), or NULL.
 * Returns 0, or -1 for an argument out of range. */
int lab_can_open(int kind, int node, int fd, int plant, const char *fault_key, double fault_factor,
                 lab_can_recv_fn recv, lab_can_send_fn send);
int lab_can_open(int kind, int node, int fd, int plant, const char *fault_key, double fault_factor,
                 lab_can_recv_fn recv, lab_can_send_fn send)
{
    if (kind < 1 || kind > 3 || node < 1 || node > 127 || !recv || !send)
        return -1;
    port.recv = recv;
    port.send = send;
    port.node = (uint8_t)node;
    port.fd = fd != 0;
    port.has_plant = plant && lab_plant_init(&port.plant, (uint8_t)kind) == 0;
    if (plant && !port.has_plant)
        return -1;
    lab_device_init(&device, (uint8_t)kind, port.fd ? 64 : 8, port.fd, port.has_plant, 0x4C430002u);
    if (fault_key && fault_key[0]) {
        strncpy(device.fault_name, fault_key, sizeof device.fault_name - 1);
        device.fault_factor = fault_factor;
    }
    return 0;
}

/* One turn of the device's main loop (a description runs inside it until its results are acknowledged). */
void lab_can_poll(void);
void lab_can_poll(void) { lab_device_poll(&device); }
