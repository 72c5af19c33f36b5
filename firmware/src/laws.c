/* docs/control-laws.md § Kinds and § The building blocks. */
#include <math.h>
#include "laws.h"

/* docs/control-laws.md § Model-free estimates, the stationary past before tick 0 */
static void estimator_init(lab_estimator *e, uint32_t len, lab_real x0, int filter_error)
{
    lab_history_fill(&e->x, len, x0);
    lab_history_fill(&e->e, len, filter_error ? 0 : x0);
    lab_history_fill(&e->v, len, 0);
}

/* f-hat from x[k-1..] and v[k-1..], then e-hat and e-hat-dot from x[k] and r[k]; order n = 1 or 2. */
static void estimate(lab_estimator *e, const lab_desc *d, unsigned n, lab_real gamma_s, int filter_error, lab_real x,
                     lab_real v_prev, const lab_real r[4], lab_real out[3])
{
    lab_history_push(&e->v, v_prev);
    out[0] = lab_fir(d->fir[n], &e->x) - gamma_s * lab_fir(d->fir[0], &e->v);
    lab_history_push(&e->x, x);
    lab_history_push(&e->e, filter_error ? x - r[0] : x);
    out[1] = lab_fir(d->fir[0], &e->e) - (filter_error ? 0 : r[0]);
    out[2] = n == 2 ? lab_fir(d->fir[1], &e->e) - (filter_error ? 0 : r[1]) : 0;
}

/* the plate's air gaps h = K c and d(h) = lambda^-1/2 h (docs/control-laws.md § Plate geometry) */
static void gaps(const lab_law_consts *c, const lab_real *y, lab_real *h, lab_real *dd)
{
    for (unsigned i = 0; i < 4; i++) {
        h[i] = c->K[i][0] * y[0] + c->K[i][1] * y[1] + c->K[i][2] * y[2];
        dd[i] = c->lambda_inv_sqrt * h[i];
    }
}

static lab_real max0(lab_real v) { return v > 0 ? v : 0; }

void lab_law_init(lab_law *law, const lab_desc *d, const lab_real *y0)
{
    const lab_law_consts *c = &d->law;
    law->d = d;
    int fe = c->filter_error != 0;
    if (d->kind == LAB_MFC1 || d->kind == LAB_MFC1_FF || d->kind == LAB_MFC2) {
        law->y_prev = y0[c->output_index];
        estimator_init(&law->est[0], d->fir_len[0], c->difference ? 0 : y0[c->output_index], fe);
    } else if (d->kind == LAB_PLATE_MFC || d->kind == LAB_PLATE_MBC) {
        gaps(c, y0, law->h_prev, law->d_prev);
        for (unsigned j = 0; j < 3; j++) {
            if (d->kind == LAB_PLATE_MFC) {
                law->gy_prev[j] = c->gamma / (y0[j] > c->y_min ? y0[j] : c->y_min);
                estimator_init(&law->est[j], d->fir_len[0], y0[j], fe);
                if (d->notch.have)
                    lab_filter_init(&law->filter[j], &d->notch, &y0[j]);
            } else {
                lab_real w0[2] = {y0[j], c->g};
                lab_filter_init(&law->filter[j], &d->chain, w0);
            }
        }
    }
}

/* mfc1, mfc1-ff, mfc2 (thesis (2.35), (2.49); paper 1 eq. (16)) */
static void mfc(lab_law *law, const lab_real *y, lab_real r[][4], const lab_real *u_prev, lab_real *u_star,
                lab_real *extra, unsigned *n_extra, lab_real *est, unsigned *n_est)
{
    const lab_desc *d = law->d;
    const lab_law_consts *c = &d->law;
    unsigned n = d->kind == LAB_MFC2 ? 2 : 1;
    lab_real gamma = c->gamma, x = y[c->output_index];
    if (c->difference) { /* Omega from the angle, thesis (2.34) */
        x = (y[c->output_index] - law->y_prev) * (lab_real)d->fs;
        law->y_prev = y[c->output_index];
        extra[(*n_extra)++] = x;
    }
    lab_real e[3];
    estimate(&law->est[0], d, n, gamma, c->filter_error != 0, x, u_prev[0], r[0], e);
    lab_real u = (r[0][n] - e[0]) / gamma - c->k_p / gamma * e[1];
    if (n == 2)
        u -= c->k_d / gamma * e[2];
    if (c->have & (1u << 6) && r[0][0] <= 0) /* i_min (paper 1 Sec. 4.4.4) */
        u = c->i_min;
    u_star[0] = u;
    for (unsigned i = 0; i <= n; i++)
        est[(*n_est)++] = e[i];
}

/* valve-ffc (paper 1 eq. (11)) */
static void valve_ffc(const lab_desc *d, const lab_real *y, lab_real r[][4], lab_real *u_star)
{
    const lab_law_consts *c = &d->law;
    lab_real rho = c->have & (1u << 10) ? LAB_SQRT(c->dp) : LAB_SQRT(max0(y[c->dp_index]));
    u_star[0] = (rho > 0 ? c->kappa * (r[0][0] / (lab_real)60000) / rho : 0) + c->i_0;
}

