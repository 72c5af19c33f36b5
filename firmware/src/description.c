/* docs/device-loop.md § Run description; docs/control-laws.md § Kinds (which records each law needs). */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include "description.h"
#include "fir.h"
#include "crc.h"

#define HEADER_BYTES 16u
#define RECORD_BYTES 8u
enum { R_RUN = 1, R_KIND, R_PARAM, R_FIR, R_SATURATION, R_BOUNDS, R_RATE, R_MAX_DURATION, R_TRAJECTORY,
       R_DERIVED, R_FILTER, R_SENSOR_TABLE, R_MOTION, R_LAW };

static const char *const KINDS[] = {"", "mfc1", "mfc1-ff", "mfc2", "plate-mfc", "plate-mbc", "open-loop", "valve-ffc"};

/* LAW names, their bit in lab_law_consts.have and their shape */
enum { L_GAMMA, L_KP, L_KD, L_OUT, L_DIFF, L_FE, L_IMIN, L_KAPPA, L_I0, L_FLOW, L_DP, L_DPI, L_INPUT, L_WEIGHTS,
       L_YMIN, L_K, L_V, L_PB, L_LAM, L_CP, L_CD, L_G, L_COUNT };
static const struct { const char *name; uint8_t rows, cols; } LAWS[L_COUNT] = {
    {"gamma", 1, 1}, {"k_p", 1, 1}, {"k_d", 1, 1}, {"output_index", 1, 1}, {"difference", 1, 1},
    {"filter_error", 1, 1}, {"i_min", 1, 1}, {"kappa", 1, 1}, {"i_0", 1, 1}, {"flow_index", 1, 1}, {"dp", 1, 1},
    {"dp_index", 1, 1}, {"input", 1, 1}, {"weights", 1, 3}, {"y_min", 1, 1}, {"K", 4, 3}, {"V", 4, 3},
    {"P_inv_B", 3, 4}, {"lambda_inv_sqrt", 1, 1}, {"c_p", 1, 1}, {"c_d", 1, 1}, {"g", 1, 1}};
#define B(x) (1u << (x))
static const uint32_t NEEDS[] = {
    0,
    B(L_GAMMA) | B(L_KP) | B(L_OUT) | B(L_DIFF) | B(L_FE),                      /* mfc1 */
    B(L_GAMMA) | B(L_KP) | B(L_OUT) | B(L_DIFF) | B(L_FE),                      /* mfc1-ff */
    B(L_GAMMA) | B(L_KP) | B(L_KD) | B(L_OUT) | B(L_DIFF) | B(L_FE),            /* mfc2 */
    B(L_INPUT) | B(L_GAMMA) | B(L_KP) | B(L_KD) | B(L_FE) | B(L_WEIGHTS) | B(L_YMIN) | B(L_K) | B(L_V) | B(L_PB) |
        B(L_LAM),                                                               /* plate-mfc */
    B(L_CP) | B(L_CD) | B(L_G) | B(L_K) | B(L_V) | B(L_PB) | B(L_LAM),          /* plate-mbc */
    0,                                                                          /* open-loop */
    B(L_KAPPA) | B(L_I0) | B(L_FLOW)};                                          /* valve-ffc */
static const uint32_t MAY[] = {0, B(L_IMIN), B(L_IMIN), B(L_IMIN), 0, 0, 0, B(L_DP) | B(L_DPI)};

typedef struct { char *text; size_t size; } why;
#if defined(__GNUC__)
__attribute__((format(printf, 2, 3)))
#endif
static int fail(why *w, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    vsnprintf(w->text, w->size, fmt, args);
    va_end(args);
    return -1;
}

static void reals(lab_real *out, const uint8_t *p, size_t n)
{
    for (size_t i = 0; i < n; i++)
        out[i] = (lab_real)lab_getf64(p + 8 * i);
}

