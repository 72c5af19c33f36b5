/* docs/protocol.md § Handshake, § Host loop; docs/device-loop.md § A run, § Protocol decisions. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "device.h"
#include "port.h"

#define STATUS_PERIOD_US 100000u    /* STATUS while a host-loop run runs */
#define PROGRESS_US 250000u         /* PROGRESS while a device-loop run runs */
#define HELD_UP_US 1000u            /* the loop woke this much late: held up, not host silence */
#define UPLOAD_SILENCE_US 10000000u /* results kept this long for a silent host */

static const struct { uint8_t n_in, n_out; double min_fs, max_fs; } KINDS[4] = {
    {0, 0, 0, 0}, {1, 1, 10.0, 10000.0}, {1, 1, 500.0, 20000.0}, {4, 4, 1000.0, 100000.0}};

static void send(lab_device *dev, uint8_t code, const uint8_t *payload, uint8_t len)
{
    lab_frame f;
    (void)dev;
    f.code = code;
    f.len = len;
    memcpy(f.payload, payload, len);
    lab_port_send(&f);
}

static void send_bulk(void *ctx, const uint8_t *payload, uint8_t len) { send(ctx, LAB_BULK_TO_HOST, payload, len); }
static void send_ack(void *ctx, const uint8_t *payload, uint8_t len) { send(ctx, LAB_BULK_ACK_DEVICE, payload, len); }

void lab_device_init(lab_device *dev, uint8_t kind, uint8_t max_payload, int can_fd, int has_plant, uint32_t firmware_id)
{
    memset(dev, 0, offsetof(lab_device, block));
    dev->kind = kind;
    dev->n_in = KINDS[kind].n_in;
    dev->n_out = KINDS[kind].n_out;
    dev->min_fs = KINDS[kind].min_fs;
    dev->max_fs = KINDS[kind].max_fs;
    dev->max_payload = max_payload;
    dev->firmware_id = firmware_id;
    dev->capabilities = LAB_CAP_DEVICE_LOOP | (has_plant ? LAB_CAP_HOST_LOOP : 0) | (can_fd ? LAB_CAP_CAN_FD : 0) |
                        (LAB_FLOAT32_CAP ? LAB_CAP_FLOAT32 : 0);
    dev->fault_factor = 1.0;
    dev->watchdog_s = INFINITY;
    dev->last_rx_us = dev->last_status_us = lab_port_now_us();
    lab_receiver_init(&dev->rx, send_ack, dev);
    lab_sender_init(&dev->tx, send_bulk, dev, max_payload, 0);
}

/* ---- the core's answers (docs/protocol.md § Messages) ---- */

static void send_error(lab_device *dev, uint8_t code, float detail, int go_safe)
{
    uint8_t p[8] = {code, 0};
    if (go_safe && dev->state == LAB_RUNNING) {
        lab_port_safe();
        dev->state = LAB_SAFE_STATE;
    }
    dev->last_error = code;
    lab_put16(p + 2, (uint16_t)dev->seq);
    lab_putf32(p + 4, detail);
    send(dev, LAB_ERROR, p, 8);
}

static uint16_t sat16(uint32_t v) { return v > 0xFFFFu ? 0xFFFFu : (uint16_t)v; }

static void send_status(lab_device *dev)
{
    uint8_t p[8] = {dev->state, dev->last_error};
    lab_put16(p + 2, sat16(dev->rejected));
    lab_put16(p + 4, sat16(dev->late));
    lab_put16(p + 6, (uint16_t)dev->seq);
    send(dev, LAB_STATUS, p, 8);
    dev->last_status_us = lab_port_now_us();
}

static void identity(lab_device *dev)
{
    uint8_t p[4][8] = {{0}};
    for (uint8_t i = 0; i < 4; i++)
        p[i][0] = i;
    p[0][4] = LAB_PROTOCOL_VERSION;
    p[0][5] = dev->kind;
    p[0][6] = dev->n_in;
    p[0][7] = dev->n_out;
    lab_put32(p[1] + 4, dev->capabilities);
    lab_putf32(p[2] + 4, (float)dev->max_fs);
    lab_put32(p[3] + 4, dev->firmware_id);
    for (int i = 0; i < 4; i++)
        send(dev, LAB_IDENTITY, p[i], 8);
}

