/* The mps2-an386 board as QEMU emulates it: CMSDK UART0 and timer 0, semihosting. */
#ifndef LAB_BOARD_H
#define LAB_BOARD_H
#include <stdint.h>

#define BOARD_CLOCK_HZ 25000000u
void board_init(void);
uint64_t board_ticks(void);            /* the 25 MHz timer, extended to 64 bits */
int board_uart_getc(void);             /* -1 when no byte waits */
void board_uart_putc(uint8_t byte);
void board_exit(int code);
/* Sleep (WFI) for up to us microseconds or until a byte arrives on UART0. */
void board_sleep(uint32_t us);             /* semihosting SYS_EXIT (QEMU -semihosting) */

#endif