static int law_record(lab_desc *d, const uint8_t *v, uint32_t size, why *w)
{
    if (size < 3 || size < 3u + v[0] + 8u * v[1] * v[2])
        return fail(w, "malformed LAW record");
    char name[64] = {0};
    memcpy(name, v + 3, v[0] < 63 ? v[0] : 63);
    const uint8_t *x = v + 3 + v[0];
    lab_law_consts *c = &d->law;
    for (int i = 0; i < L_COUNT; i++) {
        if (strcmp(name, LAWS[i].name) != 0)
            continue;
        if (v[1] != LAWS[i].rows || v[2] != LAWS[i].cols)
            return fail(w, "LAW %s has the wrong shape (%ld values)", name, (long)v[1] * v[2]);
        c->have |= B(i);
        lab_real s = (lab_real)lab_getf64(x);
        switch (i) {
        case L_GAMMA: c->gamma = s; break;
        case L_KP: c->k_p = s; break;
        case L_KD: c->k_d = s; break;
        case L_OUT: c->output_index = (int)s; break;
        case L_DIFF: c->difference = s != 0; break;
        case L_FE: c->filter_error = s; break;
        case L_IMIN: c->i_min = s; break;
        case L_KAPPA: c->kappa = s; break;
        case L_I0: c->i_0 = s; break;
        case L_FLOW: c->flow_index = (int)s; break;
        case L_DP: c->dp = s; break;
        case L_DPI: c->dp_index = (int)s; break;
        case L_INPUT: c->input = (int)s; break;
        case L_WEIGHTS: reals(c->weights, x, 3); break;
        case L_YMIN: c->y_min = s; break;
        case L_K: reals(&c->K[0][0], x, 12); break;
        case L_V: reals(&c->V[0][0], x, 12); break;
        case L_PB: reals(&c->P_inv_B[0][0], x, 12); break;
        case L_LAM: c->lambda_inv_sqrt = s; break;
        case L_CP: c->c_p = s; break;
        case L_CD: c->c_d = s; break;
        default: c->g = s; break;
        }
        return 0;
    }
    return fail(w, "unknown LAW constant %s", name);
}

static int traj_record(lab_desc *d, const uint8_t *v, uint32_t size, why *w)
{
    if (size < 3 || v[2] > 5 || d->n_traj >= LAB_MAX_IO || v[0] != d->n_traj)
        return fail(w, "malformed TRAJECTORY record");
    lab_traj *t = &d->traj[d->n_traj++];
    t->code = v[1];
    t->count = v[2];
    uint32_t at = 3;
    for (unsigned i = 0; i < t->count; i++) {
        if (at + 4 > size)
            return fail(w, "malformed TRAJECTORY record");
        t->n[i] = lab_get32(v + at);
        t->a[i] = v + at + 4;
        if (t->n[i] > (size - at - 4) / 8)
            return fail(w, "TRAJECTORY array runs past its record");
        at += 4 + 8 * t->n[i];
    }
    static const uint8_t counts[] = {0, 4, 3, 1, 2};
    if (t->code < 1 || t->code > 4 || t->count != counts[t->code])
        return fail(w, "unknown trajectory type %d", t->code);
    if ((t->code == 1 && (t->n[1] != t->n[2] || t->n[1] != t->n[3] || t->n[0] != 1)) ||
        (t->code == 2 && (t->n[1] != t->n[2] || t->n[0] != 1)) || (t->code == 3 && t->n[0] != 5) ||
        (t->code == 4 && (t->n[0] != 1 || t->n[1] % 4 != 0 || t->n[1] == 0)))
        return fail(w, "TRAJECTORY of type %d has arrays of the wrong sizes", t->code);
    return 0;
}

static int filter_record(lab_desc *d, const uint8_t *v, uint32_t size, why *w)
{
    if (size < 5 || size < 5u + v[0])
        return fail(w, "malformed FILTER record");
    uint16_t n = lab_get16(v + 1);
    uint8_t m = v[3], p = v[4];
    char name[16] = {0};
    memcpy(name, v + 5, v[0] < 15 ? v[0] : 15);
    lab_filter_def *f = strcmp(name, "_notch") == 0 ? &d->notch : strcmp(name, "_chain") == 0 ? &d->chain : NULL;
    if (f == NULL)
        return fail(w, "unknown FILTER %s", name);
    if (n > LAB_MAX_FSTATES || m > LAB_MAX_FIN || p > LAB_MAX_FOUT || m < 1 || p < 1)
        return fail(w, "FILTER %s of %d states is larger than this device's", name, n);
    uint32_t count = (uint32_t)(n + m) * (uint32_t)(p + n);
    if (size != 5u + v[0] + 8u * count)
        return fail(w, "FILTER %s has %ld bytes too few or many", name, (long)size);
    f->have = 1;
    f->n = n;
    f->m = m;
    f->p = p;
    reals(f->M, v + 5 + v[0], count);
    if (lab_filter_steady(f, v + 5 + v[0]) != 0)
        return fail(w, "FILTER %s has no steady state (I - A is singular)", name);
    return 0;
}