/* STOP, or a device-loop description arriving: the safe input, the host loop's clock stopped, idle. */
static void end_run(lab_device *dev)
{
    if (dev->state != LAB_IDLE) {
        lab_port_safe();
        dev->state = LAB_IDLE;
    }
    dev->ticking = 0;
    dev->watchdog_s = INFINITY;
}

/* HELLO, HEARTBEAT, SAFE, STOP: answered in any state, also during a device-loop run. */
static int core_frame(lab_device *dev, const lab_frame *f)
{
    switch (f->code) {
    case LAB_HELLO:
        if (f->len == 8 && f->payload[0] != LAB_PROTOCOL_VERSION)
            send_error(dev, LAB_E_VERSION, LAB_PROTOCOL_VERSION, 0);
        identity(dev);
        return 1;
    case LAB_HEARTBEAT:
        send_status(dev);
        return 1;
    case LAB_SAFE:
        if (dev->state == LAB_RUNNING) {
            lab_port_safe();
            dev->state = LAB_SAFE_STATE;
        }
        send_status(dev);
        return 1;
    case LAB_STOP:
        end_run(dev);
        send_status(dev);
        return 1;
    default:
        return 0;
    }
}

/* ---- host loop (docs/protocol.md § Host loop) ---- */

static void send_tick(lab_device *dev, const lab_real *y, uint8_t flags, uint32_t stamp_us)
{
    uint8_t p[8];
    lab_put16(p, (uint16_t)dev->k);
    p[3] = 0;
    for (uint8_t ch = 0; ch < dev->n_out; ch++) {
        p[2] = ch;
        lab_putf32(p + 4, (float)y[ch]);
        send(dev, LAB_MEASUREMENT, p, 8);
    }
    p[2] = LAB_TICK_CHANNEL;
    p[3] = flags;
    lab_put32(p + 4, stamp_us);
    send(dev, LAB_MEASUREMENT, p, 8);
}

static void start_host_loop(lab_device *dev, uint32_t seed)
{
    double fs = dev->setup_fs, watchdog = dev->setup_watchdog;
    lab_real y[LAB_MAX_IO];
    dev->setup_have = 0;
    if (!(fs >= dev->min_fs && fs <= dev->max_fs && watchdog > 0)) {
        send_error(dev, LAB_E_BAD_SETUP, (float)fs, 1);
        return;
    }
    if (!lab_port_begin_run(seed, fs)) {
        send_error(dev, LAB_E_UNSUPPORTED, LAB_SETUP, 0);
        return;
    }
    lab_port_read_sensors(y);
    dev->state = LAB_RUNNING;
    dev->last_error = LAB_E_NONE;
    dev->seq = dev->k = 0;
    dev->ticking = 1;
    dev->watchdog_s = watchdog;
    dev->rejected = dev->late = 0;
    dev->held_us = 0;
    dev->committed = -1;
    dev->got = 0;
    memset(dev->applied, 0, sizeof dev->applied);
    memset(dev->pending, 0, sizeof dev->pending);
    dev->period_us = (uint64_t)llround(1e6 / fs);
    dev->t0_us = dev->last_rx_us = dev->last_status_us = lab_port_now_us();
    dev->next_tick_us = dev->t0_us + dev->period_us;
    send_tick(dev, y, 0, 0);
}

static void on_setup(lab_device *dev, const lab_frame *f)
{
    uint8_t index = f->payload[0];
    if (index == 0)
        dev->setup_fs = lab_getf32(f->payload + 4);
    else if (index == 1)
        dev->setup_watchdog = lab_getf32(f->payload + 4);
    else if (index == 2)
        start_host_loop(dev, lab_get32(f->payload + 4));
    else {
        dev->rejected++;
        send_error(dev, LAB_E_BAD_SETUP, index, 0);
    }
}

static void host_tick(lab_device *dev, uint64_t now)
{
    int late = dev->committed != (int32_t)dev->k;
    int overrun = !dev->free_run && now - dev->next_tick_us > dev->period_us;
    lab_real y[LAB_MAX_IO];
    if (late)
        dev->late++;
    else
        memcpy(dev->applied, dev->pending, sizeof dev->applied);
    if (dev->state == LAB_RUNNING)
        lab_port_write_actuators(dev->applied);
    lab_port_read_sensors(y);
    dev->k++;
    dev->seq = dev->k;
    dev->got = 0;
    uint64_t stamp = dev->free_run ? dev->k * dev->period_us : now - dev->t0_us;
    send_tick(dev, y, (uint8_t)((late ? LAB_FLAG_LATE : 0) | (overrun ? LAB_FLAG_OVERRUN : 0)), (uint32_t)stamp);
}

