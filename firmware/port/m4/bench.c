/* Instructions per tick of each law on the Cortex-M4F image: every vector named on the semihosting
 * command line runs through lab_loop_tick in its sensor-table mode. Run under QEMU with
 * `-icount shift=0` (one instruction = 1 ns of virtual time), the 25 MHz timer counts 40
 * instructions a count: an estimate (QEMU counts instructions, not the M4's cycles or wait states). */
#include <stdio.h>
#include <string.h>
#include "board.h"
#include "loop.h"

static uint8_t raw[LAB_DESC_BYTES];
static lab_desc desc;
static lab_loop loop;

static uint32_t semihost(uint32_t op, void *args)
{
    register uint32_t r0 __asm("r0") = op;
    register void *r1 __asm("r1") = args;
    __asm volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

static void say(const char *text) { semihost(0x04u, (void *)text); } /* SYS_WRITE0 */

static long load(const char *dir)
{
    char path[256];
    snprintf(path, sizeof path, "%s/description.bin", dir);
    uint32_t open_args[3] = {(uint32_t)path, 1u, (uint32_t)strlen(path)}; /* "rb" */
    uint32_t handle = semihost(0x01u, open_args);
    if (handle == 0xFFFFFFFFu)
        return -1;
    uint32_t flen_args[1] = {handle};
    uint32_t n = semihost(0x0Cu, flen_args);
    uint32_t read_args[3] = {handle, (uint32_t)raw, n};
    uint32_t left = n <= sizeof raw ? semihost(0x06u, read_args) : n;
    semihost(0x02u, flen_args);
    return left == 0 ? (long)n : -1;
}

static void bench(const char *dir)
{
    char line[200], reason[160];
    const char *name = strrchr(dir, '/') ? strrchr(dir, '/') + 1 : dir;
    uint8_t kind = strstr(name, "plate") ? LAB_PLATE : strstr(name, "valve") ? LAB_VALVE : LAB_DCMOTOR;
    uint8_t io = kind == LAB_PLATE ? 4 : 1;
    long n = load(dir);
    if (n < 0 || lab_desc_parse(&desc, raw, (size_t)n, kind, io, io, 1e6, reason, sizeof reason) != 0) {
        snprintf(line, sizeof line, "%-28s not run: %s\n", name, n < 0 ? "no description.bin that fits" : reason);
        say(line);
        return;
    }
    lab_real y[LAB_MAX_IO], u[LAB_MAX_IO], row[LAB_MAX_COLUMNS];
    lab_trip trip;
    uint64_t total = 0, worst = 0;
    uint32_t k = 0;
    for (int tripped = 0; k < desc.ticks && !tripped; k++) {
        lab_desc_table_row(&desc, k, y);
        if (k == 0)
            lab_loop_init(&loop, &desc, y);
        uint64_t t0 = board_ticks();
        tripped = lab_loop_tick(&loop, y, row, u, &trip);
        uint64_t dt = board_ticks() - t0;
        total += dt;
        worst = dt > worst ? dt : worst;
    }
    unsigned long per = (unsigned long)(total * (1000000000u / BOARD_CLOCK_HZ) / k);
    snprintf(line, sizeof line, "%-28s %s %5lu insn/tick (max %lu) over %lu ticks, FIR %lu taps, f_s %lu Hz\n", name,
             sizeof(lab_real) == 4 ? "float32" : "float64", per,
             (unsigned long)(worst * (1000000000u / BOARD_CLOCK_HZ)), (unsigned long)k, (unsigned long)desc.fir_len[0],
             (unsigned long)desc.fs);
    say(line);
}

int main(void)
{
    static char cmdline[2048];
    uint32_t args[2] = {(uint32_t)cmdline, sizeof cmdline - 1};
    board_init();
    if (semihost(0x15u, args) != 0) { /* SYS_GET_CMDLINE */
        say("bench: no command line (QEMU -semihosting-config arg=...)\n");
        board_exit(2);
    }
    for (char *word = cmdline, *end; *word; word = end) { /* the first word is the program */
        for (end = word; *end && *end != ' '; end++) {
        }
        if (*end)
            *end++ = 0;
        if (word != cmdline)
            bench(word);
    }
    board_exit(0);
    return 0;
}
