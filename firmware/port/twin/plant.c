/* Twins of the rigs for the host and M4 builds' --plant, ported from labrunner/rigs/sim/ with the
 * Python twins' default parameters; the noise comes from their own generator (the same statistics,
 * not the same numbers).
 * - the DC motor (dcmotor.py, thesis Sec. 2.4.1): the linear part (theta_m, Omega, v) by its exact
 *   ZOH transition per sub-step, Coulomb and static friction, backlash, a 2048-count encoder and
 *   white input noise;
 * - the valve (valve.py, paper 1 Sec. 3.3): current controller lag, magnetic hysteresis, pilot and
 *   main spool with friction and end stops, orifice and return-path flow, the sensor's delay, lag,
 *   under-reading below its range and noise;
 * - the plate (plate.py, paper 2): a rigid body in (z, phi_x, phi_y) and one plate mode, four
 *   magnets F = i^2 / d(h)^2 saturated, screws below and a stop above as stiff one-sided
 *   spring-dampers, current ripple and sensor noise, drift-kick-drift sub-steps. */
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

/* the valve's defaults (labrunner/rigs/sim/valve.py) */
static const double I_MAX = 1.01, CURRENT_TAU = 1.5e-3, HYSTERESIS = 0.02, PILOT_TAU = 3e-3, PILOT_TH = 0.5,
                    MAIN_TAU = 0.015, MAIN_FS = 0.006, MAIN_FC = 0.004, MAIN_G = 12.0, PILOT_G = 0.02, DOWN_G = 6.0,
                    SUPPLY_BAR = 30.0, PUMP_LPM = 21.9, SENSOR_DELAY = 0.05, SENSOR_TAU = 5e-3, SENSOR_MIN = 1.2,
                    SENSOR_MAX = 20.0, VALVE_SUBSTEP = 1.25e-4, NOISE_LPM = 0.03;

int lab_plant_init(lab_plant *p, uint8_t kind)
{
    memset(p, 0, sizeof *p);
    p->kind = kind;
    return kind >= 1 && kind <= 3 ? 0 : -1;
}

static double decay(double tau, double h) { return tau > 0 ? exp(-h / tau) : 0; }

static void valve_reset(lab_plant *p, double fs)
{
    p->n_sub = (int)ceil(1.0 / fs / VALVE_SUBSTEP - 1e-9);
    p->n_sub = p->n_sub < 1 ? 1 : p->n_sub;
    double h = 1.0 / (fs * p->n_sub);
    p->e_i = decay(CURRENT_TAU, h);
    p->e_p = decay(PILOT_TAU, h);
    p->e_m = decay(MAIN_TAU, h);
    p->e_s = decay(SENSOR_TAU, 1.0 / fs);
    p->i_c = p->i_m = p->x_p = p->x_m = p->q = p->q_sensor = 0;
    p->moving = 0;
    p->delay = (int)lround(SENSOR_DELAY * fs);
    p->delay = p->delay > 1024 ? 1024 : p->delay;
    p->at = 0;
    memset(p->line, 0, sizeof p->line);
}

static double valve_flow(double x_m, double x_p)
{
    double g = MAIN_G * x_m + PILOT_G * x_p, q = g * DOWN_G / sqrt(g * g + DOWN_G * DOWN_G) * sqrt(SUPPLY_BAR);
    return fmin(q, PUMP_LPM);
}

static double clip(double v, double lo, double hi) { return fmin(fmax(v, lo), hi); }

static void valve_step(lab_plant *p)
{
    double i = p->u[0];
    for (int k = 0; k < p->n_sub; k++) {
        p->i_c = i + (p->i_c - i) * p->e_i;
        p->i_m = fmin(fmax(p->i_m, p->i_c - HYSTERESIS / 2), p->i_c + HYSTERESIS / 2); /* magnetic hysteresis */
        double target = clip(p->i_m / I_MAX, 0, 1);
        p->x_p = target + (p->x_p - target) * p->e_p;
        double x_t = (p->x_p - PILOT_TH) / (1 - PILOT_TH), e = x_t - p->x_m;
        p->moving = fabs(e) > (p->moving ? MAIN_FC : MAIN_FS);
        double x_eq = x_t - MAIN_FC * ((e > 0) - (e < 0));
        p->x_m = clip(p->moving ? x_eq + (p->x_m - x_eq) * p->e_m : p->x_m, 0, 1);
    }
    p->q = valve_flow(p->x_m, p->x_p);
    int n = p->delay + 1;
    p->at = (p->at + 1) % n;
    p->line[p->at] = p->q;
    double delayed = p->line[(p->at - p->delay + n) % n];
    p->q_sensor = delayed + (p->q_sensor - delayed) * p->e_s;
}

