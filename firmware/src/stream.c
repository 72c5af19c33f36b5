/* docs/device-loop.md § Bulk transfer: blocks, frames, BULK_ACK, the sender's window and resends. */
#include <string.h>
#include "stream.h"
#include "crc.h"

#define RETRY_US 500000u  /* nothing acknowledged for this long: the oldest block again */
#define NACK_US 200000u   /* an open gap is NACKed again after this long */
#define FROM_DEVICE 1u    /* ACK direction bit: the device -> host stream */

void lab_sender_init(lab_sender *s, lab_send_fn send, void *ctx, uint8_t max_payload, uint16_t transfer)
{
    memset(s, 0, offsetof(lab_sender, slots));
    s->send = send;
    s->ctx = ctx;
    s->max_payload = max_payload;
    s->transfer = transfer;
    s->advertised = 1u << 16;
    uint32_t w = LAB_WINDOW_BYTES / (lab_sender_body_limit(s) + LAB_BLOCK_EXTRA);
    s->window = w < 2 ? 2 : w;
    if (s->window > LAB_BLOCK_SLOTS / 2)
        s->window = LAB_BLOCK_SLOTS / 2;
    s->cwnd = s->window;
}

uint32_t lab_sender_body_limit(const lab_sender *s)
{
    uint32_t bytes = 64u * (s->max_payload - 1u);
    if (bytes > 4096u)
        bytes = 4096u;
    bytes -= LAB_BLOCK_EXTRA;
    return bytes < LAB_BLOCK_BODY ? bytes : LAB_BLOCK_BODY;
}

/* Where a block of n encoded bytes goes in the ring, or -1 (kept contiguous: it wraps whole). */
static long ring_place(const lab_sender *s, uint32_t n)
{
    if (lab_sender_pending(s) >= LAB_BLOCK_SLOTS)
        return -1;
    if (lab_sender_pending(s) == 0)
        return n <= LAB_BLOCK_RING ? 0 : -1;
    if (s->head >= s->tail) {
        if (LAB_BLOCK_RING - s->head >= n)
            return s->head;
        return s->tail > n ? 0 : -1;
    }
    return s->tail - s->head > n ? (long)s->head : -1;
}

int lab_sender_room(const lab_sender *s, uint32_t body_len)
{
    return ring_place(s, body_len + LAB_BLOCK_EXTRA) >= 0;
}

int lab_sender_queue(lab_sender *s, uint8_t kind, uint8_t flags, const uint8_t *body, uint32_t len)
{
    uint32_t total = len, n = total + LAB_BLOCK_EXTRA;
    long at = ring_place(s, n);
    if (at < 0 || total > lab_sender_body_limit(s))
        return -1;
    if (lab_sender_pending(s) == 0)
        s->tail = 0;
    uint8_t *p = s->ring + at;
    lab_put32(p, s->next_seq);
    lab_put16(p + 4, s->transfer);
    p[6] = kind;
    p[7] = flags;
    lab_put16(p + 8, (uint16_t)total);
    if (len)
        memcpy(p + LAB_BLOCK_HEAD, body, len);
    lab_put32(p + LAB_BLOCK_HEAD + total, lab_crc32(0, p, LAB_BLOCK_HEAD + total));
    lab_slot *slot = &s->slots[s->next_seq % LAB_BLOCK_SLOTS];
    slot->at = (uint32_t)at;
    slot->len = n;
    slot->sent = 0;
    slot->sent_us = slot->resent_us = 0;
    s->head = (uint32_t)at + n;
    s->next_seq++;
    return 0;
}

static void release(lab_sender *s, uint32_t upto)
{
    s->acked = upto;
    if (lab_sender_pending(s) == 0)
        s->head = s->tail = 0;
    else
        s->tail = s->slots[s->acked % LAB_BLOCK_SLOTS].at;
}

