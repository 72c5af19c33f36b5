/* The run description (docs/device-loop.md § Run description): header, TLV records, CRC-32, parsed
 * into what the law reads. Large arrays (the sensor table, trajectory tables) stay in the received
 * bytes and are read from there tick by tick. */
#ifndef LAB_DESCRIPTION_H
#define LAB_DESCRIPTION_H
#include "protocol.h"

enum lab_law_kind { LAB_MFC1 = 1, LAB_MFC1_FF, LAB_MFC2, LAB_PLATE_MFC, LAB_PLATE_MBC, LAB_OPEN_LOOP, LAB_VALVE_FFC };

typedef struct { /* one TRAJECTORY record: type and up to 5 f64 arrays in the raw bytes */
    uint8_t code, count;
    uint32_t n[5];
    const uint8_t *a[5];
} lab_traj;

typedef struct { /* one FILTER record: [out, x+] = [x, w] . M */
    int have;
    uint16_t n;
    uint8_t m, p;
    lab_real M[(LAB_MAX_FSTATES + LAB_MAX_FIN) * (LAB_MAX_FOUT + LAB_MAX_FSTATES)];
    double steady[LAB_MAX_FSTATES][LAB_MAX_FIN]; /* (I - A)^-1 B from the record's float64 M */
} lab_filter_def;

typedef struct { /* the LAW records (docs/control-laws.md § Kinds) */
    lab_real gamma, k_p, k_d, filter_error, i_min, kappa, i_0, dp, y_min, c_p, c_d, g, lambda_inv_sqrt;
    int output_index, difference, flow_index, dp_index, input, have_k_d, have_i_min, have_dp, have_dp_index;
    lab_real weights[3], K[4][3], V[4][3], P_inv_B[3][4];
    uint32_t have; /* bit per name, for the checks */
} lab_law_consts;

typedef struct {
    double fs, duration, watchdog_s;
    uint32_t ticks, seed;
    uint8_t n_in, n_out, kind, stream;
    uint16_t n_columns;
    uint32_t fir_len[2];                 /* purpose 0 (orders 0..2), purpose 1 */
    uint8_t fir_have;                    /* bit n: purpose 0 order n; bit 3: purpose 1 order 1 */
    lab_real fir[4][LAB_MAX_FIR];        /* [order] for purpose 0, [3] the |du/dt| estimator */
    int have_sat;
    lab_real u_min[LAB_MAX_IO], u_max[LAB_MAX_IO];
    uint8_t bounds_have, bounds_n[3];    /* bit per kind 0 inputs, 1 outputs, 2 derived; signals each */
    lab_real lo[3][LAB_MAX_IO], hi[3][LAB_MAX_IO];
    uint8_t n_derived;
    lab_real derived[LAB_MAX_IO][LAB_MAX_IO];
    int have_rate;
    lab_real max_du_dt;
    double max_duration; /* compared with t = k/f_s, which is double too */
    uint8_t n_traj;
    lab_traj traj[LAB_MAX_IO];
    lab_filter_def notch, chain;
    lab_law_consts law;
    int have_motion;
    uint8_t motion_out, motion_rule;
    lab_real motion_threshold;
    const uint8_t *table;                /* SENSOR_TABLE rows (f64, row-major), NULL: the sensors */
    uint32_t table_rows;
} lab_desc;

/* Parse and check data[0..n) for a device of this kind with n_in inputs, n_out outputs and f_s up
 * to max_fs; 0 on success, else -1 with a one-line ASCII reason in reason (the REJECT's text).
 * The description keeps pointers into data: keep the bytes while it runs. */
int lab_desc_parse(lab_desc *d, const uint8_t *data, size_t n, uint8_t device_kind, uint8_t n_in, uint8_t n_out,
                   double max_fs, char *reason, size_t reason_size);
/* Columns per tick the kind logs (docs/device-loop.md § Blocks). */
unsigned lab_desc_columns(const lab_desc *d);
/* Controlled outputs with their own reference (one TRAJECTORY each). */
unsigned lab_desc_references(const lab_desc *d);
/* y[k] of the sensor table (row min(k, rows - 1)). */
void lab_desc_table_row(const lab_desc *d, uint32_t k, lab_real *y);

/* A deliberately wrong law (labrunner emulate --fault-law KEY=FACTOR): the scalar LAW constant
 * name x factor; 0 if the description has it, else -1. */
int lab_desc_fault(lab_desc *d, const char *name, double factor);

#endif