static int record(lab_desc *d, uint16_t type, const uint8_t *v, uint32_t size, int *have_run, why *w)
{
    switch (type) {
    case R_RUN:
        if (size != 36)
            return fail(w, "RUN record of %ld bytes, expected 36", (long)size);
        d->fs = lab_getf64(v);
        d->duration = lab_getf64(v + 8);
        d->ticks = lab_get32(v + 16);
        d->seed = lab_get32(v + 20);
        d->watchdog_s = lab_getf64(v + 24);
        d->n_in = v[32];
        d->n_out = v[33];
        d->n_columns = lab_get16(v + 34);
        *have_run = 1;
        return 0;
    case R_KIND:
        for (uint8_t k = 1; k < sizeof KINDS / sizeof KINDS[0]; k++)
            if (strlen(KINDS[k]) == size && memcmp(KINDS[k], v, size) == 0)
                d->kind = k;
        if (d->kind == 0)
            return fail(w, "controller kind %.*s is not in this firmware", (int)(size < 32 ? size : 32), (const char *)v);
        return 0;
    case R_PARAM: /* the point's sections: the LAW records carry every constant the law reads */
        if (size < 3 || size < 3u + v[2])
            return fail(w, "malformed PARAM record");
        return 0;
    case R_FIR: {
        if (size < 6)
            return fail(w, "malformed FIR record");
        uint8_t purpose = v[0], order = v[1];
        uint32_t len = lab_get32(v + 2);
        if (purpose > 1 || order > 2 || (purpose == 1 && order != 1))
            return fail(w, "FIR of purpose %d and order %d is not one this firmware uses", purpose, order);
        if (len == 0 || len > LAB_MAX_FIR)
            return fail(w, "FIR of %ld taps: this device takes 1..%d", (long)len, LAB_MAX_FIR);
        if (size != 6 + 8 * len)
            return fail(w, "FIR record of %ld bytes disagrees with its length", (long)size);
        int slot = purpose ? 3 : order;
        if (d->fir_have & ~(1u << 3) && purpose == 0 && d->fir_len[0] != len)
            return fail(w, "FIR orders of %ld taps and another length", (long)len);
        d->fir_len[purpose] = len;
        d->fir_have |= (uint8_t)(1u << slot);
        reals(d->fir[slot], v + 6, len);
        return 0;
    }
    case R_SATURATION:
        if (size < 1 || v[0] > LAB_MAX_IO || size != 1u + 16u * v[0])
            return fail(w, "malformed SATURATION record");
        if (v[0] != d->n_in)
            return fail(w, "SATURATION for %d inputs", v[0]);
        reals(d->u_min, v + 1, v[0]);
        reals(d->u_max, v + 1 + 8 * v[0], v[0]);
        d->have_sat = 1;
        return 0;
    case R_BOUNDS:
        if (size < 2 || v[0] > 2 || v[1] > LAB_MAX_IO || size != 2u + 16u * v[1])
            return fail(w, "malformed BOUNDS record");
        d->bounds_n[v[0]] = v[1];
        reals(d->lo[v[0]], v + 2, v[1]);
        reals(d->hi[v[0]], v + 2 + 8 * v[1], v[1]);
        d->bounds_have |= (uint8_t)(1u << v[0]);
        return 0;
    case R_RATE:
        if (size != 32)
            return fail(w, "malformed RATE record");
        d->max_du_dt = (lab_real)lab_getf64(v);
        d->have_rate = 1;
        return 0;
    case R_MAX_DURATION:
        if (size != 8)
            return fail(w, "malformed MAX_DURATION record");
        d->max_duration = lab_getf64(v);
        return 0;
    case R_TRAJECTORY:
        return traj_record(d, v, size, w);
    case R_DERIVED:
        if (size < 2 || v[0] > LAB_MAX_IO || v[1] != d->n_out || size != 2u + 8u * v[0] * v[1])
            return fail(w, "malformed DERIVED record");
        d->n_derived = v[0];
        for (unsigned r = 0; r < v[0]; r++)
            reals(d->derived[r], v + 2 + 8 * r * v[1], v[1]);
        return 0;
    case R_FILTER:
        return filter_record(d, v, size, w);
    case R_SENSOR_TABLE:
        if (size < 5 || v[0] != d->n_out || lab_get32(v + 1) == 0 ||
            (size - 5) / 8 / v[0] != lab_get32(v + 1) || (size - 5) % (8u * v[0]) != 0)
            return fail(w, "SENSOR_TABLE not of %d outputs", d->n_out);
        d->table = v + 5;
        d->table_rows = lab_get32(v + 1);
        return 0;
    case R_MOTION:
        if (size != 10 || v[0] >= d->n_out || v[1] > 1)
            return fail(w, "malformed MOTION record");
        d->motion_out = v[0];
        d->motion_rule = v[1];
        d->motion_threshold = (lab_real)lab_getf64(v + 2);
        d->have_motion = 1;
        return 0;
    case R_LAW:
        return law_record(d, v, size, w);
    default:
        return fail(w, "unknown record type %d", type);
    }
}

