/*
 * STM32F405/407 registers used by the board's HAL, written out by hand from the reference
 * manual RM0090 (section numbers in the comments) and the Cortex-M4 generic user guide. Only
 * what hal.c touches; no vendor header.
 */
#ifndef RW_STM32F4_REGS_H
#define RW_STM32F4_REGS_H

#include <stdint.h>

#define REG(addr) (*(volatile uint32_t *)(uintptr_t)(addr))

/* ---------------------------------------------------------------- RCC (RM0090 7.3) */
#define RCC_BASE 0x40023800u
#define RCC_CR REG(RCC_BASE + 0x00u)
#define RCC_PLLCFGR REG(RCC_BASE + 0x04u)
#define RCC_CFGR REG(RCC_BASE + 0x08u)
#define RCC_AHB1ENR REG(RCC_BASE + 0x30u)
#define RCC_APB1ENR REG(RCC_BASE + 0x40u)
#define RCC_APB2ENR REG(RCC_BASE + 0x44u)
#define RCC_CSR REG(RCC_BASE + 0x74u)

#define RCC_CR_HSIRDY (1u << 1)
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)

#define RCC_PLLCFGR_SRC_HSE (1u << 22)
#define RCC_PLLCFGR_M(v) ((uint32_t)(v) << 0)        /* 2..63 */
#define RCC_PLLCFGR_N(v) ((uint32_t)(v) << 6)        /* 50..432 */
#define RCC_PLLCFGR_P(v) ((uint32_t)((v) / 2u - 1u) << 16) /* 2, 4, 6, 8 */
#define RCC_PLLCFGR_Q(v) ((uint32_t)(v) << 24)       /* 2..15 */

#define RCC_CFGR_SW_MASK (3u << 0)
#define RCC_CFGR_SW_PLL (2u << 0)
#define RCC_CFGR_SWS(v) (((v) >> 2) & 3u)           /* 0 HSI, 1 HSE, 2 PLL */
#define RCC_CFGR_HPRE(v) (((v) >> 4) & 0xFu)
#define RCC_CFGR_PPRE1(v) (((v) >> 10) & 7u)
#define RCC_CFGR_PPRE2(v) (((v) >> 13) & 7u)
#define RCC_CFGR_PRE_MASK ((0xFu << 4) | (7u << 10) | (7u << 13))
#define RCC_CFGR_PPRE1_DIV4 (5u << 10)
#define RCC_CFGR_PPRE2_DIV2 (4u << 13)

#define RCC_AHB1ENR_GPIOA (1u << 0)
#define RCC_AHB1ENR_GPIOB (1u << 1)
#define RCC_AHB1ENR_GPIOC (1u << 2)
#define RCC_AHB1ENR_GPIOD (1u << 3)
#define RCC_APB1ENR_TIM2 (1u << 0)
#define RCC_APB1ENR_TIM3 (1u << 1)
#define RCC_APB1ENR_USART2 (1u << 17)
#define RCC_APB1ENR_PWR (1u << 28)
#define RCC_APB2ENR_TIM1 (1u << 0)

#define RCC_CSR_LSION (1u << 0)

/* ---------------------------------------------------------------- PWR (RM0090 5.4) */
#define PWR_CR REG(0x40007000u)
#define PWR_CR_VOS (1u << 14)                       /* scale 1: up to 168 MHz */

/* ---------------------------------------------------------------- FLASH (RM0090 3.9) */
#define FLASH_ACR REG(0x40023C00u)
#define FLASH_ACR_LATENCY(ws) ((uint32_t)(ws))
#define FLASH_ACR_PRFTEN (1u << 8)
#define FLASH_ACR_ICEN (1u << 9)
#define FLASH_ACR_DCEN (1u << 10)

/* ---------------------------------------------------------------- GPIO (RM0090 8.4) */
#define GPIOA 0x40020000u
#define GPIOB 0x40020400u
#define GPIOC 0x40020800u
#define GPIOD 0x40020C00u
#define GPIO_MODER(p) REG((p) + 0x00u)
#define GPIO_OTYPER(p) REG((p) + 0x04u)
#define GPIO_OSPEEDR(p) REG((p) + 0x08u)
#define GPIO_PUPDR(p) REG((p) + 0x0Cu)
#define GPIO_IDR(p) REG((p) + 0x10u)
#define GPIO_ODR(p) REG((p) + 0x14u)
#define GPIO_BSRR(p) REG((p) + 0x18u)
#define GPIO_AFR(p, i) REG((p) + 0x20u + 4u * (i))   /* i = 0: pins 0-7, 1: pins 8-15 */