void lab_sender_ack(lab_sender *s, const uint8_t *p, uint8_t len)
{
    if (len < 8)
        return;
    uint8_t code = p[0] & 0x7Fu, window = p[1];
    uint32_t seq = lab_get32(p + 4);
    if ((p[0] >> 7) != FROM_DEVICE || lab_get16(p + 2) != s->transfer)
        return;
    if (code == LAB_CANCEL) {
        s->cancelled = 1;
    } else if (code == LAB_ACK_OK && seq > s->acked) {
        uint32_t upto = seq < s->next_seq ? seq : s->next_seq, fresh = upto - s->acked;
        release(s, upto);
        s->advertised = window ? window : 1;
        s->cwnd = s->cwnd + fresh < s->window ? s->cwnd + fresh : s->window;
        s->progress_set = 0;
    } else if (code == LAB_NACK && seq >= s->acked && seq < s->next_seq) {
        for (unsigned i = 0; i < s->n_nacked; i++)
            if (s->nacked[i] == seq)
                return;
        if (s->n_nacked < sizeof s->nacked / sizeof s->nacked[0])
            s->nacked[s->n_nacked++] = seq;
        if (seq >= s->recovered) { /* one loss event per window in flight (NewReno's recovery point) */
            s->cwnd = s->cwnd / 2 > 1 ? s->cwnd / 2 : 1;
            s->recovered = s->sent_upto;
        }
    }
}

static void send_block(lab_sender *s, uint32_t seq, uint64_t now)
{
    lab_slot *slot = &s->slots[seq % LAB_BLOCK_SLOTS];
    const uint8_t *raw = s->ring + slot->at;
    uint8_t frame[LAB_MAX_PAYLOAD], step = (uint8_t)(s->max_payload - 1u);
    for (uint32_t i = 0, at = 0; at < slot->len; i++, at += step) {
        uint32_t n = slot->len - at < step ? slot->len - at : step;
        frame[0] = (uint8_t)i;
        memcpy(frame + 1, raw + at, n);
        s->send(s->ctx, frame, (uint8_t)(n + 1));
    }
    slot->sent = 1;
    slot->sent_us = now;
    if (seq + 1 > s->sent_upto)
        s->sent_upto = seq + 1;
}

void lab_sender_pump(lab_sender *s, uint64_t now)
{
    while (s->n_nacked) {
        uint32_t seq = s->nacked[0];
        memmove(s->nacked, s->nacked + 1, --s->n_nacked * sizeof s->nacked[0]);
        lab_slot *slot = &s->slots[seq % LAB_BLOCK_SLOTS];
        if (seq >= s->acked && seq < s->next_seq && now - slot->resent_us >= RETRY_US / 4) {
            slot->resent_us = now;
            send_block(s, seq, now);
            s->resent++;
        }
    }
    if (lab_sender_pending(s) && s->slots[s->acked % LAB_BLOCK_SLOTS].sent) {
        if (!s->progress_set) {
            s->progress_us = now;
            s->progress_set = 1;
        } else if (now - s->progress_us >= RETRY_US) { /* a timeout: the oldest again, the window one block */
            send_block(s, s->acked, now);
            s->resent++;
            s->progress_us = now;
            s->cwnd = 1;
        }
    }
    uint32_t room = (uint32_t)s->cwnd < s->advertised ? (uint32_t)s->cwnd : s->advertised;
    uint32_t end = s->acked + room < s->next_seq ? s->acked + room : s->next_seq;
    for (uint32_t seq = s->acked; seq < end; seq++)
        if (!s->slots[seq % LAB_BLOCK_SLOTS].sent)
            send_block(s, seq, now);
}

/* ---- receiver ---- */

void lab_receiver_init(lab_receiver *r, lab_send_fn send_ack, void *ctx)
{
    memset(r, 0, offsetof(lab_receiver, buf));
    r->send_ack = send_ack;
    r->ctx = ctx;
    r->next_index = -1;
    r->follow = 1;
}

