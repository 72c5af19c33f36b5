/* CMSDK APB UART0 (0x40004000) and timer 0 (0x40000000) of the MPS2 AN386, as QEMU models them. */
#include <errno.h>
#include <stddef.h>
#include "board.h"

#define REG(a) (*(volatile uint32_t *)(a))
#define UART_DATA REG(0x40004000u)
#define UART_STATE REG(0x40004004u)
#define UART_CTRL REG(0x40004008u)
#define UART_BAUDDIV REG(0x40004010u)
#define TIMER_CTRL REG(0x40000000u)
#define TIMER_VALUE REG(0x40000004u)
#define TIMER_RELOAD REG(0x40000008u)

static uint32_t last;
static uint64_t ticks;

void board_init(void)
{
    UART_BAUDDIV = BOARD_CLOCK_HZ / 115200u;
    UART_CTRL = 0x3u; /* TX and RX enabled */
    TIMER_RELOAD = 0xFFFFFFFFu;
    TIMER_VALUE = 0xFFFFFFFFu;
    TIMER_CTRL = 0x1u;
    last = TIMER_VALUE;
}

uint64_t board_ticks(void) /* called far more often than the 171 s wrap */
{
    uint32_t now = TIMER_VALUE;
    ticks += (uint32_t)(last - now); /* it counts down */
    last = now;
    return ticks;
}

int board_uart_getc(void) { return (UART_STATE & 0x2u) ? (int)(UART_DATA & 0xFFu) : -1; }

void board_uart_putc(uint8_t byte)
{
    while (UART_STATE & 0x1u) {
    }
    UART_DATA = byte;
}

void board_exit(int code)
{
    uint32_t args[2] = {0x20026u, (uint32_t)code}; /* ADP_Stopped_ApplicationExit */
    register uint32_t r0 __asm("r0") = 0x20u;      /* SYS_EXIT_EXTENDED */
    register uint32_t *r1 __asm("r1") = args;
    __asm volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
}

/* No heap: a malloc anywhere (a libc routine that wants one) fails rather than grows. */
void *_sbrk(ptrdiff_t increment);
void *_sbrk(ptrdiff_t increment)
{
    (void)increment;
    errno = ENOMEM;
    return (void *)-1;
}