unsigned lab_desc_references(const lab_desc *d)
{
    switch (d->kind) {
    case LAB_PLATE_MFC: case LAB_PLATE_MBC: return 3;
    case LAB_OPEN_LOOP: return d->n_in;
    default: return 1;
    }
}

unsigned lab_desc_columns(const lab_desc *d)
{
    unsigned n = d->n_in + d->n_out + lab_desc_references(d);
    switch (d->kind) {
    case LAB_MFC1: case LAB_MFC1_FF: return n + (unsigned)d->law.difference + 2;
    case LAB_MFC2: return n + (unsigned)d->law.difference + 3;
    case LAB_PLATE_MFC: case LAB_PLATE_MBC: return n + 9;
    case LAB_OPEN_LOOP: return n + d->n_in;
    default: return n;
    }
}

void lab_desc_table_row(const lab_desc *d, uint32_t k, lab_real *y)
{
    uint32_t row = k < d->table_rows ? k : d->table_rows - 1;
    for (unsigned j = 0; j < d->n_out; j++)
        y[j] = (lab_real)lab_getf64(d->table + 8u * ((size_t)row * d->n_out + j));
}

/* The records a kind needs, and that they fit this device (docs/control-laws.md § Kinds). */
static int consistent(const lab_desc *d, uint8_t device_kind, double max_fs, why *w)
{
    int plate = d->kind == LAB_PLATE_MFC || d->kind == LAB_PLATE_MBC;
    if ((plate && device_kind != LAB_PLATE) || (d->kind == LAB_VALVE_FFC && device_kind != LAB_VALVE) ||
        (!plate && d->kind != LAB_OPEN_LOOP && device_kind == LAB_PLATE))
        return fail(w, "controller kind %s does not run on this device kind (%d)", KINDS[d->kind], device_kind);
    if (!(d->fs > 0 && d->fs <= max_fs))
        return fail(w, "f_s of %ld Hz is outside this device's range", (long)d->fs);
    if (d->ticks == 0 || !(d->watchdog_s > 0))
        return fail(w, "RUN needs ticks > 0 and a watchdog > 0");
    uint32_t have = d->law.have, need = NEEDS[d->kind];
    if ((have & need) != need)
        return fail(w, "LAW constants missing for %s (%ld)", KINDS[d->kind], (long)(need & ~have));
    if (have & ~(need | MAY[d->kind]))
        return fail(w, "LAW constants for %s that it does not use (%ld)", KINDS[d->kind], (long)(have & ~need));
    if (d->kind == LAB_VALVE_FFC && !!(have & B(L_DP)) == !!(have & B(L_DPI)))
        return fail(w, "valve-ffc needs dp or dp_index");
    const lab_law_consts *c = &d->law;
    if ((d->kind <= LAB_MFC2 && (c->output_index < 0 || c->output_index >= d->n_out)) ||
        (d->kind == LAB_VALVE_FFC && (c->flow_index < 0 || c->flow_index >= d->n_out ||
                                      ((have & B(L_DPI)) && (c->dp_index < 0 || c->dp_index >= d->n_out)))) ||
        (d->kind == LAB_PLATE_MFC && (c->input < 0 || c->input > 3)) || (plate && d->n_out < 3))
        return fail(w, "LAW index out of range for %s", KINDS[d->kind]);
    unsigned order = d->kind == LAB_MFC2 || d->kind == LAB_PLATE_MFC ? 2 : 1;
    if (d->kind <= LAB_PLATE_MFC && (d->fir_have & ((1u << (order + 1)) - 1)) != (1u << (order + 1)) - 1)
        return fail(w, "FIR weights of derivative orders 0..%ld missing", (long)order);
    if (d->have_rate != !!(d->fir_have & 8u))
        return fail(w, "RATE and the |du/dt| FIR come together");
    if (!d->have_sat)
        return fail(w, "SATURATION record missing");
    if (d->kind == LAB_PLATE_MBC && !(d->chain.have && d->chain.m == 2 && d->chain.p == 3))
        return fail(w, "plate-mbc needs its FILTER _chain (2 inputs, 3 outputs)");
    if (d->notch.have && (d->kind != LAB_PLATE_MFC || d->notch.m != 1 || d->notch.p != 1))
        return fail(w, "FILTER _notch only for plate-mfc, 1 input and 1 output");
    if (d->chain.have && d->kind != LAB_PLATE_MBC)
        return fail(w, "FILTER _chain only for plate-mbc");
    if (d->n_traj != lab_desc_references(d))
        return fail(w, "%s needs one TRAJECTORY per controlled output, got %d", KINDS[d->kind], d->n_traj);
    if (!d->have_motion)
        return fail(w, "MOTION record missing");
    for (unsigned kind = 0; kind < 3; kind++)
        if ((d->bounds_have & (1u << kind)) && d->bounds_n[kind] != (kind == 0 ? d->n_in : kind == 1 ? d->n_out : d->n_derived))
            return fail(w, "BOUNDS of kind %u for the wrong number of signals", kind);
    if (d->n_columns != lab_desc_columns(d) || d->n_columns > LAB_MAX_COLUMNS)
        return fail(w, "description asks for %d columns, the run logs %u", d->n_columns, lab_desc_columns(d));
    return 0;
}

