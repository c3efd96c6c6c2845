/*
 * Reset and the vector table of the STM32F405/F407 (Cortex-M4; RM0090 table 61), no vendor
 * code: copy .data, clear .bss, run main(). Every exception and interrupt not used goes to
 * fault(): the amplifier off, then wait for the independent watchdog's reset.
 */
#include <stdint.h>
#include <string.h>

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
extern int main(void);
extern void hal_amplifier_off(void);

void Reset_Handler(void);
void SysTick_Handler(void);
void USART2_IRQHandler(void);
void PendSV_Handler(void);

static void fault(void)
{
    hal_amplifier_off();
    for (;;) {
    }
}

void Reset_Handler(void)
{
    memcpy(&_sdata, &_sidata, (size_t)((uintptr_t)&_edata - (uintptr_t)&_sdata));
    memset(&_sbss, 0, (size_t)((uintptr_t)&_ebss - (uintptr_t)&_sbss));
    (void)main();
    fault();
}

typedef void (*handler)(void);

#define F fault
struct vectors {
    uint32_t *stack_top;
    handler h[15 + 82];              /* 15 system exceptions, 82 interrupts (IRQ 0..81) */
};

__attribute__((section(".isr_vector"), used)) static const struct vectors vector_table = {
    &_estack,
    {
        /* 1 Reset, NMI, HardFault, MemManage, BusFault, UsageFault, 4 reserved */
        Reset_Handler, F, F, F, F, F, 0, 0, 0, 0,
        /* 11 SVCall, DebugMonitor, reserved, PendSV, SysTick */
        F, F, 0, PendSV_Handler, SysTick_Handler,
        /* IRQ 0 .. 29 */
        F, F, F, F, F, F, F, F, F, F,
        F, F, F, F, F, F, F, F, F, F,
        F, F, F, F, F, F, F, F, F, F,
        /* IRQ 30 .. 37 */
        F, F, F, F, F, F, F, F,
        /* IRQ 38: USART2 */
        USART2_IRQHandler,
        /* IRQ 39 .. 81 */
        F, F, F, F, F, F, F, F, F, F,
        F, F, F, F, F, F, F, F, F, F,
        F, F, F, F, F, F, F, F, F, F,
        F, F, F, F, F, F, F, F, F, F,
        F, F, F,
    },
};
