/* docs/control-laws.md § Safety routine: the monitors in the order a verdict takes them. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "safety.h"

void lab_safety_init(lab_safety *s, const lab_desc *d)
{
    s->d = d;
    for (unsigned i = 0; i < d->n_in; i++)
        lab_history_fill(&s->rate[i], d->have_rate ? d->fir_len[1] : 1, 0);
}

static int trip_at(lab_trip *t, const char *monitor, const char *signal, double time, double value, double threshold)
{
    if (signal)
        snprintf(t->monitor, sizeof t->monitor, "%s:%s", monitor, signal);
    else
        snprintf(t->monitor, sizeof t->monitor, "%s", monitor);
    t->time = time;
    t->value = value;
    t->threshold = threshold;
    return 1;
}

/* A signal's name in a monitor when its group has more than one: the plate's i1..i4, y1..y4 and h1..h4
 * (docs/rigs.md); NULL (the bare monitor name) for a group of one. */
static const char *label(char buf[4], char prefix, unsigned n, unsigned j)
{
    if (n == 1)
        return NULL;
    buf[0] = prefix;
    buf[1] = (char)('1' + j);
    buf[2] = 0;
    return buf;
}

int lab_safety_check(lab_safety *s, uint32_t k, const lab_real *u, const lab_real *y, lab_trip *t)
{
    const lab_desc *d = s->d;
    double time = k / d->fs;
    lab_real derived[LAB_MAX_IO];
    char buf[4];
    for (unsigned j = 0; j < d->n_in; j++) /* the |du/dt| estimator runs every tick */
        lab_history_push(&s->rate[j], isfinite(u[j]) ? u[j] : 0);
    for (unsigned j = 0; j < d->n_in; j++)
        if (!isfinite(u[j]))
            return trip_at(t, "non_finite_input", NULL, time, u[j], 0);
    for (unsigned j = 0; j < d->n_out; j++)
        if (!isfinite(y[j]))
            return trip_at(t, "non_finite_output", NULL, time, y[j], 0);
    for (unsigned r = 0; r < d->n_derived; r++) {
        derived[r] = 0;
        for (unsigned j = 0; j < d->n_out; j++)
            derived[r] += d->derived[r][j] * y[j];
    }
    for (unsigned group = 0; group < 3; group++) { /* measured outputs, derived outputs, inputs */
        unsigned kind = group == 0 ? 1 : group == 1 ? 2 : 0;
        if (!(d->bounds_have & (1u << kind)))
            continue;
        const lab_real *v = kind == 1 ? y : kind == 2 ? derived : u;
        unsigned n = kind == 1 ? d->n_out : kind == 2 ? d->n_derived : d->n_in;
        const char *low = kind == 0 ? "input_low" : "output_low", *high = kind == 0 ? "input_high" : "output_high";
        for (unsigned side = 0; side < 2; side++)
            for (unsigned j = 0; j < n; j++) {
                const char *sig = label(buf, kind == 0 ? 'i' : kind == 1 ? 'y' : 'h', n, j);
                if (side == 0 && v[j] < d->lo[kind][j])
                    return trip_at(t, low, sig, time, v[j], d->lo[kind][j]);
                if (side == 1 && v[j] > d->hi[kind][j])
                    return trip_at(t, high, sig, time, v[j], d->hi[kind][j]);
            }
    }
    if (d->have_rate)
        for (unsigned j = 0; j < d->n_in; j++) {
            lab_real rho = LAB_FABS(lab_fir(d->fir[3], &s->rate[j]));
            if (rho >= d->max_du_dt)
                return trip_at(t, "du_dt", label(buf, 'i', d->n_in, j), time, rho, d->max_du_dt);
        }
    if (time >= d->max_duration)
        return trip_at(t, "run_time", NULL, time, time, d->max_duration);
    return 0;
}
