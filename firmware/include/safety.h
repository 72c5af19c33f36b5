/* The safety routine and the no-motion rule (docs/control-laws.md § Safety routine). */
#ifndef LAB_SAFETY_H
#define LAB_SAFETY_H
#include "fir.h"

typedef struct {
    char monitor[24];                /* e.g. "du_dt", "output_high:h2"; empty: none tripped */
    double time, value, threshold;
} lab_trip;

typedef struct {
    const lab_desc *d;
    lab_history rate[LAB_MAX_IO];    /* |du/dt| estimator: u-tilde, its past the safe input (0) */
} lab_safety;

void lab_safety_init(lab_safety *s, const lab_desc *d);
/* The monitors on the applied u[k] and measured y[k] at tick k; 1 with *trip set when one trips. */
int lab_safety_check(lab_safety *s, uint32_t k, const lab_real *u, const lab_real *y, lab_trip *trip);

#endif
