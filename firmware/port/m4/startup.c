/* Reset for a Cortex-M4F: copy .data, zero .bss, enable the FPU, call main. */
#include <stdint.h>

extern uint32_t _data_load, _data_start, _data_end, _bss_start, _bss_end, _stack_top;
int main(void);
void reset_handler(void);

static void hang(void)
{
    for (;;) {
    }
}

void board_systick_isr(void);
void board_uart_rx_isr(void);

/* the core's exceptions, SysTick (15) and the UART0 receive interrupt (IRQ 0 of the MPS2 AN386) */
__attribute__((section(".vectors"), used)) static void (*const vectors[17])(void) = {
    (void (*)(void))(&_stack_top), reset_handler, hang, hang, hang, hang, hang, 0, 0, 0, 0, hang, hang, 0, hang,
    board_systick_isr, board_uart_rx_isr};

void reset_handler(void)
{
    uint32_t *src = &_data_load, *dst = &_data_start;
    while (dst < &_data_end)
        *dst++ = *src++;
    for (dst = &_bss_start; dst < &_bss_end;)
        *dst++ = 0;
    *(volatile uint32_t *)0xE000ED88u |= 0xFu << 20; /* CPACR: CP10, CP11 full access (the FPU) */
    __asm volatile("dsb\n isb");
    main();
    hang();
}
