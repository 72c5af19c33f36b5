/* FIR estimates and linear filters (docs/control-laws.md § The building blocks). */
#ifndef LAB_FIR_H
#define LAB_FIR_H
#include "description.h"

/* A signal's history, newest first, stored twice so that a window is contiguous (no modulo per tap). */
typedef struct {
    lab_real buf[2 * LAB_MAX_FIR];
    uint32_t len, head;
} lab_history;

/* A stationary past: every sample of the history holds v. */
void lab_history_fill(lab_history *h, uint32_t len, lab_real v);
/* x[k] becomes the newest sample. */
void lab_history_push(lab_history *h, lab_real v);
/* D x[k] = sum_j w[j] x[k - j], w newest first (len taps). */
lab_real lab_fir(const lab_real *w, const lab_history *h);

/* One channel of a FILTER record: [out[k], x[k+1]] = [x[k], w[k]] . M. */
typedef struct {
    const lab_filter_def *def;
    lab_real x[LAB_MAX_FSTATES];
} lab_filter;

/* def->steady = (I - A)^-1 B, solved in double from the record's float64 M (m64, little-endian);
 * -1 if I - A is singular. */
int lab_filter_steady(lab_filter_def *def, const uint8_t *m64);
/* Start in the steady state of the first input: x = (I - A)^-1 B w0, rounded once. */
void lab_filter_init(lab_filter *f, const lab_filter_def *def, const lab_real *w0);
/* One tick: out gets the p outputs. */
void lab_filter_step(lab_filter *f, const lab_real *w, lab_real *out);

#endif