static void on_input(lab_device *dev, const lab_frame *f, uint64_t now)
{
    if (!dev->ticking) {
        dev->rejected++;
        if (dev->state == LAB_IDLE)
            send_error(dev, LAB_E_NOT_RUNNING, 0, 0);
        return;
    }
    uint16_t seq = lab_get16(f->payload), age = (uint16_t)((uint16_t)dev->k - seq);
    uint8_t channel = f->payload[2], flags = f->payload[3];
    if ((age > 0 && age < 0x8000u) || (age == 0 && dev->committed == (int32_t)dev->k)) {
        dev->rejected++; /* late or repeated: dropped */
        return;
    }
    if (age != 0) {
        send_error(dev, LAB_E_SEQUENCE, seq, 1);
        return;
    }
    if (channel >= dev->n_in) {
        send_error(dev, LAB_E_BAD_CHANNEL, channel, 1);
        return;
    }
    dev->pending[channel] = (lab_real)lab_getf32(f->payload + 4);
    dev->got |= (uint8_t)(1u << channel);
    if (flags & LAB_FLAG_COMMIT) {
        if (dev->got == (1u << dev->n_in) - 1u)
            dev->committed = (int32_t)dev->k;
        else
            dev->rejected++; /* a channel of this tick was lost: never a mix of old and new inputs */
        if (dev->free_run && dev->state != LAB_IDLE)
            host_tick(dev, now);
    }
}

/* ---- device loop (docs/device-loop.md) ---- */

static void take_description_frame(lab_device *dev, const lab_frame *f, uint64_t now)
{
    lab_block b;
    if (!lab_receiver_feed(&dev->rx, f->payload, f->len, now, &b) || b.kind != LAB_B_DESCRIPTION)
        return;
    if (b.seq == 0) {
        dev->desc_len = 0;
        dev->desc_overflow = 0;
    }
    if (dev->desc_len + b.len > sizeof dev->desc_buf)
        dev->desc_overflow = 1;
    else
        memcpy(dev->desc_buf + dev->desc_len, b.body, b.len);
    dev->desc_len += b.len;
    if (b.flags & LAB_FLAG_LAST) {
        dev->desc_ready = 1;
        dev->rx.follow = 0; /* no other transfer starts until this one has run */
    }
}

static void queue_block(lab_device *dev, uint8_t kind, uint8_t flags, const uint8_t *body, uint32_t len)
{
    while (lab_sender_queue(&dev->tx, kind, flags, body, len) != 0) { /* wait for room: ACKs free it */
        lab_frame f;
        uint64_t now = lab_port_now_us();
        lab_sender_pump(&dev->tx, now);
        if (lab_port_recv(&f)) {
            dev->last_rx_us = now;
            if (f.code == LAB_BULK_ACK_HOST)
                lab_sender_ack(&dev->tx, f.payload, f.len);
            else
                core_frame(dev, &f);
        } else if (now - dev->last_rx_us > UPLOAD_SILENCE_US || dev->tx.cancelled) {
            return;
        } else {
            lab_port_wait_until(now + 1000);
        }
    }
}

static uint64_t tick_us(uint32_t k, double fs) { return (uint64_t)llround(k * 1e6 / fs); }

/* Wait for t on the port's clock; time the loop was held up beyond that (it came back more than
 * 1 ms later than it asked: a busy machine pausing an emulator, a flash write with interrupts off)
 * is not the host's silence (docs/protocol.md § Host loop, the watchdog). */
static void wait_for(lab_device *dev, uint64_t t)
{
    uint64_t before = lab_port_now_us();
    lab_port_wait_until(t);
    uint64_t after = lab_port_now_us(), asked = t > before ? t - before : 0;
    if (after - before > asked + HELD_UP_US)
        dev->held_us += after - before - asked;
}

/* SAMPLES blocks of the rows logged so far: full blocks, or every row left when final. 0 if the
 * sender had no room for a block that was due. */
