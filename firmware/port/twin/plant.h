/* The host build's twins of the rigs (--plant): C ports of labrunner/rigs/sim/, for campaigns that
 * run end to end on the host build. Not part of the core: a board reads its real sensors. */
#ifndef LAB_PLANT_H
#define LAB_PLANT_H
#include "lab_config.h"

typedef struct {
    uint8_t kind;
    int started;                 /* the first measurement after a reset is the initial state */
    uint64_t rng;
    double fs, u[4];
    int n_sub;
    double M[3][5];              /* the motor: [Phi | Gamma] of one sub-step */
    double z[5], theta;          /* theta_m, Omega, v, v_cmd, F; the load angle behind the backlash */
    /* the valve: coil current, magnetising current, pilot and main stroke, sticking, flow, sensor */
    double i_c, i_m, x_p, x_m, q, q_sensor, e_i, e_p, e_m, e_s;
    int moving, delay, at;
    double line[1025];           /* the flow sensor's delay: 50 ms at up to 20 kHz */
    /* the plate: coordinates (z, phi_x, phi_y, mode q), velocities, the maps to the magnet gaps and sensors */
    double x[4], v[4], G[4][4], S[4][4], inv_mass[4], k_c, c_c;
} lab_plant;

/* 0 if the twin of this device kind is built in (1 the DC motor, 2 the valve, 3 the plate). */
int lab_plant_init(lab_plant *p, uint8_t kind);
void lab_plant_reset(lab_plant *p, uint32_t seed, double fs);
/* The first call after a reset: the initial measurement; each later one integrates one period with the applied u. */
void lab_plant_measure(lab_plant *p, lab_real *y);
void lab_plant_apply(lab_plant *p, const lab_real *u);
void lab_plant_safe(lab_plant *p);

#endif