#define GPIO_MODE_INPUT 0u
#define GPIO_MODE_OUTPUT 1u
#define GPIO_MODE_AF 2u
#define GPIO_PULL_NONE 0u
#define GPIO_PULL_UP 1u
#define GPIO_PULL_DOWN 2u
#define GPIO_SPEED_HIGH 2u

/* ---------------------------------------------------------------- timers (RM0090 14, 18) */
#define TIM1 0x40010000u            /* advanced, 16-bit, APB2 */
#define TIM2 0x40000000u            /* general purpose, 32-bit, APB1 */
#define TIM3 0x40000400u            /* general purpose, 16-bit, APB1 */
#define TIM_CR1(t) REG((t) + 0x00u)
#define TIM_SMCR(t) REG((t) + 0x08u)
#define TIM_DIER(t) REG((t) + 0x0Cu)
#define TIM_SR(t) REG((t) + 0x10u)
#define TIM_EGR(t) REG((t) + 0x14u)
#define TIM_CCMR1(t) REG((t) + 0x18u)
#define TIM_CCER(t) REG((t) + 0x20u)
#define TIM_CNT(t) REG((t) + 0x24u)
#define TIM_PSC(t) REG((t) + 0x28u)
#define TIM_ARR(t) REG((t) + 0x2Cu)
#define TIM_CCR1(t) REG((t) + 0x34u)
#define TIM_BDTR(t) REG((t) + 0x44u)

#define TIM_CR1_CEN (1u << 0)
#define TIM_CR1_ARPE (1u << 7)
#define TIM_DIER_UIE (1u << 0)
#define TIM_SR_UIF (1u << 0)
#define TIM_EGR_UG (1u << 0)
#define TIM_SMCR_SMS_ENCODER3 (3u << 0)             /* count on TI1 and TI2 edges: x4 */
#define TIM_CCMR1_CC1S_TI1 (1u << 0)
#define TIM_CCMR1_IC1F(f) ((uint32_t)(f) << 4)
#define TIM_CCMR1_CC2S_TI2 (1u << 8)
#define TIM_CCMR1_IC2F(f) ((uint32_t)(f) << 12)
#define TIM_CCMR1_OC1PE (1u << 3)
#define TIM_CCMR1_OC1M_PWM1 (6u << 4)
#define TIM_CCER_CC1E (1u << 0)
#define TIM_BDTR_MOE (1u << 15)

/* ---------------------------------------------------------------- USART (RM0090 30.6) */
#define USART2 0x40004400u
#define USART_SR(u) REG((u) + 0x00u)
#define USART_DR(u) REG((u) + 0x04u)
#define USART_BRR(u) REG((u) + 0x08u)
#define USART_CR1(u) REG((u) + 0x0Cu)
#define USART_CR2(u) REG((u) + 0x10u)
#define USART_CR3(u) REG((u) + 0x14u)

#define USART_SR_PE (1u << 0)
#define USART_SR_FE (1u << 1)
#define USART_SR_NF (1u << 2)
#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_UE (1u << 13)

/* ---------------------------------------------------------------- IWDG (RM0090 21.4) */
#define IWDG_KR REG(0x40003000u)
#define IWDG_PR REG(0x40003004u)
#define IWDG_RLR REG(0x40003008u)
#define IWDG_KEY_START 0xCCCCu
#define IWDG_KEY_RELOAD 0xAAAAu
#define IWDG_KEY_ACCESS 0x5555u

/* ---------------------------------------------------------------- debug (RM0090 38.16) */
#define DBGMCU_APB1_FZ REG(0xE0042008u)
#define DBGMCU_APB1_FZ_IWDG_STOP (1u << 12)

/* ---------------------------------------------------------------- Cortex-M4 core */
#define NVIC_ISER(i) REG(0xE000E100u + 4u * (i))
#define NVIC_IPR_BYTE(irq) (*(volatile uint8_t *)(uintptr_t)(0xE000E400u + (irq)))
#define SCB_ICSR REG(0xE000ED04u)
#define SCB_ICSR_PENDSTSET (1u << 26)               /* SysTick exception pending */
#define SCB_ICSR_PENDSVSET (1u << 28)
#define SCB_SHPR3 REG(0xE000ED20u)                  /* [23:16] PendSV, [31:24] SysTick */
#define SYST_CSR REG(0xE000E010u)                   /* SysTick control and status */
#define SYST_RVR REG(0xE000E014u)                   /* reload value (24 bits) */
#define SYST_CVR REG(0xE000E018u)                   /* current value, counts down */
#define SYST_CSR_ENABLE (1u << 0)
#define SYST_CSR_TICKINT (1u << 1)
#define SYST_CSR_CLKSOURCE_CPU (1u << 2)

/* STM32F4 interrupt numbers (RM0090 table 61) */
#define IRQ_USART2 38u

#endif /* RW_STM32F4_REGS_H */