static double valve_read(lab_plant *p)
{
    double q = p->q_sensor, reading = q < SENSOR_MIN ? q * q / SENSOR_MIN : q;
    return clip(reading + NOISE_LPM * gauss(&p->rng), 0, SENSOR_MAX);
}

/* the plate's defaults (labrunner/rigs/sim/plate.py, labrunner/plate_geometry.py) */
static const double P_M = 4.69, P_G = 9.81, P_JX = 5.13e-2, P_JY = 8.19e-2, P_LDX = 0.135, P_LDY = 0.144,
                    P_LFX = 0.1825, P_LFY = 0.117, P_LAM = 250.0, P_FMAX = 300.0, P_SCREW = 5.5e-3, P_TOP = 0.5e-3,
                    P_CONTACT_W = 1e4, P_CONTACT_Z = 0.5, P_MODE_W = 942.0, P_MODE_Z = 0.02, P_MODE_M = 4.0,
                    P_MODE_SHAPE = 0.8, P_SUBSTEP = 32e-6, P_SENSOR_STD = 0.5e-6, P_CURRENT_STD = 0.02;
static const double CORNERS[4][2] = {{-1, 1}, {-1, -1}, {1, 1}, {1, -1}};

/* x A = b for a 4 x 4 system in place (Gaussian elimination with partial pivoting) */
static void solve4(double a[4][4], double b[4], double x[4])
{
    for (int c = 0; c < 4; c++) {
        int best = c;
        for (int r = c + 1; r < 4; r++)
            best = fabs(a[r][c]) > fabs(a[best][c]) ? r : best;
        for (int j = 0; j < 4; j++) {
            double t = a[c][j];
            a[c][j] = a[best][j];
            a[best][j] = t;
        }
        double t = b[c];
        b[c] = b[best];
        b[best] = t;
        for (int r = c + 1; r < 4; r++) {
            double q = a[r][c] / a[c][c];
            for (int j = c; j < 4; j++)
                a[r][j] -= q * a[c][j];
            b[r] -= q * b[c];
        }
    }
    for (int i = 3; i >= 0; i--) {
        double s = b[i];
        for (int j = i + 1; j < 4; j++)
            s -= a[i][j] * x[j];
        x[i] = s / a[i][i];
    }
}

static void plate_reset(lab_plant *p, double fs)
{
    double inertia[4] = {P_M, P_JX, P_JY, P_MODE_M}, m[4][4], load[4], w[4] = {1, 1, 1, 1};
    for (int j = 0; j < 4; j++) { /* gaps h = x G at the magnets, sensor readings x S */
        double mx = CORNERS[j][0] * P_LFX, my = CORNERS[j][1] * P_LFY, sx = CORNERS[j][0] * P_LDX, sy = CORNERS[j][1] * P_LDY;
        p->G[0][j] = 1, p->G[1][j] = -my, p->G[2][j] = mx, p->G[3][j] = 1;
        p->S[0][j] = 1, p->S[1][j] = -sy, p->S[2][j] = sx, p->S[3][j] = P_MODE_SHAPE;
    }
    for (int a = 0; a < 4; a++)
        p->inv_mass[a] = 1 / inertia[a];
    for (int i = 0; i < 4; i++) /* G^T M^-1 G, its largest eigenvalue by power iteration */
        for (int j = 0; j < 4; j++) {
            m[i][j] = 0;
            for (int a = 0; a < 4; a++)
                m[i][j] += p->G[a][i] * p->inv_mass[a] * p->G[a][j];
        }
    double lambda = 0;
    for (int it = 0; it < 200; it++) {
        double next[4], norm = 0;
        for (int i = 0; i < 4; i++) {
            next[i] = 0;
            for (int j = 0; j < 4; j++)
                next[i] += m[i][j] * w[j];
            norm = fmax(norm, fabs(next[i]));
        }
        for (int i = 0; i < 4; i++)
            w[i] = next[i] / norm;
        lambda = norm;
    }
    double corner_mass = 1 / lambda;
    p->k_c = corner_mass * P_CONTACT_W * P_CONTACT_W;
    p->c_c = 2 * P_CONTACT_Z * corner_mass * P_CONTACT_W;
    p->n_sub = (int)ceil(1.0 / fs / P_SUBSTEP - 1e-9);
    p->n_sub = p->n_sub < 1 ? 1 : p->n_sub;
    for (int a = 0; a < 4; a++) { /* at rest on the screws: (k G G^T + S) x = M g + k G 1 screw_gap */
        for (int b = 0; b < 4; b++) {
            m[a][b] = 0;
            for (int j = 0; j < 4; j++)
                m[a][b] += p->k_c * p->G[a][j] * p->G[b][j];
        }
        m[a][a] += a == 3 ? P_MODE_W * P_MODE_W * inertia[3] : 0;
        load[a] = (a == 0 ? P_G * inertia[0] : 0) + p->k_c * P_SCREW * (p->G[a][0] + p->G[a][1] + p->G[a][2] + p->G[a][3]);
    }
    solve4(m, load, p->x);
    memset(p->v, 0, sizeof p->v);
}

