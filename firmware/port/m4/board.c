/* CMSDK APB UART0 (0x40004000) and timer 0 (0x40000000) of the MPS2 AN386, as QEMU models them. */
#include <errno.h>
#include <stddef.h>
#include "board.h"

#define REG(a) (*(volatile uint32_t *)(a))
#define UART_DATA REG(0x40004000u)
#define UART_STATE REG(0x40004004u)
#define UART_CTRL REG(0x40004008u)
#define UART_BAUDDIV REG(0x40004010u)
#define UART_INTCLEAR REG(0x4000400Cu)
#define SYST_CSR REG(0xE000E010u)
#define SYST_RVR REG(0xE000E014u)
#define SYST_CVR REG(0xE000E018u)
#define NVIC_ISER0 REG(0xE000E100u)
#define TIMER_CTRL REG(0x40000000u)
#define TIMER_VALUE REG(0x40000004u)
#define TIMER_RELOAD REG(0x40000008u)

static uint32_t last;
static uint64_t ticks;

void board_init(void)
{
    UART_BAUDDIV = BOARD_CLOCK_HZ / 115200u;
    UART_CTRL = 0x3u | 0x8u; /* TX and RX enabled, the RX interrupt: it ends a board_sleep */
    NVIC_ISER0 = 1u;          /* IRQ 0: UART0 RX */
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

void board_uart_rx_isr(void) { UART_INTCLEAR = 0x2u; /* the byte stays in DATA for board_uart_getc */ }
void board_systick_isr(void) {}

void board_sleep(uint32_t us)
{
    if (UART_STATE & 0x2u)
        return; /* a byte waits */
    uint32_t counts = us * (BOARD_CLOCK_HZ / 1000000u);
    SYST_RVR = counts < 0xFFFFFFu ? (counts > 1u ? counts : 2u) : 0xFFFFFFu;
    SYST_CVR = 0;
    SYST_CSR = 0x7u; /* processor clock, interrupt, enabled */
    __asm volatile("wfi");
    SYST_CSR = 0;
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