/* plate-mbc (paper 2 Sec. 3.1, 4.2) */
static void plate_mbc(lab_law *law, const lab_real *y, lab_real r[][4], const lab_real *u_prev, lab_real *u_star,
                      lab_real *est)
{
    const lab_law_consts *c = &law->d->law;
    lab_real f[4], v[3], h[4];
    for (unsigned i = 0; i < 4; i++) {
        f[i] = u_prev[i] / law->d_prev[i];
        f[i] *= f[i];
    }
    for (unsigned j = 0; j < 3; j++) {
        lab_real t = c->P_inv_B[j][0] * f[0] + c->P_inv_B[j][1] * f[1] + c->P_inv_B[j][2] * f[2] + c->P_inv_B[j][3] * f[3];
        lab_real w[2] = {y[j], t + c->g}, o[3];
        lab_filter_step(&law->filter[j], w, o);
        est[j] = o[2] + c->g;
        est[3 + j] = o[0] - r[j][0];
        est[6 + j] = o[1] - r[j][1];
        v[j] = r[j][2] - c->c_d * est[6 + j] - c->c_p * est[3 + j] - c->g - o[2];
    }
    gaps(c, y, h, law->d_prev);
    for (unsigned i = 0; i < 4; i++)
        u_star[i] = law->d_prev[i] * LAB_SQRT(max0(c->V[i][0] * v[0] + c->V[i][1] * v[1] + c->V[i][2] * v[2]));
}

/* plate-mfc (paper 2 Sec. 3.2-3.3) */
static void plate_mfc(lab_law *law, const lab_real *y, lab_real r[][4], const lab_real *u_prev, lab_real *u_star,
                      lab_real *est)
{
    const lab_desc *d = law->d;
    const lab_law_consts *c = &d->law;
    lab_real gamma = c->gamma, x_est[3], wv[3], s[3];
    if (c->input == 0) { /* v: f = (u / d_prev)^2, x_est = P_inv_B f */
        lab_real f[4];
        for (unsigned i = 0; i < 4; i++) {
            f[i] = u_prev[i] / law->d_prev[i];
            f[i] *= f[i];
        }
        for (unsigned j = 0; j < 3; j++)
            x_est[j] = c->P_inv_B[j][0] * f[0] + c->P_inv_B[j][1] * f[1] + c->P_inv_B[j][2] * f[2] + c->P_inv_B[j][3] * f[3];
    } else {
        for (unsigned j = 0; j < 3; j++) {
            lab_real q = u_prev[j] / (c->input == 1 ? law->d_prev[j] : law->h_prev[j]);
            x_est[j] = c->input == 3 ? law->gy_prev[j] * u_prev[j] : q * q;
        }
    }
    lab_real gamma_s = c->input == 0 ? gamma : c->input == 3 ? -1 : -gamma;
    for (unsigned j = 0; j < 3; j++) {
        lab_real z = y[j], e[3];
        if (d->notch.have)
            lab_filter_step(&law->filter[j], &y[j], &z);
        estimate(&law->est[j], d, 2, gamma_s, c->filter_error != 0, z, x_est[j], r[j], e);
        est[j] = e[0];
        est[3 + j] = e[1];
        est[6 + j] = e[2];
        wv[j] = r[j][2] - c->k_p * e[1] - c->k_d * e[2] - e[0];
    }
    gaps(c, y, law->h_prev, law->d_prev);
    for (unsigned j = 0; j < 3; j++)
        law->gy_prev[j] = gamma / (y[j] > c->y_min ? y[j] : c->y_min);
    if (c->input == 0) {
        for (unsigned i = 0; i < 4; i++)
            u_star[i] = law->d_prev[i] *
                        LAB_SQRT(max0(c->V[i][0] * (wv[0] / gamma) + c->V[i][1] * (wv[1] / gamma) + c->V[i][2] * (wv[2] / gamma)));
        return;
    }
    for (unsigned j = 0; j < 3; j++)
        s[j] = -wv[j] / (c->input == 3 ? law->gy_prev[j] : gamma);
    lab_real q[4] = {s[0], s[1], s[2], c->weights[0] * s[0] + c->weights[1] * s[1] + c->weights[2] * s[2]};
    for (unsigned i = 0; i < 4; i++)
        u_star[i] = c->input == 3 ? q[i] : (c->input == 1 ? law->d_prev[i] : law->h_prev[i]) * LAB_SQRT(max0(q[i]));
}

void lab_law_step(lab_law *law, const lab_real *y, lab_real r[][4], const lab_real *u_prev, lab_real *u_star,
                  lab_real *extra, unsigned *n_extra, lab_real *est, unsigned *n_est)
{
    const lab_desc *d = law->d;
    *n_extra = *n_est = 0;
    switch (d->kind) {
    case LAB_OPEN_LOOP: /* the reference is the input; <input>_cmd is logged saturated by the caller */
        for (unsigned i = 0; i < d->n_in; i++)
            u_star[i] = extra[i] = r[i][0];
        *n_extra = d->n_in;
        break;
    case LAB_VALVE_FFC:
        valve_ffc(d, y, r, u_star);
        break;
    case LAB_PLATE_MBC:
        plate_mbc(law, y, r, u_prev, u_star, est);
        *n_est = 9;
        break;
    case LAB_PLATE_MFC:
        plate_mfc(law, y, r, u_prev, u_star, est);
        *n_est = 9;
        break;
    default:
        mfc(law, y, r, u_prev, u_star, extra, n_extra, est, n_est);
    }
}