static void ack(lab_receiver *r, uint8_t code, uint32_t seq)
{
    uint8_t p[8];
    if (!r->have_transfer)
        return;
    p[0] = code;     /* direction bit 0: the host -> device stream */
    p[1] = 1;        /* window: only the next block is taken (no buffer for blocks out of order) */
    lab_put16(p + 2, r->transfer);
    lab_put32(p + 4, seq);
    r->send_ack(r->ctx, p, 8);
}

static void nack(lab_receiver *r, uint32_t seq, uint64_t now)
{
    if (r->gap_open && now - r->gap_nack_us < NACK_US)
        return;
    r->gap_open = 1;
    r->gap_nack_us = now;
    r->nacks++;
    ack(r, LAB_NACK, seq);
}

void lab_receiver_done(lab_receiver *r, uint16_t transfer)
{
    r->done[r->n_done++ % 16] = transfer;
}

static int ran(const lab_receiver *r, uint16_t transfer)
{
    unsigned n = r->n_done < 16 ? r->n_done : 16;
    for (unsigned i = 0; i < n; i++)
        if (r->done[i] == transfer)
            return 1;
    return 0;
}

/* The block in progress lost a frame: ask at once when its header had arrived and it is the one expected. */
static void broken(lab_receiver *r, uint64_t now)
{
    r->broken++;
    if (r->need && r->have_transfer && lab_get16(r->buf + 4) == r->transfer && lab_get32(r->buf) == r->expected)
        nack(r, r->expected, now);
}

static int block(lab_receiver *r, uint64_t now, lab_block *b)
{
    const uint8_t *raw = r->buf;
    uint32_t n = r->need;
    if (lab_crc32(0, raw, n - 4) != lab_get32(raw + n - 4)) {
        r->crc_errors++;
        return 0;
    }
    r->blocks++;
    b->seq = lab_get32(raw);
    b->transfer = lab_get16(raw + 4);
    b->kind = raw[6];
    b->flags = raw[7];
    b->len = lab_get16(raw + 8);
    b->body = raw + LAB_BLOCK_HEAD;
    if (!r->have_transfer || b->transfer != r->transfer) {
        if (!r->follow || b->seq != 0 || ran(r, b->transfer)) {
            r->foreign++;
            return 0;
        }
        r->have_transfer = 1;
        r->transfer = b->transfer;
        r->expected = 0;
        r->gap_open = 0;
    }
    if (b->seq < r->expected) {
        r->duplicates++;
        ack(r, LAB_ACK_OK, r->expected);
        return 0;
    }
    if (b->seq > r->expected) { /* a gap: this block is dropped, the expected one asked for */
        nack(r, r->expected, now);
        return 0;
    }
    r->expected++;
    r->gap_open = 0;
    ack(r, LAB_ACK_OK, r->expected);
    return 1;
}

int lab_receiver_feed(lab_receiver *r, const uint8_t *p, uint8_t len, uint64_t now, lab_block *b)
{
    r->frames++;
    if (len == 0)
        return 0;
    int index = p[0];
    if (index == 0) {
        if (r->next_index > 0)
            broken(r, now);
        r->have = r->need = 0;
        r->next_index = 0;
    } else if (index != r->next_index) {
        if (r->next_index > 0)
            broken(r, now);
        r->next_index = -1;
        return 0;
    }
    if (r->have + len - 1u > sizeof r->buf) {
        r->next_index = -1;
        r->broken++;
        return 0;
    }
    memcpy(r->buf + r->have, p + 1, len - 1u);
    r->have += len - 1u;
    r->next_index = (index + 1) % 256;
    if (!r->need && r->have >= LAB_BLOCK_HEAD) {
        r->need = LAB_BLOCK_EXTRA + lab_get16(r->buf + 8);
        if (r->need > sizeof r->buf - LAB_MAX_PAYLOAD) {
            r->broken++;
            r->next_index = -1;
            r->need = 0;
            return 0;
        }
    }
    if (!r->need || r->have < r->need)
        return 0;
    r->next_index = -1; /* padding after the CRC is ignored */
    return block(r, now, b);
}
