/* One tick of a device-loop run, in the documented order (docs/control-laws.md § One tick). */
#ifndef LAB_LOOP_H
#define LAB_LOOP_H
#include "laws.h"
#include "safety.h"

typedef struct {
    const lab_desc *d;
    lab_law law;
    lab_safety safety;
    lab_real u_prev[LAB_MAX_IO];      /* the applied input of the previous tick (u_init = 0 before tick 0) */
    lab_real y0, motion;              /* the no-motion rule: the watched output's first value, its extreme */
    uint32_t k;                       /* ticks done */
} lab_loop;

/* The state before tick 0 from y[0] (a FILTER without a steady state was rejected with its description). */
void lab_loop_init(lab_loop *loop, const lab_desc *d, const lab_real *y0);
/* Tick k = loop->k on the measured y: writes the logged row (d->n_columns values; the device sends them as float32) and the
 * input to apply; returns 1 with *trip set when the safety routine trips (the row is still logged). */
int lab_loop_tick(lab_loop *loop, const lab_real *y, lab_real *row, lab_real *u, lab_trip *trip);
/* After a run that neither failed nor tripped: whether the load moved (the MOTION record's rule). */
int lab_loop_moved(const lab_loop *loop);

#endif
