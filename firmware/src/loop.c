/* docs/control-laws.md § One tick: measure, reference, law, saturate, safety routine, log, apply. */
#include <math.h>
#include "loop.h"
#include "reference.h"

void lab_loop_init(lab_loop *loop, const lab_desc *d, const lab_real *y0)
{
    loop->d = d;
    loop->k = 0;
    for (unsigned i = 0; i < LAB_MAX_IO; i++)
        loop->u_prev[i] = 0;
    loop->y0 = y0[d->motion_out];
    loop->motion = d->motion_rule ? y0[d->motion_out] : 0;
    lab_safety_init(&loop->safety, d);
    lab_law_init(&loop->law, d, y0);
}

static lab_real clamp(lab_real v, lab_real lo, lab_real hi) { return v < lo ? lo : v > hi ? hi : v; }

int lab_loop_tick(lab_loop *loop, const lab_real *y, lab_real *row, lab_real *u, lab_trip *trip)
{
    const lab_desc *d = loop->d;
    lab_real r[LAB_MAX_IO][4], u_star[LAB_MAX_IO], extra[LAB_MAX_IO], est[9];
    unsigned n_ref = lab_desc_references(d), n_extra, n_est, c = 0;
    for (unsigned j = 0; j < n_ref; j++)
        lab_reference(&d->traj[j], loop->k, d->fs, r[j]);
    lab_law_step(&loop->law, y, r, loop->u_prev, u_star, extra, &n_extra, est, &n_est);
    for (unsigned i = 0; i < d->n_in; i++) /* fmin/fmax would drop a NaN that the safety routine must see */
        u[i] = clamp(u_star[i], d->u_min[i], d->u_max[i]);
    if (d->kind == LAB_OPEN_LOOP)
        for (unsigned i = 0; i < n_extra; i++)
            extra[i] = clamp(extra[i], d->u_min[i], d->u_max[i]);
    int tripped = lab_safety_check(&loop->safety, loop->k, u, y, trip);
    for (unsigned i = 0; i < d->n_in; i++)
        row[c++] = u[i];
    for (unsigned j = 0; j < d->n_out; j++)
        row[c++] = y[j];
    for (unsigned i = 0; i < n_extra; i++)
        row[c++] = extra[i];
    for (unsigned j = 0; j < n_ref; j++)
        row[c++] = r[j][0];
    for (unsigned i = 0; i < n_est; i++)
        row[c++] = est[i];
    lab_real m = y[d->motion_out];
    if (d->motion_rule)
        loop->motion = m > loop->motion ? m : loop->motion;
    else if (LAB_FABS(m - loop->y0) > loop->motion)
        loop->motion = LAB_FABS(m - loop->y0);
    for (unsigned i = 0; i < d->n_in; i++)
        loop->u_prev[i] = u[i];
    loop->k++;
    return tripped;
}

int lab_loop_moved(const lab_loop *loop) { return loop->motion > loop->d->motion_threshold; }
