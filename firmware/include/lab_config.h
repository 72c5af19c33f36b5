/* Build options of the device core: the arithmetic type and the static buffer sizes.
 * Override with -D at build time (the Makefile sets them per target). */
#ifndef LAB_CONFIG_H
#define LAB_CONFIG_H

#include <stdint.h>
#include <stddef.h>

/* lab_real: the law's arithmetic. -DLAB_FLOAT32 builds the core in float (a Cortex-M4F's FPU is
 * single precision); the default is double, as docs/control-laws.md's reference computes. */
#ifdef LAB_FLOAT32
typedef float lab_real;
#define LAB_SQRT sqrtf
#define LAB_SIN sinf
#define LAB_COS cosf
#define LAB_FABS fabsf
#define LAB_FLOAT32_CAP 1u
#else
typedef double lab_real;
#define LAB_SQRT sqrt
#define LAB_SIN sin
#define LAB_COS cos
#define LAB_FABS fabs
#define LAB_FLOAT32_CAP 0u
#endif

#ifndef LAB_MAX_FIR
#define LAB_MAX_FIR 512 /* taps of one FIR (the plate's 32 kHz MFC uses 261) */
#endif
#ifndef LAB_DESC_BYTES
#define LAB_DESC_BYTES (1u << 21) /* largest run description the device takes */
#endif
#ifndef LAB_STORE_BYTES
#define LAB_STORE_BYTES (1u << 26) /* result blocks held until the host acknowledges them */
#endif
#ifndef LAB_BLOCK_BODY
#define LAB_BLOCK_BODY 4032 /* largest block body the device makes (docs: 64 frames, 4 KiB) */
#endif
#ifndef LAB_STORE_SLOTS
#define LAB_STORE_SLOTS 4096 /* blocks held at once */
#endif

#define LAB_MAX_IO 4         /* inputs and outputs of a device kind (the plate: 4 and 4) */
#define LAB_MAX_CTRL 3       /* controlled outputs (the plate: y1..y3) */
#define LAB_MAX_COLUMNS 24   /* logged columns per tick (the plate MFC: 20) */
#define LAB_MAX_FSTATES 16   /* states of one FILTER (the plate MBC's chain: 14) */
#define LAB_MAX_FIN 2        /* inputs of one FILTER */
#define LAB_MAX_FOUT 3       /* outputs of one FILTER */
#define LAB_MAX_PAYLOAD 64   /* link payload (serial and CAN FD) */

#endif
