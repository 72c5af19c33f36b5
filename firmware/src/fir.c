/* docs/control-laws.md § The building blocks: FIR estimate, FILTER record. */
#include <math.h>
#include <string.h>
#include "fir.h"
#include "protocol.h"

void lab_history_fill(lab_history *h, uint32_t len, lab_real v)
{
    h->len = len;
    h->head = 0;
    for (uint32_t i = 0; i < 2 * len; i++)
        h->buf[i] = v;
}

void lab_history_push(lab_history *h, lab_real v)
{
    h->head = h->head == 0 ? h->len - 1 : h->head - 1;
    h->buf[h->head] = v;
    h->buf[h->head + h->len] = v;
}

lab_real lab_fir(const lab_real *w, const lab_history *h)
{
    const lab_real *x = h->buf + h->head;
    lab_real sum = 0;
    for (uint32_t j = 0; j < h->len; j++)
        sum += w[j] * x[j];
    return sum;
}

/* M is (n + m) x (p + n), row-major; A[i][j] = M[j][p + i], B[i][j] = M[n + j][p + i].
 * docs/control-laws.md, "float32 devices": I - A is ill-conditioned (the MBC chain's integrators),
 * so the steady-state gain (I - A)^-1 B is solved in double from the record's float64 M (m64, the
 * FILTER record's little-endian values), never from the float M of a float32 build. */
int lab_filter_steady(lab_filter_def *def, const uint8_t *m64)
{
    unsigned n = def->n, m = def->m, cols = (unsigned)def->p + n;
    double a[LAB_MAX_FSTATES][LAB_MAX_FSTATES + LAB_MAX_FIN];
    for (unsigned i = 0; i < n; i++) { /* the system (I - A) S = B, augmented */
        for (unsigned j = 0; j < n; j++)
            a[i][j] = (i == j) - lab_getf64(m64 + 8 * (j * cols + def->p + i));
        for (unsigned j = 0; j < m; j++)
            a[i][n + j] = lab_getf64(m64 + 8 * ((n + j) * cols + def->p + i));
    }
    for (unsigned c = 0; c < n; c++) { /* Gaussian elimination with partial pivoting */
        unsigned best = c;
        for (unsigned r = c + 1; r < n; r++)
            if (fabs(a[r][c]) > fabs(a[best][c]))
                best = r;
        if (a[best][c] == 0)
            return -1;
        for (unsigned j = 0; j < n + m; j++) {
            double t = a[c][j];
            a[c][j] = a[best][j];
            a[best][j] = t;
        }
        for (unsigned r = c + 1; r < n; r++) {
            double q = a[r][c] / a[c][c];
            for (unsigned j = c; j < n + m; j++)
                a[r][j] -= q * a[c][j];
        }
    }
    for (unsigned k = 0; k < m; k++)
        for (unsigned i = n; i-- > 0;) {
            double s = a[i][n + k];
            for (unsigned j = i + 1; j < n; j++)
                s -= a[i][j] * def->steady[j][k];
            def->steady[i][k] = s / a[i][i];
        }
    return 0;
}

void lab_filter_init(lab_filter *f, const lab_filter_def *def, const lab_real *w0)
{
    f->def = def;
    for (unsigned i = 0; i < def->n; i++) {
        double s = 0;
        for (unsigned j = 0; j < def->m; j++)
            s += def->steady[i][j] * (double)w0[j];
        f->x[i] = (lab_real)s; /* rounded once */
    }
}

void lab_filter_step(lab_filter *f, const lab_real *w, lab_real *out)
{
    const lab_filter_def *d = f->def;
    unsigned n = d->n, cols = (unsigned)d->p + n;
    lab_real next[LAB_MAX_FOUT + LAB_MAX_FSTATES];
    for (unsigned c = 0; c < cols; c++) {
        lab_real s = 0;
        for (unsigned i = 0; i < n; i++)
            s += f->x[i] * d->M[i * cols + c];
        for (unsigned i = 0; i < d->m; i++)
            s += w[i] * d->M[(n + i) * cols + c];
        next[c] = s;
    }
    memcpy(out, next, d->p * sizeof *out);
    memcpy(f->x, next + d->p, n * sizeof *f->x);
}
