/* The device: handshake, host loop, device loop, STOP/SAFE, watchdog, STATUS and PROGRESS
 * (docs/protocol.md, docs/device-loop.md). One lab_device holds all of the firmware's state. */
#ifndef LAB_DEVICE_H
#define LAB_DEVICE_H
#include "loop.h"
#include "stream.h"

#ifndef LAB_ROW_BYTES
#define LAB_ROW_BYTES (1u << 26) /* logged rows (float32) not yet in a SAMPLES block */
#endif

typedef struct {
    /* what the device is (IDENTITY) */
    uint8_t kind, n_in, n_out, max_payload;
    uint32_t capabilities, firmware_id;
    double min_fs, max_fs;
    int free_run;                     /* tick as fast as the law computes (a host-build option, not firmware) */
    char fault_name[16];              /* --fault-law: LAW constant x factor */
    double fault_factor;
    /* protocol state */
    uint8_t state, last_error;
    uint32_t rejected, late, seq;
    uint64_t last_rx_us, last_status_us, held_us;
    double watchdog_s;
    /* host loop (docs/protocol.md § Host loop) */
    int ticking;
    uint8_t setup_have;
    float setup_fs, setup_watchdog;
    uint64_t t0_us, next_tick_us, period_us;
    uint32_t k;
    int32_t committed;
    uint8_t got;
    lab_real pending[LAB_MAX_IO], applied[LAB_MAX_IO];
    /* device loop (docs/device-loop.md) */
    lab_receiver rx;
    lab_sender tx;
    int stopped;                      /* the host's STOP or SAFE arrived during the run */
    uint32_t desc_len;
    int desc_ready, desc_overflow;
    lab_desc desc;
    lab_loop loop;
    uint32_t row_cap, queued_upto, ticks_done;
    uint8_t block[LAB_BLOCK_BODY];
    uint8_t desc_buf[LAB_DESC_BYTES];
    float rows[LAB_ROW_BYTES / sizeof(float)];
} lab_device;

/* A device of kind (LAB_DCMOTOR, ...) on a link of max_payload bytes (8 classic CAN, 64 FD and serial);
 * has_plant: whether lab_port_begin_run can run a rig (else only SENSOR_TABLE runs, no host loop). */
void lab_device_init(lab_device *dev, uint8_t kind, uint8_t max_payload, int can_fd, int has_plant, uint32_t firmware_id);
/* One turn of the main loop: every waiting frame, the host loop's clock, the watchdog, STATUS; a
 * complete description runs here (the call returns after its results are acknowledged). */
void lab_device_poll(lab_device *dev);

#endif
