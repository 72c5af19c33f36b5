/* The DC motor twin of labrunner/rigs/sim/dcmotor.py (thesis Sec. 2.4.1): the linear part
 * (theta_m, Omega, v) by its exact ZOH transition per sub-step, Coulomb and static friction,
 * backlash at the load, an encoder of 2048 counts and white input noise. Its defaults are the
 * Python twin's; its noise comes from its own generator (the same statistics, not the same numbers). */
#include <math.h>
#define PI 3.14159265358979323846
#include <string.h>
#include "plant.h"

static const double A_POLE = 40.8, B_GAIN = 121.3, U_MAX = 12.0, STATIC_F = 0.8, COULOMB_F = 0.6, BACKLASH = 0.02,
                    TAU = 0.5e-3, MAX_SUBSTEP = 1.25e-3, NOISE_V = 0.02;
static const int COUNTS = 2048;

/* e^(M) of an n x n matrix (n <= 5): scaling and squaring of a 20-term Taylor series. */
static void expm(double m[5][5], int n, double out[5][5])
{
    double norm = 0, term[5][5], next[5][5];
    int squarings = 0;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++)
            norm = fabs(m[i][j]) > norm ? fabs(m[i][j]) : norm;
    while (norm * n > 0.5) {
        norm /= 2;
        squarings++;
    }
    double scale = ldexp(1.0, -squarings);
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++)
            out[i][j] = term[i][j] = (i == j);
    for (int k = 1; k <= 20; k++) {
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++) {
                double s = 0;
                for (int l = 0; l < n; l++)
                    s += term[i][l] * m[l][j] * scale;
                next[i][j] = s / k;
            }
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++)
                out[i][j] += term[i][j] = next[i][j];
    }
    while (squarings-- > 0) {
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++) {
                double s = 0;
                for (int l = 0; l < n; l++)
                    s += out[i][l] * out[l][j];
                next[i][j] = s;
            }
        memcpy(out, next, sizeof next);
    }
}

static double gauss(uint64_t *s) /* xorshift64* and Box-Muller */
{
    double u[2];
    for (int i = 0; i < 2; i++) {
        *s ^= *s >> 12;
        *s ^= *s << 25;
        *s ^= *s >> 27;
        u[i] = ((*s * 0x2545F4914F6CDD1DULL) >> 11) * (1.0 / 9007199254740992.0);
    }
    return sqrt(-2.0 * log(u[0] + 1e-300)) * cos(2.0 * PI * u[1]);
}

int lab_plant_init(lab_plant *p, uint8_t kind)
{
    memset(p, 0, sizeof *p);
    p->kind = kind;
    return kind == 1 ? 0 : -1;
}

void lab_plant_reset(lab_plant *p, uint32_t seed, double fs)
{
    double h, m[5][5] = {{0}}, e[5][5];
    p->fs = fs;
    p->n_sub = (int)ceil(1.0 / fs / MAX_SUBSTEP - 1e-9);
    p->n_sub = p->n_sub < 1 ? 1 : p->n_sub;
    h = 1.0 / (fs * p->n_sub);
    m[0][1] = h;                 /* Van Loan: expm([[A, B], [0, 0]] h) */
    m[1][1] = -A_POLE * h;
    m[1][2] = B_GAIN * h;
    m[2][2] = -h / TAU;
    m[1][4] = -B_GAIN * h;
    m[2][3] = h / TAU;
    expm(m, 5, e);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 5; j++)
            p->M[i][j] = e[i][j];
    memset(p->z, 0, sizeof p->z);
    memset(p->u, 0, sizeof p->u);
    p->theta = 0;
    p->rng = 0x9E3779B97F4A7C15ULL ^ ((uint64_t)seed << 1 | 1u);
    p->started = 0;
}

static double sign(double v) { return (v > 0) - (v < 0); }

static void substep(lab_plant *p)
{
    double *z = p->z, xn[3], s;
    int stuck = z[1] == 0, hold = 0;
    if (stuck) {
        double drive = p->M[2][2] * z[2] + p->M[2][3] * z[3];
        s = sign(z[1] + drive);
        hold = fabs(drive) <= STATIC_F;
    } else {
        s = sign(z[1]);
    }
    z[4] = COULOMB_F * s;
    for (int i = 0; i < 3; i++)
        xn[i] = p->M[i][0] * z[0] + p->M[i][1] * z[1] + p->M[i][2] * z[2] + p->M[i][3] * z[3] + p->M[i][4] * z[4];
    int stop = xn[1] * s < 0 || hold; /* Coulomb friction stops a reversal; static friction holds */
    if (hold)
        xn[0] = z[0];
    if (stop)
        xn[1] = 0;
    memcpy(z, xn, sizeof xn);
    double half = BACKLASH / 2;
    p->theta = fmin(fmax(p->theta, z[0] - half), z[0] + half);
}

void lab_plant_measure(lab_plant *p, lab_real *y)
{
    if (p->started) {
        double v = p->u[0] + NOISE_V * gauss(&p->rng);
        p->z[3] = fmin(fmax(v, -U_MAX), U_MAX);
        for (int i = 0; i < p->n_sub; i++)
            substep(p);
    }
    p->started = 1;
    double d = 2.0 * PI / COUNTS;
    y[0] = (lab_real)(round(p->theta / d) * d);
}

void lab_plant_apply(lab_plant *p, const lab_real *u) { p->u[0] = u[0]; }

void lab_plant_safe(lab_plant *p) { p->u[0] = 0; }
