/* Replays every conformance vector of docs/vectors/ through the core (docs/control-laws.md
 * § Conformance vectors): the law on the sensor table, every logged column against vector.csv,
 * the verdict against verdict.txt. Prints one line per vector with the largest error, normalised
 * as tests/test_vectors.py does for the Python reference: |got - want| / (|want| + max |column|).
 * Exit 1 when a verdict differs or an error exceeds the limit given (the float64 build: 1e-9).
 * With --rows OUT it also writes each vector's logged rows (OUT/CASE.csv, one tick a line) and its
 * verdict (OUT/CASE.verdict: status, monitor or -, time, value, threshold), so that the host's law
 * check can judge a float32 replay per column and tick under its float32 tolerance. --fault KEY
 * FACTOR runs a deliberately wrong law (the LAW constant KEY times FACTOR), as labdevice --fault-law. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "loop.h"

#define MAX_ROWS 2000
static uint8_t raw[1 << 20];
static double want[MAX_ROWS][LAB_MAX_COLUMNS + 1];
static lab_desc desc;
static lab_loop loop;

static long slurp(const char *path, uint8_t *buf, size_t size)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return -1;
    size_t n = fread(buf, 1, size, f);
    fclose(f);
    return (long)n;
}

static int csv(const char *path, unsigned cols)
{
    static char line[16384];
    FILE *f = fopen(path, "r");
    int rows = 0;
    if (!f || !fgets(line, sizeof line, f))
        return -1;
    while (rows < MAX_ROWS && fgets(line, sizeof line, f)) {
        char *p = line;
        for (unsigned c = 0; c <= cols; c++) {
            want[rows][c] = strtod(p, &p);
            if (*p == ',')
                p++;
        }
        rows++;
    }
    fclose(f);
    return rows;
}

static void verdict_value(const char *path, const char *key, char *out, size_t size)
{
    char line[512];
    FILE *f = fopen(path, "r");
    out[0] = 0;
    while (f && fgets(line, sizeof line, f))
        if (strncmp(line, key, strlen(key)) == 0 && strncmp(line + strlen(key), " = ", 3) == 0) {
            snprintf(out, size, "%s", line + strlen(key) + 3);
            out[strcspn(out, "\n")] = 0;
        }
    if (f)
        fclose(f);
}

static const char *rows_dir, *fault_key; /* --rows OUT, --fault KEY FACTOR; else NULL */
static double fault_factor;

static FILE *open_out(const char *name, const char *suffix)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s.%s", rows_dir, name, suffix);
    FILE *f = fopen(path, "w");
    if (!f) {
        fprintf(stderr, "cannot write %s\n", path);
        exit(2);
    }
    return f;
}

static int replay(const char *dir, const char *name, double limit)
{
    char path[1024], reason[160], status[64], monitor[64], samples[32];
    const char *statuses[] = {"completed", "aborted", "no-motion"};
    snprintf(path, sizeof path, "%s/%s/description.bin", dir, name);
    long n = slurp(path, raw, sizeof raw);
    uint8_t kind = strstr(name, "plate") ? LAB_PLATE : strstr(name, "valve") ? LAB_VALVE : LAB_DCMOTOR;
    uint8_t io = kind == LAB_PLATE ? 4 : 1;
    if (n < 0 || lab_desc_parse(&desc, raw, (size_t)n, kind, io, io, 1e6, reason, sizeof reason) != 0) {
        printf("%-28s refused: %s\n", name, n < 0 ? "no description.bin" : reason);
        return 1;
    }
    if (fault_key && lab_desc_fault(&desc, fault_key, fault_factor) != 0) {
        printf("%-28s has no LAW constant %s\n", name, fault_key);
        return 1;
    }
    snprintf(path, sizeof path, "%s/%s/vector.csv", dir, name);
    int rows = csv(path, desc.n_columns);
    lab_real y[LAB_MAX_IO], u[LAB_MAX_IO], row[LAB_MAX_COLUMNS];
    lab_trip trip;
    double scale[LAB_MAX_COLUMNS] = {0}, worst = 0;
    unsigned worst_col = 0;
    int tripped = 0, got = 0, worst_row = 0;
    FILE *out = rows_dir ? open_out(name, "csv") : NULL;
    for (int k = 0; k < rows; k++)
        for (unsigned c = 0; c < desc.n_columns; c++)
            if (isfinite(want[k][c + 1]) && fabs(want[k][c + 1]) > scale[c])
                scale[c] = fabs(want[k][c + 1]);
    for (uint32_t k = 0; k < desc.ticks && !tripped; k++, got++) {
        lab_desc_table_row(&desc, k, y);
        if (k == 0)
            lab_loop_init(&loop, &desc, y);
        tripped = lab_loop_tick(&loop, y, row, u, &trip);
        for (unsigned c = 0; out && c < desc.n_columns; c++)
            fprintf(out, "%.17g%c", (double)row[c], c + 1 < desc.n_columns ? ',' : '\n');
        for (unsigned c = 0; c < desc.n_columns && got < rows; c++) {
            double w = want[got][c + 1], err = fabs((double)row[c] - w) / (fabs(w) + scale[c] + 1e-300);
            if (isnan(w) != isnan((double)row[c]))
                err = INFINITY;
            if (isnan(w))
                continue;
            if (err > worst) {
                worst = err;
                worst_col = c;
                worst_row = got;
            }
        }
    }
    snprintf(path, sizeof path, "%s/%s/verdict.txt", dir, name);
    verdict_value(path, "status", status, sizeof status);
    verdict_value(path, "monitor", monitor, sizeof monitor);
    verdict_value(path, "samples", samples, sizeof samples);
    const char *mine = tripped ? "aborted" : statuses[lab_loop_moved(&loop) ? 0 : 2];
    if (out) {
        fclose(out);
        out = open_out(name, "verdict");
        fprintf(out, "%s %s %.17g %.17g %.17g\n", mine, tripped ? trip.monitor : "-", tripped ? trip.time : NAN,
                tripped ? trip.value : NAN, tripped ? trip.threshold : NAN);
        fclose(out);
    }
    int verdict_ok = strcmp(mine, status) == 0 && got == atoi(samples) && got == rows &&
                     (!tripped || strcmp(trip.monitor, monitor) == 0);
    int ok = verdict_ok && worst <= limit;
    printf("%-28s %s %d ticks, %s%s%s, max error %.3g (column %u, tick %d)%s\n", name, ok ? "ok  " : "FAIL", got, mine,
           tripped ? " " : "", tripped ? trip.monitor : "", worst, worst_col, worst_row,
           verdict_ok ? "" : " -- verdict differs from verdict.txt");
    return !ok;
}

int main(int argc, char **argv)
{
    for (;;)
        if (argc > 2 && strcmp(argv[1], "--rows") == 0) {
            rows_dir = argv[2];
            argv += 2;
            argc -= 2;
        } else if (argc > 3 && strcmp(argv[1], "--fault") == 0) {
            fault_key = argv[2];
            fault_factor = strtod(argv[3], NULL);
            argv += 3;
            argc -= 3;
        } else
            break;
    if (argc < 4) {
        fprintf(stderr, "usage: vectors [--rows OUT] [--fault KEY FACTOR] DOCS_VECTORS_DIR LIMIT CASE...\n");
        return 2;
    }
    double limit = strtod(argv[2], NULL);
    int failed = 0;
    printf("arithmetic: %s\n", sizeof(lab_real) == sizeof(float) ? "float32" : "float64");
    for (int i = 3; i < argc; i++)
        failed += replay(argv[1], argv[i], limit);
    return failed ? 1 : 0;
}
