/* Bulk transfer: blocks in indexed frames, ACK/NACK, resends and the send window
 * (docs/device-loop.md § Bulk transfer, § Blocks). Static memory: the sender keeps its blocks,
 * encoded, in a byte ring until they are acknowledged. */
#ifndef LAB_STREAM_H
#define LAB_STREAM_H
#include "protocol.h"

#define LAB_BLOCK_HEAD 10u   /* seq u32, transfer u16, kind u8, flags u8, length u16 */
#define LAB_BLOCK_EXTRA 14u  /* head and CRC-32 */
#define LAB_FLAG_LAST 0x01u
enum { LAB_B_DESCRIPTION = 1, LAB_B_ACCEPT, LAB_B_REJECT, LAB_B_PROGRESS, LAB_B_SAMPLES, LAB_B_VERDICT };
enum { LAB_ACK_OK = 1, LAB_NACK = 2, LAB_CANCEL = 3 };

#ifndef LAB_BLOCK_RING
#define LAB_BLOCK_RING (1u << 20) /* bytes of encoded blocks waiting for their ACK */
#endif
#ifndef LAB_BLOCK_SLOTS
#define LAB_BLOCK_SLOTS 512u
#endif
#define LAB_WINDOW_BYTES 32768u

typedef void (*lab_send_fn)(void *ctx, const uint8_t *payload, uint8_t len);

typedef struct {
    uint32_t at, len;          /* where the encoded block lies in the ring */
    uint64_t sent_us, resent_us;
    uint8_t sent;
} lab_slot;

/* One stream's sending end (the device's results). */
typedef struct {
    lab_send_fn send;
    void *ctx;
    uint8_t max_payload;
    uint16_t transfer;
    uint32_t next_seq, acked, sent_upto, recovered, advertised, window, resent;
    double cwnd;
    uint64_t progress_us;       /* when the oldest pending block was last acknowledged or resent (0: not yet) */
    int progress_set, cancelled;
    uint32_t nacked[16];
    unsigned n_nacked;
    uint32_t head, tail;        /* ring bytes in use: [tail, head) modulo wrap */
    lab_slot slots[LAB_BLOCK_SLOTS];
    uint8_t ring[LAB_BLOCK_RING];
} lab_sender;

void lab_sender_init(lab_sender *s, lab_send_fn send, void *ctx, uint8_t max_payload, uint16_t transfer);
/* Largest body a block of this link carries (64 frames, 4 KiB, LAB_BLOCK_BODY). */
uint32_t lab_sender_body_limit(const lab_sender *s);
/* Whether a block of this body size fits in the ring and the slots now. */
int lab_sender_room(const lab_sender *s, uint32_t body_len);
/* Queue one block; -1 if there is no room. */
int lab_sender_queue(lab_sender *s, uint8_t kind, uint8_t flags, const uint8_t *body, uint32_t len);
/* Take a BULK_ACK payload (ignored unless it is for this stream). */
void lab_sender_ack(lab_sender *s, const uint8_t *payload, uint8_t len);
/* Send NACKed blocks, then new and overdue ones within the window. */
void lab_sender_pump(lab_sender *s, uint64_t now_us);
/* Blocks queued but not yet acknowledged. */
static inline uint32_t lab_sender_pending(const lab_sender *s) { return s->next_seq - s->acked; }

/* The receiving end of the host's stream (the description): delivers blocks in order, ACKs them,
 * NACKs broken blocks and gaps; a seq-0 block of a transfer it has not run starts a new one. */
typedef struct {
    lab_send_fn send_ack;
    void *ctx;
    int have_transfer, follow;   /* follow: a new transfer may start now */
    uint16_t transfer, done[16];
    unsigned n_done;
    uint32_t expected;
    uint32_t frames, blocks, crc_errors, broken, duplicates, foreign, nacks;
    uint64_t gap_nack_us;
    int gap_open;
    int next_index;              /* frame index expected next, -1: waiting for a block's start */
    uint32_t have, need;
    uint8_t buf[LAB_BLOCK_EXTRA + 4096 + LAB_MAX_PAYLOAD];
} lab_receiver;

typedef struct {
    uint32_t seq;
    uint16_t transfer;
    uint8_t kind, flags;
    const uint8_t *body;
    uint16_t len;
} lab_block;

void lab_receiver_init(lab_receiver *r, lab_send_fn send_ack, void *ctx);
/* Feed one frame; returns 1 with *b set (valid until the next call) when a block is delivered in order. */
int lab_receiver_feed(lab_receiver *r, const uint8_t *payload, uint8_t len, uint64_t now_us, lab_block *b);
/* Remember a transfer that ran: a late resend of its description never runs again. */
void lab_receiver_done(lab_receiver *r, uint16_t transfer);

#endif
