/* docs/control-laws.md § References: setpoints (poly-5 steps), steps, sine, table. */
#include <math.h>
#include "reference.h"

static lab_real at(const lab_traj *t, unsigned array, uint32_t i) { return (lab_real)lab_getf64(t->a[array] + 8u * i); }

void lab_reference(const lab_traj *t, uint32_t k, double fs, lab_real r[4])
{
    lab_real time = (lab_real)(k / fs);
    r[1] = r[2] = r[3] = 0;
    if (t->code == 1) { /* setpoints: first, starts, durations, steps */
        r[0] = at(t, 0, 0);
        for (uint32_t i = 0; i < t->n[1]; i++) {
            lab_real T = at(t, 2, i), D = at(t, 3, i), x = (time - at(t, 1, i)) / T;
            lab_real tau = x < 0 ? 0 : x > 1 ? 1 : x, inside = x >= 0 && x < 1;
            lab_real t2 = tau * tau, t3 = t2 * tau, u = 1 - tau;
            r[0] += D * (10 * t3 - 15 * t3 * tau + 6 * t3 * t2);
            r[1] += D * (30 * t2 * u * u) / T;
            r[2] += D * (60 * tau * u * (1 - 2 * tau)) / (T * T);
            if (inside)
                r[3] += D * (60 * (1 - 6 * tau + 6 * t2)) / (T * T * T);
        }
    } else if (t->code == 2) { /* steps: first, starts, steps */
        r[0] = at(t, 0, 0);
        for (uint32_t i = 0; i < t->n[1]; i++)
            if (time >= at(t, 1, i))
                r[0] += at(t, 2, i);
    } else if (t->code == 3) { /* sine: amplitude, omega, duration, offset, delay */
        lab_real A = at(t, 0, 0), w = at(t, 0, 1), s = time - at(t, 0, 4);
        r[0] = at(t, 0, 3);
        if (s >= 0 && s < at(t, 0, 2)) {
            lab_real sn = LAB_SIN(w * s), cs = LAB_COS(w * s);
            r[0] += A * sn;
            r[1] = A * w * cs;
            r[2] = -A * w * w * sn;
            r[3] = -A * w * w * w * cs;
        }
    } else { /* table: (f_s), rows of r and 3 derivatives */
        uint32_t rows = t->n[1] / 4, row = k < rows ? k : rows - 1;
        for (unsigned m = 0; m < 4; m++)
            r[m] = at(t, 1, 4 * row + m);
    }
}