static int queue_samples(lab_device *dev, int final)
{
    unsigned cols = dev->desc.n_columns;
    uint32_t per = (lab_sender_body_limit(&dev->tx) - 16u) / (4u * cols);
    if (per > 0xFFFFu)
        per = 0xFFFFu;
    while (dev->ticks_done - dev->queued_upto >= per || (final && dev->ticks_done > dev->queued_upto)) {
        uint32_t n = dev->ticks_done - dev->queued_upto < per ? dev->ticks_done - dev->queued_upto : per;
        uint32_t len = 16u + 4u * n * cols;
        if (!lab_sender_room(&dev->tx, len))
            return 0;
        lab_put32(dev->block, dev->queued_upto);
        lab_put16(dev->block + 4, (uint16_t)n);
        lab_put16(dev->block + 6, (uint16_t)cols);
        lab_put64(dev->block + 8, tick_us(dev->queued_upto, dev->desc.fs));
        for (uint32_t t = 0; t < n; t++) {
            const float *row = dev->rows + (size_t)((dev->queued_upto + t) % dev->row_cap) * cols;
            for (unsigned c = 0; c < cols; c++)
                lab_putf32(dev->block + 16 + 4 * (t * cols + c), row[c]);
        }
        lab_sender_queue(&dev->tx, LAB_B_SAMPLES, 0, dev->block, len);
        dev->queued_upto += n;
    }
    return 1;
}

/* The link during a run or an upload: ACKs, the core's answers, STOP and SAFE, description resends. */
static void service(lab_device *dev)
{
    lab_frame f;
    uint64_t now = lab_port_now_us();
    while (lab_port_recv(&f)) {
        dev->last_rx_us = now;
        dev->held_us = 0;
        if (f.code == LAB_BULK_ACK_HOST)
            lab_sender_ack(&dev->tx, f.payload, f.len);
        else if (f.code == LAB_BULK_TO_DEVICE)
            take_description_frame(dev, &f, now);
        else if (core_frame(dev, &f)) {
            if (f.code == LAB_SAFE || f.code == LAB_STOP)
                dev->stopped = 1;
        } else {
            dev->rejected++;
        }
    }
    lab_sender_pump(&dev->tx, now);
}

typedef struct {
    uint8_t status;                 /* 0 completed, 1 aborted, 2 no-motion, 3 failed */
    lab_trip trip;
    char message[96];
    uint32_t overruns;
    uint64_t compute_ns;
} lab_verdict;

static void queue_verdict(lab_device *dev, const lab_verdict *v)
{
    uint8_t *p = dev->block;
    size_t nm = v->status == 1 ? strlen(v->trip.monitor) : 0, ns = strlen(v->message);
    double nan = NAN;
    p[0] = v->status;
    p[1] = (uint8_t)nm;
    lab_put16(p + 2, (uint16_t)ns);
    lab_put32(p + 4, dev->ticks_done);
    lab_put32(p + 8, dev->ticks_done);
    lab_put32(p + 12, v->overruns);
    lab_putf64(p + 16, v->status == 1 ? v->trip.time : nan);
    lab_putf64(p + 24, v->status == 1 ? v->trip.value : nan);
    lab_putf64(p + 32, v->status == 1 ? v->trip.threshold : nan);
    lab_put64(p + 40, tick_us(dev->ticks_done, dev->desc.fs));
    lab_put64(p + 48, v->compute_ns);
    memcpy(p + 56, v->trip.monitor, nm);
    memcpy(p + 56 + nm, v->message, ns);
    queue_block(dev, LAB_B_VERDICT, LAB_FLAG_LAST, p, (uint32_t)(56 + nm + ns));
}

