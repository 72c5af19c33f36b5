/* The hardware functions a lab writes to bring the core up on its board (docs/firmware.md § Port).
 * The core calls nothing else: no OS, no heap. All are called from the core's one thread. */
#ifndef LAB_PORT_H
#define LAB_PORT_H
#include "protocol.h"

/* A monotonic clock in microseconds (a free-running timer; it may start anywhere). */
uint64_t lab_port_now_us(void);
/* Wait until now_us >= t_us or a frame arrived (sleep, WFI, or return at once to busy-poll). */
void lab_port_wait_until(uint64_t t_us);
/* The next frame from the host if one is waiting (node id already checked); 1 if *f was set. */
int lab_port_recv(lab_frame *f);
/* Send one frame to the host (serial: COBS-framed; CAN: id = code << 7 | node, FD-padded). */
void lab_port_send(const lab_frame *f);
/* A run begins on the rig: reset what must be reset (the twin: its state and noise seed);
 * 0 if there is no rig to run (then only SENSOR_TABLE runs are served). */
int lab_port_begin_run(uint32_t seed, double fs);
/* Sample the sensors now: y[0..n_outputs) in SI units of the rig kind (docs/rigs.md). */
void lab_port_read_sensors(lab_real *y);
/* Apply u[0..n_inputs) (held until the next call). */
void lab_port_write_actuators(const lab_real *u);
/* The rig's safe input now (0 V, 0 A; drivers disabled where the board can). */
void lab_port_safe(void);

#endif
