/* The host port: the device core served on a pty (serial framing), optionally on a built-in twin
 * of the rig (--plant). `labdevice --kind dcmotor|valve|plate --pty [--plant] [--node N]
 * [--fault-law KEY=FACTOR] [--free-run]` prints `pty /dev/pts/N` first, then serves until killed. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>
#include "device.h"
#include "frame.h"
#include "plant.h"
#include "port.h"

static lab_device device; /* the firmware's state: static, as on a board */
static struct {
    int fd;
    uint8_t node;
    lab_serial_decoder decoder;
    uint8_t in[4096];
    size_t have, at;
    lab_plant plant;
    int has_plant, running;
} port;

uint64_t lab_port_now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

void lab_port_wait_until(uint64_t t_us)
{
    uint64_t now = lab_port_now_us();
    if (t_us <= now || port.at < port.have)
        return;
    struct pollfd p = {port.fd, POLLIN, 0};
    struct timespec ts = {(time_t)((t_us - now) / 1000000u), (long)((t_us - now) % 1000000u) * 1000};
    ppoll(&p, 1, &ts, NULL);
}

int lab_port_recv(lab_frame *f)
{
    uint8_t node;
    for (;;) {
        if (port.at == port.have) {
            ssize_t n = read(port.fd, port.in, sizeof port.in);
            if (n <= 0)
                return 0;
            port.have = (size_t)n;
            port.at = 0;
        }
        while (port.at < port.have)
            if (lab_serial_feed(&port.decoder, port.in[port.at++], &node, f) && node == port.node)
                return 1;
    }
}

void lab_port_send(const lab_frame *f)
{
    uint8_t wire[LAB_SERIAL_MAX_WIRE];
    size_t n = lab_serial_encode(port.node, f, wire), done = 0;
    while (done < n) {
        ssize_t w = write(port.fd, wire + done, n - done);
        if (w > 0)
            done += (size_t)w;
        else if (errno == EAGAIN) {
            struct pollfd p = {port.fd, POLLOUT, 0};
            poll(&p, 1, 100);
        } else
            return; /* the host end went away: frames are lost, as on a cut wire */
    }
}

int lab_port_begin_run(uint32_t seed, double fs)
{
    if (!port.has_plant)
        return 0;
    lab_plant_reset(&port.plant, seed, fs);
    return 1;
}

void lab_port_read_sensors(lab_real *y) { lab_plant_measure(&port.plant, y); }
void lab_port_write_actuators(const lab_real *u) { lab_plant_apply(&port.plant, u); }
void lab_port_safe(void)
{
    if (port.has_plant)
        lab_plant_safe(&port.plant);
}

static int open_pty(void)
{
    int fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (fd < 0 || grantpt(fd) != 0 || unlockpt(fd) != 0)
        return -1;
    const char *name = ptsname(fd);
    int slave = open(name, O_RDWR | O_NOCTTY); /* kept open: the master never reads EOF before the host opens it */
    struct termios t;
    if (slave < 0 || tcgetattr(slave, &t) != 0)
        return -1;
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
    printf("pty %s\n", name);
    fflush(stdout);
    return fd;
}

static int usage(const char *why)
{
    fprintf(stderr, "labdevice: %s\nusage: labdevice --kind dcmotor|valve|plate --pty [--plant] [--node 1..127] "
                    "[--fault-law KEY=FACTOR] [--free-run]\n", why);
    return 2;
}

int main(int argc, char **argv)
{
    const char *kinds[] = {"", "dcmotor", "valve", "plate"};
    uint8_t kind = 0;
    int pty = 0, node = 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *next = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--kind") == 0 && next) {
            for (uint8_t k = 1; k < 4; k++)
                if (strcmp(next, kinds[k]) == 0)
                    kind = k;
            if (!kind)
                return usage("--kind: must be one of dcmotor, valve, plate");
            i++;
        } else if (strcmp(a, "--pty") == 0) {
            pty = 1;
        } else if (strcmp(a, "--plant") == 0) {
            port.has_plant = 1;
        } else if (strcmp(a, "--free-run") == 0) {
            device.free_run = 1;
        } else if (strcmp(a, "--node") == 0 && next) {
            node = atoi(next);
            if (node < 1 || node > 127)
                return usage("--node: must be in 1..127");
            i++;
        } else if (strcmp(a, "--fault-law") == 0 && next) {
            const char *eq = strchr(next, '=');
            char *end;
            double factor = eq ? strtod(eq + 1, &end) : 0;
            if (!eq || eq == next || (size_t)(eq - next) >= sizeof device.fault_name || *end || !(factor == factor))
                return usage("--fault-law: must be KEY=FACTOR, e.g. gamma=1.01");
            memcpy(device.fault_name, next, (size_t)(eq - next));
            device.fault_factor = factor;
            i++;
        } else {
            return usage("unknown option");
        }
    }
    if (!kind)
        return usage("--kind: required (dcmotor, valve, plate)");
    if (!pty)
        return usage("--pty: required (the only link of the host build)");
    char fault[sizeof device.fault_name];
    double factor = device.fault_factor;
    int free_run = device.free_run;
    memcpy(fault, device.fault_name, sizeof fault);
    port.node = (uint8_t)node;
    lab_serial_init(&port.decoder);
    port.fd = open_pty();
    if (port.fd < 0) {
        perror("labdevice: pty");
        return 1;
    }
    lab_plant_init(&port.plant, kind);
    lab_device_init(&device, kind, LAB_MAX_PAYLOAD, 0, port.has_plant, 0x4C430001u);
    memcpy(device.fault_name, fault, sizeof fault);
    device.fault_factor = factor;
    device.free_run = free_run;
    for (;;)
        lab_device_poll(&device);
}