/* Ticks of the run until the last, a trip, the host's STOP/SAFE, its silence or a full buffer. */
static void run_ticks(lab_device *dev, lab_verdict *v)
{
    const lab_desc *d = &dev->desc;
    lab_real y[LAB_MAX_IO], u[LAB_MAX_IO], row[LAB_MAX_COLUMNS];
    uint64_t period = (uint64_t)llround(1e6 / d->fs), start = lab_port_now_us(), due = start, progress = start;
    for (uint32_t k = 0; k < d->ticks; k++) {
        if (!dev->free_run) { /* tick k at its time; the link is served while waiting */
            for (uint64_t now = lab_port_now_us(); now < due; now = lab_port_now_us()) {
                service(dev);
                if (dev->stopped)
                    break;
                wait_for(dev, due);
            }
            uint64_t now = lab_port_now_us();
            if (now - due > period) { /* an overrun slips the clock */
                v->overruns++;
                due = now;
            }
            due += period;
        }
        service(dev);
        uint64_t now = lab_port_now_us();
        if (dev->stopped || dev->tx.cancelled) {
            snprintf(v->message, sizeof v->message, "stopped by the host");
            v->status = 3;
            return;
        }
        uint64_t heard = dev->last_rx_us + dev->held_us;
        if (now > heard && (double)(now - heard) > d->watchdog_s * 1e6) {
            unsigned long ms = (unsigned long)((now - heard) / 1000u); /* no float printf: none on a board */
            snprintf(v->message, sizeof v->message, "watchdog: no message from the host for %lu.%03lu s", ms / 1000,
                     ms % 1000);
            v->status = 3;
            return;
        }
        if (now - progress >= PROGRESS_US) {
            uint8_t p[12];
            progress = now;
            lab_put32(p, k);
            lab_put64(p + 4, tick_us(k, d->fs));
            queue_block(dev, LAB_B_PROGRESS, 0, p, 12);
        }
        if (d->table)
            lab_desc_table_row(d, k, y);
        else
            lab_port_read_sensors(y);
        if (k == 0)
            lab_loop_init(&dev->loop, d, y);
        uint64_t t0 = lab_port_now_us();
        int tripped = lab_loop_tick(&dev->loop, y, row, u, &v->trip);
        if (!d->table && !tripped) /* a trip: the safe input instead (after the run) */
            lab_port_write_actuators(u);
        v->compute_ns += (lab_port_now_us() - t0) * 1000u;
        float *slot = dev->rows + (size_t)(k % dev->row_cap) * d->n_columns;
        for (unsigned c = 0; c < d->n_columns; c++)
            slot[c] = (float)row[c];
        dev->ticks_done = dev->seq = k + 1;
        if (tripped) {
            v->status = 1;
            return;
        }
        /* stream when asked, or when the rows would fill the buffer before the run ends */
        if ((d->stream || dev->ticks_done - dev->queued_upto > dev->row_cap / 2) && !queue_samples(dev, 0) &&
            dev->ticks_done - dev->queued_upto >= dev->row_cap) {
            snprintf(v->message, sizeof v->message, "the device's sample buffer is full: the link did not carry the samples");
            v->status = 3;
            return;
        }
    }
    v->status = lab_loop_moved(&dev->loop) ? 0 : 2;
    if (v->status == 2)
        snprintf(v->message, sizeof v->message, "the load never moved beyond the sensor resolution");
}

/* Upload every block until the host has acknowledged them all, cancelled, gone silent for 10 s, or
 * sent its next description (docs/device-loop.md § A run). */
static void upload(lab_device *dev, const lab_verdict *v, int with_results)
{
    int verdict_queued = !with_results;
    dev->rx.follow = 1; /* the next description may come once the host holds the verdict */
    while (!dev->tx.cancelled && !dev->desc_ready) {
        if (!verdict_queued && queue_samples(dev, 1) && dev->queued_upto == dev->ticks_done) {
            queue_verdict(dev, v);
            verdict_queued = 1;
        }
        service(dev);
        uint64_t now = lab_port_now_us();
        if (verdict_queued && lab_sender_pending(&dev->tx) == 0)
            return;
        if (now - dev->last_rx_us > UPLOAD_SILENCE_US)
            return; /* the host is gone; the rig is already in its safe state */
        lab_port_wait_until(now + 2000);
    }
}