int lab_desc_parse(lab_desc *d, const uint8_t *data, size_t n, uint8_t device_kind, uint8_t n_in, uint8_t n_out,
                   double max_fs, char *reason, size_t reason_size)
{
    why w = {reason, reason_size};
    memset(d, 0, sizeof *d);
    d->max_duration = 1.0 / 0.0;
    if (n < HEADER_BYTES + 4)
        return fail(&w, "description of %ld bytes is shorter than its header and CRC", (long)n);
    if (memcmp(data, "LRDL", 4) != 0)
        return fail(&w, "bad magic");
    if (lab_get16(data + 4) != 1)
        return fail(&w, "description version %d; this device speaks 1", lab_get16(data + 4));
    uint16_t head = lab_get16(data + 6);
    uint32_t body = lab_get32(data + 8);
    if (head != HEADER_BYTES || (uint64_t)head + body + 4 != n)
        return fail(&w, "description of %ld bytes disagrees with its header", (long)n);
    if (lab_crc32(0, data, n - 4) != lab_get32(data + n - 4))
        return fail(&w, "description CRC-32 mismatch");
    d->stream = (uint8_t)(lab_get16(data + 12) & 1u);
    uint16_t count = lab_get16(data + 14);
    size_t pos = head, end = n - 4;
    int have_run = 0;
    for (unsigned i = 0; i < count; i++) {
        if (pos + RECORD_BYTES > end)
            return fail(&w, "record runs past the end of the description");
        uint16_t type = lab_get16(data + pos);
        uint32_t size = lab_get32(data + pos + 4);
        pos += RECORD_BYTES;
        if (size > end - pos)
            return fail(&w, "record runs past the end of the description");
        if (type != R_RUN && !have_run)
            return fail(&w, "RUN must be the first record");
        if (record(d, type, data + pos, size, &have_run, &w) != 0)
            return -1;
        if (type == R_RUN && (d->n_in != n_in || d->n_out != n_out)) {
            snprintf(reason, reason_size, "description for %u inputs and %u outputs; this device has %u and %u",
                     d->n_in, d->n_out, n_in, n_out);
            return -1;
        }
        pos += size;
    }
    if (pos != end)
        return fail(&w, "%ld bytes after the last record", (long)(end - pos));
    if (!have_run || d->kind == 0)
        return fail(&w, "description without its RUN or KIND record");
    return consistent(d, device_kind, max_fs, &w);
}

int lab_desc_fault(lab_desc *d, const char *name, double factor)
{
    lab_law_consts *c = &d->law;
    lab_real *targets[L_COUNT] = {[L_GAMMA] = &c->gamma, [L_KP] = &c->k_p, [L_KD] = &c->k_d, [L_IMIN] = &c->i_min,
                                  [L_KAPPA] = &c->kappa, [L_I0] = &c->i_0, [L_DP] = &c->dp, [L_YMIN] = &c->y_min,
                                  [L_CP] = &c->c_p, [L_CD] = &c->c_d, [L_G] = &c->g};
    for (int i = 0; i < L_COUNT; i++)
        if (targets[i] && (c->have & B(i)) && strcmp(name, LAWS[i].name) == 0) {
            *targets[i] = (lab_real)(*targets[i] * factor);
            return 0;
        }
    return -1;
}
