/* The control laws a device runs, one tick each (docs/control-laws.md § Kinds). */
#ifndef LAB_LAWS_H
#define LAB_LAWS_H
#include "fir.h"

/* f-hat, e-hat, e-hat-dot of one ultra-local model (docs/control-laws.md § Model-free estimates). */
typedef struct {
    lab_history x, e, v; /* x: x[k-1], x[k-2], ... before the tick; e: e[k], ...; v: v[k-1], ... */
} lab_estimator;

typedef struct {
    const lab_desc *d;
    lab_estimator est[LAB_MAX_CTRL];
    lab_filter filter[LAB_MAX_CTRL];
    lab_real y_prev;                              /* mfc with difference = 1: y_o[k-1] */
    lab_real d_prev[4], h_prev[4], gy_prev[3];    /* the plate: the previous tick's d(h), h, gamma_y */
} lab_law;

/* The state before tick 0 from the first measurement y0 (docs/control-laws.md § One tick). */
void lab_law_init(lab_law *law, const lab_desc *d, const lab_real *y0);

/* One tick: from y[k], the references r[j][0..3] and the applied inputs u_prev = u[k-1], the
 * unsaturated inputs u_star, the logged controlled outputs not measured (extra) and the estimates
 * (est, in column order); returns how many extra and estimate values it wrote via n_extra, n_est. */
void lab_law_step(lab_law *law, const lab_real *y, lab_real r[][4], const lab_real *u_prev, lab_real *u_star,
                  lab_real *extra, unsigned *n_extra, lab_real *est, unsigned *n_est);

#endif