static void run_description(lab_device *dev)
{
    char reason[160];
    lab_verdict v;
    memset(&v, 0, sizeof v);
    dev->desc_ready = 0;
    end_run(dev); /* a host-loop run set up before ends here */
    lab_receiver_done(&dev->rx, dev->rx.transfer);
    lab_sender_init(&dev->tx, send_bulk, dev, dev->max_payload, dev->rx.transfer);
    dev->stopped = 0;
    dev->ticks_done = dev->queued_upto = dev->seq = 0;
    int ok = !dev->desc_overflow &&
             lab_desc_parse(&dev->desc, dev->desc_buf, dev->desc_len, dev->kind, dev->n_in, dev->n_out, dev->max_fs,
                            reason, sizeof reason) == 0;
    if (dev->desc_overflow)
        snprintf(reason, sizeof reason, "description of %lu bytes is larger than this device's %lu",
                 (unsigned long)dev->desc_len, (unsigned long)sizeof dev->desc_buf);
    if (ok && dev->desc.fs < dev->min_fs) {
        snprintf(reason, sizeof reason, "f_s of %lu Hz is below this device's %lu Hz", (unsigned long)dev->desc.fs,
                 (unsigned long)dev->min_fs);
        ok = 0;
    }
    if (ok && dev->fault_name[0] && lab_desc_fault(&dev->desc, dev->fault_name, dev->fault_factor) != 0) {
        /* a fault on a constant this law lacks changes nothing (as the emulator's --fault-law) */
    }
    if (ok && !dev->desc.table && !lab_port_begin_run(dev->desc.seed, dev->desc.fs)) {
        snprintf(reason, sizeof reason, "this device has no rig attached: only SENSOR_TABLE runs");
        ok = 0;
    }
    if (!ok) {
        queue_block(dev, LAB_B_REJECT, LAB_FLAG_LAST, (const uint8_t *)reason, (uint32_t)strlen(reason));
        upload(dev, &v, 0);
        return;
    }
    dev->row_cap = (uint32_t)(sizeof dev->rows / sizeof dev->rows[0] / dev->desc.n_columns);
    uint8_t accept[6];
    lab_put32(accept, dev->desc.ticks);
    lab_put16(accept + 4, dev->desc.n_columns);
    dev->state = LAB_RUNNING;
    dev->last_rx_us = lab_port_now_us();
    dev->held_us = 0;
    queue_block(dev, LAB_B_ACCEPT, 0, accept, 6);
    run_ticks(dev, &v);
    lab_port_safe();
    dev->state = LAB_IDLE;
    upload(dev, &v, 1);
}

/* ---- the main loop ---- */

static void dispatch(lab_device *dev, const lab_frame *f, uint64_t now)
{
    dev->last_rx_us = now;
    dev->held_us = 0;
    if (core_frame(dev, f))
        return;
    switch (f->code) {
    case LAB_SETUP:
        if (dev->capabilities & LAB_CAP_HOST_LOOP) {
            on_setup(dev, f);
            return;
        }
        break;
    case LAB_INPUT:
        if (dev->capabilities & LAB_CAP_HOST_LOOP) {
            on_input(dev, f, now);
            return;
        }
        break;
    case LAB_BULK_TO_DEVICE:
        take_description_frame(dev, f, now);
        return;
    case LAB_BULK_ACK_HOST:
        lab_sender_ack(&dev->tx, f->payload, f->len);
        return;
    default:
        break;
    }
    dev->rejected++;
    send_error(dev, LAB_E_UNSUPPORTED, f->code, 0);
}

void lab_device_poll(lab_device *dev)
{
    lab_frame f;
    uint64_t now = lab_port_now_us();
    while (lab_port_recv(&f)) /* every waiting frame before the timers judge silence */
        dispatch(dev, &f, now);
    if (dev->desc_ready) {
        run_description(dev);
        return;
    }
    now = lab_port_now_us(); /* the timers judge after every waiting frame was taken */
    lab_sender_pump(&dev->tx, now); /* a REJECT or results still unacknowledged */
    uint64_t wake = now + 10000u, heard = dev->last_rx_us + dev->held_us;
    double silent = now > heard ? (double)(now - heard) * 1e-6 : 0; /* the loop's own hold-ups are no silence */
    if (dev->ticking && !dev->free_run) {
        if (now >= dev->next_tick_us) {
            host_tick(dev, now);
            dev->next_tick_us = now - dev->next_tick_us > dev->period_us ? now + dev->period_us
                                                                          : dev->next_tick_us + dev->period_us;
        }
        wake = dev->next_tick_us < wake ? dev->next_tick_us : wake;
    }
    if (dev->state == LAB_SAFE_STATE && dev->ticking && silent > dev->watchdog_s)
        dev->ticking = 0; /* safe, and nobody listens */
    if (dev->state == LAB_RUNNING) {
        if (silent > dev->watchdog_s)
            send_error(dev, LAB_E_WATCHDOG, (float)silent, 1);
        else if (now >= dev->last_status_us + STATUS_PERIOD_US)
            send_status(dev);
    }
    lab_port_wait_until(wake);
    uint64_t woke = lab_port_now_us();
    if (woke > wake + HELD_UP_US)
        dev->held_us += woke - wake;
}