/* x-double-dot at the current x for squared currents cs and velocity v (plate.py's _acceleration) */
static void plate_acceleration(const lab_plant *p, const double cs[4], const double v[4], double acc[4])
{
    double f[4], gen[4] = {0};
    for (int j = 0; j < 4; j++) {
        double gap = 0, rate = 0;
        for (int a = 0; a < 4; a++) {
            gap += p->x[a] * p->G[a][j];
            rate += v[a] * p->G[a][j];
        }
        double d = P_LAM * fmax(gap, 1e-6), pen = gap - clip(gap, P_TOP, P_SCREW);
        f[j] = fmin(cs[j] / (d * d), P_FMAX);
        if (pen != 0) { /* a screw or the stop: a one-sided spring-damper */
            double s = (pen > 0) - (pen < 0);
            f[j] += s * fmax(s * (p->k_c * pen + p->c_c * rate), 0);
        }
        for (int a = 0; a < 4; a++)
            gen[a] += f[j] * p->G[a][j];
    }
    for (int a = 0; a < 4; a++) {
        double lin = (a == 0 ? P_G : 0) - (a == 3 ? P_MODE_W * P_MODE_W : 0) * p->x[a];
        acc[a] = lin - gen[a] * p->inv_mass[a] - (a == 3 ? 2 * P_MODE_Z * P_MODE_W : 0) * v[a];
    }
}

static void plate_step(lab_plant *p)
{
    double cs[4], acc[4], h = 1.0 / (p->fs * p->n_sub);
    for (int j = 0; j < 4; j++) {
        double i = fmax(p->u[j] + P_CURRENT_STD * gauss(&p->rng), 0);
        cs[j] = i * i;
    }
    for (int k = 0; k < p->n_sub; k++) { /* drift-kick-drift (position Verlet) */
        for (int a = 0; a < 4; a++)
            p->x[a] += 0.5 * h * p->v[a];
        plate_acceleration(p, cs, p->v, acc);
        for (int a = 0; a < 4; a++) {
            p->v[a] += h * acc[a];
            p->x[a] += 0.5 * h * p->v[a];
        }
    }
}

static void plate_read(lab_plant *p, lab_real *y)
{
    for (int j = 0; j < 4; j++) {
        double s = 0;
        for (int a = 0; a < 4; a++)
            s += p->x[a] * p->S[a][j];
        y[j] = (lab_real)(s + P_SENSOR_STD * gauss(&p->rng));
    }
}

void lab_plant_reset(lab_plant *p, uint32_t seed, double fs)
{
    double h, m[5][5] = {{0}}, e[5][5];
    p->fs = fs;
    p->rng = 0x9E3779B97F4A7C15ULL ^ ((uint64_t)seed << 1 | 1u);
    p->started = 0;
    memset(p->u, 0, sizeof p->u);
    if (p->kind == 2 || p->kind == 3) {
        if (p->kind == 2)
            valve_reset(p, fs);
        else
            plate_reset(p, fs);
        return;
    }
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
    p->theta = 0;
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
    if (p->kind == 2 || p->kind == 3) {
        if (p->started)
            p->kind == 2 ? valve_step(p) : plate_step(p);
        p->started = 1;
        if (p->kind == 2)
            y[0] = (lab_real)valve_read(p);
        else
            plate_read(p, y);
        return;
    }
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

void lab_plant_apply(lab_plant *p, const lab_real *u)
{
    for (int j = 0; j < (p->kind == 3 ? 4 : 1); j++)
        p->u[j] = u[j];
}

void lab_plant_safe(lab_plant *p) { memset(p->u, 0, sizeof p->u); }
