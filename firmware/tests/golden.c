/* Golden frames: decodes what the Python side wrote and encodes it back (docs/protocol.md § Serial
 * framing; docs/device-loop.md § Bulk transfer, § Run description). Reads lines from stdin:
 *   frame WIREHEX                       -> frame NODE CODE PAYLOADHEX WIREHEX (re-encoded)
 *   block MAXPAYLOAD FRAMEHEX,FRAMEHEX  -> block SEQ TRANSFER KIND FLAGS BODYHEX FRAMEHEX,... (re-sent)
 *   desc KIND NIN NOUT HEX              -> desc ok KIND FS TICKS COLUMNS ... | desc reject REASON
 * and writes one line per input for tests/test_firmware_golden.py to compare with the Python modules. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "description.h"
#include "frame.h"
#include "stream.h"

static uint8_t bytes[1 << 21];
static char line[1 << 23];
static lab_receiver rx;
static lab_sender tx;
static lab_desc desc;

static size_t unhex(const char *s, uint8_t *out)
{
    size_t n = 0;
    while (s[0] && s[1] && s[0] != ',' && s[0] != '\n' && s[0] != ' ') {
        unsigned v;
        sscanf(s, "%2x", &v);
        out[n++] = (uint8_t)v;
        s += 2;
    }
    return n;
}

static void hex(const uint8_t *p, size_t n)
{
    for (size_t i = 0; i < n; i++)
        printf("%02x", p[i]);
}

static void ignore(void *ctx, const uint8_t *p, uint8_t n) { (void)ctx, (void)p, (void)n; }

static void print_frame(void *ctx, const uint8_t *p, uint8_t n)
{
    int *first = ctx;
    printf(*first ? " " : ",");
    *first = 0;
    hex(p, n);
}

static void frame(const char *arg)
{
    lab_serial_decoder d;
    lab_frame f;
    uint8_t node, wire[LAB_SERIAL_MAX_WIRE];
    size_t n = unhex(arg, bytes);
    int got = 0;
    lab_serial_init(&d);
    for (size_t i = 0; i < n; i++)
        got |= lab_serial_feed(&d, bytes[i], &node, &f);
    if (!got) {
        printf("frame none %u %u\n", (unsigned)d.malformed, (unsigned)d.crc_errors);
        return;
    }
    printf("frame %u %u ", node, f.code);
    hex(f.payload, f.len);
    printf(" ");
    hex(wire, lab_serial_encode(node, &f, wire));
    printf("\n");
}

static void block(char *arg)
{
    int max_payload = (int)strtol(arg, &arg, 10), first = 1;
    lab_block b;
    int got = 0;
    lab_receiver_init(&rx, ignore, NULL);
    for (char *p = arg + 1; *p && *p != '\n'; p += *p == ',') {
        size_t n = unhex(p, bytes);
        p += 2 * n;
        got = lab_receiver_feed(&rx, bytes, (uint8_t)n, 0, &b);
    }
    if (!got) {
        printf("block none %u %u\n", (unsigned)rx.crc_errors, (unsigned)rx.broken);
        return;
    }
    printf("block %u %u %u %u ", (unsigned)b.seq, b.transfer, b.kind, b.flags);
    hex(b.body, b.len);
    lab_sender_init(&tx, print_frame, &first, (uint8_t)max_payload, b.transfer);
    memcpy(bytes, b.body, b.len);
    lab_sender_queue(&tx, b.kind, b.flags, bytes, b.len);
    lab_sender_pump(&tx, 1);
    printf("\n");
}

static void description(char *arg)
{
    char reason[200];
    int kind = (int)strtol(arg, &arg, 10), n_in = (int)strtol(arg, &arg, 10), n_out = (int)strtol(arg, &arg, 10);
    size_t n = unhex(arg + 1, bytes);
    if (lab_desc_parse(&desc, bytes, n, (uint8_t)kind, (uint8_t)n_in, (uint8_t)n_out, 1e6, reason, sizeof reason) != 0) {
        printf("desc reject %s\n", reason);
        return;
    }
    printf("desc ok %d %.17g %.17g %u %u %.17g %u %u %u %u %u %u %d %u %u %u\n", desc.kind, desc.fs, desc.duration,
           (unsigned)desc.ticks, (unsigned)desc.seed, desc.watchdog_s, desc.n_columns, desc.stream, desc.n_traj,
           (unsigned)desc.fir_len[0], (unsigned)desc.fir_len[1], (unsigned)desc.table_rows, desc.have_rate,
           desc.notch.have ? desc.notch.n : 0, desc.chain.have ? desc.chain.n : 0, desc.motion_out);
}

int main(void)
{
    while (fgets(line, sizeof line, stdin)) {
        if (strncmp(line, "frame ", 6) == 0)
            frame(line + 6);
        else if (strncmp(line, "block ", 6) == 0)
            block(line + 6);
        else if (strncmp(line, "desc ", 5) == 0)
            description(line + 5);
        else
            printf("unknown\n");
        fflush(stdout);
    }
    return 0;
}
