/*
 * The board's HAL: STM32F405/F407, registers by hand (regs.h). The thin shell around the
 * portable core (core/rw_core.h):
 *
 *   SysTick exception, every h        the sample clock (PROTOCOL.md "Device behaviour": the
 *                                     device is the sample clock): rw_core_tick_begin, motor,
 *                                     encoders (TIM3, TIM2 in encoder mode), rw_core_tick_end,
 *                                     SAMPLE frame into the TX ring
 *   USART2 interrupt, per byte        the byte into the RX ring, PendSV pended
 *   PendSV                            the RX ring through rw_core_receive, replies into the TX
 *                                     ring, motor (a COMMAND is held "from now on")
 *   main loop                         the TX ring out through USART2 (TXE polled), wfi when empty
 *
 * SysTick and PendSV share one priority, so the core's two entry points never preempt each other;
 * the USART interrupt is above them (a byte every 10.9 us at 921 600 baud must not be lost to a
 * sample). The rings have one writer and one reader each.
 */
#include <stddef.h>
#include <stdint.h>

#include "board.h"
#include "regs.h"
#include "rw_core.h"

/* ---------------------------------------------------------------- priorities (upper nibble) */
#define PRIO_USART 0x00u
#define PRIO_CORE 0x40u              /* SysTick and PendSV */

/* ---------------------------------------------------------------- what the HAL counts
 * (not on the wire: read them with a debugger, e.g. `print hal` in gdb through OpenOCD) */
struct hal_counters {
    uint32_t rx_overruns;            /* USART overrun: a byte lost before it was read */
    uint32_t rx_line_errors;         /* framing / noise errors (the byte is passed on) */
    uint32_t rx_ring_full;           /* bytes dropped: the RX ring full */
    uint32_t tx_frames_dropped;      /* frames dropped whole: the TX ring full ("drop bytes
                                        when the UART is full") */
    uint32_t sysclk_hz;              /* the CPU's (HCLK), the SysTick's */
    uint32_t pclk1_hz;               /* USART2 */
    uint32_t pclk2_hz;
    uint32_t tim1_clk_hz;            /* the PWM timer's */
    uint32_t clock_source;           /* RCC_CFGR.SWS: 0 HSI, 1 HSE, 2 PLL; 3 no RCC (emulator) */
    uint32_t hse_failed;             /* the crystal did not start: PLL from the HSI */
};
volatile struct hal_counters hal;

static rw_core core;

/* ---------------------------------------------------------------- rings */
#define RX_RING 256u                 /* powers of two */
#define TX_RING 1024u
static uint8_t rx_buf[RX_RING];
static volatile uint32_t rx_head, rx_tail;   /* head: USART ISR; tail: PendSV */
static uint8_t tx_buf[TX_RING];
static volatile uint32_t tx_head, tx_tail;   /* head: SysTick / PendSV; tail: main loop */

static inline void barrier(void)
{
    __asm__ volatile("dmb" ::: "memory");
}

/* A whole frame block into the TX ring, or nothing (counted) when it does not fit. */
static void tx_put(const uint8_t *p, size_t n)
{
    uint32_t head = tx_head;
    uint32_t space = TX_RING - 1u - ((head - tx_tail) & (TX_RING - 1u));
    if (!n)
        return;
    if (n > space) {
        hal.tx_frames_dropped++;
        return;
    }
    for (size_t i = 0; i < n; i++)
        tx_buf[(head + i) & (TX_RING - 1u)] = p[i];
    barrier();
    tx_head = (head + (uint32_t)n) & (TX_RING - 1u);
}

/* ---------------------------------------------------------------- GPIO */
static void gpio_mode(uint32_t port, uint32_t pin, uint32_t mode, uint32_t pull)
{
    GPIO_MODER(port) = (GPIO_MODER(port) & ~(3u << (2u * pin))) | (mode << (2u * pin));
    GPIO_PUPDR(port) = (GPIO_PUPDR(port) & ~(3u << (2u * pin))) | (pull << (2u * pin));
    GPIO_OSPEEDR(port) = (GPIO_OSPEEDR(port) & ~(3u << (2u * pin))) | (GPIO_SPEED_HIGH << (2u * pin));
    GPIO_OTYPER(port) &= ~(1u << pin);                   /* push-pull */
}

static void gpio_af(uint32_t port, uint32_t pin, uint32_t af, uint32_t pull)
{
    uint32_t i = pin / 8u, shift = 4u * (pin % 8u);
    GPIO_AFR(port, i) = (GPIO_AFR(port, i) & ~(0xFu << shift)) | (af << shift);
    gpio_mode(port, pin, GPIO_MODE_AF, pull);
}

static void gpio_write(uint32_t port, uint32_t pin, int high)
{
    GPIO_BSRR(port) = high ? (1u << pin) : (1u << (pin + 16u));
}

static void gpio_output(uint32_t port, uint32_t pin, int high)
{
    gpio_write(port, pin, high);                         /* level first: no glitch */
    gpio_mode(port, pin, GPIO_MODE_OUTPUT, GPIO_PULL_NONE);
}

/* ---------------------------------------------------------------- clock */

/* Bounded wait for a flag: a part that never answers (or an emulator without the RCC) leaves
 * the clock as it is rather than hanging. */
static int wait_set(volatile uint32_t *reg, uint32_t mask, uint32_t want)
{
    for (uint32_t i = 0; i < 200000u; i++)
        if ((*reg & mask) == want)
            return 1;
    return 0;
}

static uint32_t ahb_div(uint32_t hpre)
{
    static const uint16_t div[8] = {2, 4, 8, 16, 64, 128, 256, 512};
    return hpre < 8u ? 1u : div[hpre - 8u];
}

static uint32_t apb_div(uint32_t ppre)
{
    return ppre < 4u ? 1u : 1u << (ppre - 3u);
}

#define NOMINAL_SYSCLK_HZ 168000000u

/* 168 MHz from the PLL (HSE, else HSI): AHB 168, APB1 42 (timers 84), APB2 84 (timers 168).
 * The clocks are then read back from the RCC, so the UART and the timers are set for the
 * clock the chip actually runs on (RM0090 6.3). */
static void clock_init(void)
{
    uint32_t src_hz = 16000000u, m, n, pll;
    if (!(RCC_CR & RCC_CR_HSIRDY)) {
        /* Out of reset every STM32F4 reads HSIRDY set (RCC_CR reset value 0x0000 XX83, RM0090
         * 7.3.1): the HSI runs. Clear means no clock tree behind the registers -- an emulator
         * (QEMU's netduinoplus2 models no RCC). Its CPU clock is the nominal one. */
        hal.clock_source = 3u;
        hal.sysclk_hz = NOMINAL_SYSCLK_HZ;
        hal.pclk1_hz = NOMINAL_SYSCLK_HZ / 4u;
        hal.pclk2_hz = NOMINAL_SYSCLK_HZ / 2u;
        hal.tim1_clk_hz = NOMINAL_SYSCLK_HZ;
        return;
    }
    RCC_APB1ENR |= RCC_APB1ENR_PWR;
    PWR_CR |= PWR_CR_VOS;
    RCC_CR |= RCC_CR_HSEON;
    if (wait_set(&RCC_CR, RCC_CR_HSERDY, RCC_CR_HSERDY)) {
        src_hz = RW_HSE_HZ;
    } else {
        RCC_CR &= ~RCC_CR_HSEON;
        hal.hse_failed = 1;
    }
    /* VCO input 2 MHz where the source allows it (recommended), else 1 MHz; VCO 336 MHz */
    m = (src_hz % 2000000u == 0u) ? src_hz / 2000000u : src_hz / 1000000u;
    n = 336000000u / (src_hz / m);
    pll = RCC_PLLCFGR_M(m) | RCC_PLLCFGR_N(n) | RCC_PLLCFGR_P(2u) | RCC_PLLCFGR_Q(7u);
    if (!hal.hse_failed)
        pll |= RCC_PLLCFGR_SRC_HSE;
    RCC_PLLCFGR = pll;
    RCC_CR |= RCC_CR_PLLON;
    if (wait_set(&RCC_CR, RCC_CR_PLLRDY, RCC_CR_PLLRDY)) {
        FLASH_ACR = FLASH_ACR_LATENCY(5) | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
        RCC_CFGR = (RCC_CFGR & ~(RCC_CFGR_PRE_MASK | RCC_CFGR_SW_MASK)) |
                   RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_PPRE2_DIV2 | RCC_CFGR_SW_PLL;
        (void)wait_set(&RCC_CFGR, 3u << 2, RCC_CFGR_SW_PLL << 2);
    }
    /* read back what runs */
    uint32_t cfgr = RCC_CFGR, sys;
    hal.clock_source = RCC_CFGR_SWS(cfgr);
    if (hal.clock_source == 1u) {
        sys = RW_HSE_HZ;
    } else if (hal.clock_source == 2u) {
        uint32_t c = RCC_PLLCFGR;
        uint32_t in = (c & RCC_PLLCFGR_SRC_HSE) ? RW_HSE_HZ : 16000000u;
        uint32_t pm = c & 0x3Fu, pn = (c >> 6) & 0x1FFu, pp = 2u * (((c >> 16) & 3u) + 1u);
        sys = pm ? in / pm * pn / pp : 16000000u;
    } else {
        sys = 16000000u;
    }
    uint32_t hclk = sys / ahb_div(RCC_CFGR_HPRE(cfgr));
    uint32_t apb2 = apb_div(RCC_CFGR_PPRE2(cfgr));
    hal.sysclk_hz = hclk;
    hal.pclk1_hz = hclk / apb_div(RCC_CFGR_PPRE1(cfgr));
    hal.pclk2_hz = hclk / apb2;
    /* timers run at twice their APB clock when its prescaler is not 1 (RM0090 6.2) */
    hal.tim1_clk_hz = apb2 == 1u ? hal.pclk2_hz : 2u * hal.pclk2_hz;
}

/* ---------------------------------------------------------------- the amplifier */
static uint32_t pwm_period;          /* TIM1 ARR + 1 */

/* Safe state, also from the fault handlers: PWM 0, enable low. */
void hal_amplifier_off(void)
{
    TIM_CCR1(TIM1) = 0;
    gpio_write(PIN_ENABLE, 0);
}

static void apply(rw_drive d)
{
    if (!d.amplifier_on) {
        hal_amplifier_off();
        return;
    }
    uint32_t duty = (uint32_t)d.magnitude_milli * pwm_period / RW_U_MAX_MILLI;
    gpio_write(PIN_DIR, d.reverse);
    TIM_CCR1(TIM1) = duty > pwm_period ? pwm_period : duty;
    gpio_write(PIN_ENABLE, 1);
}

static void amplifier_init(void)
{
    gpio_output(PIN_ENABLE, 0);
    gpio_output(PIN_DIR, 0);
    pwm_period = hal.tim1_clk_hz / RW_PWM_HZ;           /* 8400 steps at 168 MHz / 20 kHz */
    TIM_PSC(TIM1) = 0;
    TIM_ARR(TIM1) = pwm_period - 1u;
    TIM_CCR1(TIM1) = 0;
    TIM_CCMR1(TIM1) = TIM_CCMR1_OC1M_PWM1 | TIM_CCMR1_OC1PE;
    TIM_CCER(TIM1) = TIM_CCER_CC1E;
    TIM_BDTR(TIM1) = TIM_BDTR_MOE;                      /* advanced timer: outputs on */
    TIM_EGR(TIM1) = TIM_EGR_UG;
    TIM_CR1(TIM1) = TIM_CR1_ARPE | TIM_CR1_CEN;
    gpio_af(PIN_PWM, GPIO_PULL_NONE);
}

/* ---------------------------------------------------------------- encoders */
static int32_t pendulum_count;       /* TIM3 (16-bit) extended to 32 bits */

static void encoder_init(uint32_t tim, uint32_t arr)
{
    TIM_SMCR(tim) = TIM_SMCR_SMS_ENCODER3;
    /* inputs TI1, TI2 with a digital filter of 8 samples at the timer clock (~95 ns) */
    TIM_CCMR1(tim) = TIM_CCMR1_CC1S_TI1 | TIM_CCMR1_IC1F(3) | TIM_CCMR1_CC2S_TI2 | TIM_CCMR1_IC2F(3);
    TIM_CCER(tim) = 0;                                   /* both polarities non-inverted */
    TIM_ARR(tim) = arr;
    TIM_CNT(tim) = 0;                                    /* "encoders zero at power-up" */
    TIM_CR1(tim) = TIM_CR1_CEN;
}

static void encoders_init(void)
{
    gpio_af(PIN_PEND_A, GPIO_PULL_UP);
    gpio_af(PIN_PEND_B, GPIO_PULL_UP);
    gpio_af(PIN_MOTOR_A, GPIO_PULL_UP);
    gpio_af(PIN_MOTOR_B, GPIO_PULL_UP);
    encoder_init(TIM3, 0xFFFFu);
    encoder_init(TIM2, 0xFFFFFFFFu);
}

/* ---------------------------------------------------------------- sample clock and device time
 * SysTick, the Cortex-M4's own timer, at the CPU clock: one exception every h. */
static volatile uint32_t periods;    /* SysTick wraps since start */
static uint32_t ticks_per_us;

/* Device clock, us: h per period elapsed plus the SysTick's progress in the current one
 * (it counts down from the reload value). Call at PRIO_CORE: the SysTick exception cannot run
 * meanwhile, and a pending one is a wrap not yet counted. */
static uint32_t device_time_us(void)
{
    uint32_t p = periods, val = SYST_CVR;
    if (SCB_ICSR & SCB_ICSR_PENDSTSET) {
        val = SYST_CVR;
        p++;
    }
    return p * RW_SAMPLE_PERIOD_US + (SYST_RVR - val) / ticks_per_us;
}

static void sample_clock_init(void)
{
    ticks_per_us = hal.sysclk_hz / 1000000u;
    SYST_RVR = RW_SAMPLE_PERIOD_US * ticks_per_us - 1u;  /* < 2^24 for h up to 99 ms */
    SYST_CVR = 0;
    SCB_SHPR3 = (SCB_SHPR3 & ~(0xFFu << 24)) | (PRIO_CORE << 24);
    SYST_CSR = SYST_CSR_CLKSOURCE_CPU | SYST_CSR_TICKINT | SYST_CSR_ENABLE;
}

static void leds(void)
{
#if RW_LEDS
    static uint32_t beat;
    static int lit;
    if (++beat >= 500000u / RW_SAMPLE_PERIOD_US) {       /* 1 Hz */
        beat = 0;
        lit = !lit;
        gpio_write(PIN_LED_HEARTBEAT, lit);
    }
    gpio_write(PIN_LED_ENABLED, core.enabled);
    gpio_write(PIN_LED_TRIPPED, core.tripped);
#endif
}

/* The sample instant. PROTOCOL.md "Order within a sample period: watchdog check -> apply held
 * command for the period -> read encoders -> send SAMPLE". */
void SysTick_Handler(void)
{
    uint8_t frame[RW_SAMPLE_FRAME_SIZE];
    periods++;
    uint32_t now = device_time_us();
    rw_core_tick_begin(&core, now);
    apply(rw_core_drive(&core));
    pendulum_count = rw_counter_extend16(pendulum_count, (uint16_t)TIM_CNT(TIM3));
    int32_t motor_count = (int32_t)TIM_CNT(TIM2);
    size_t n = rw_core_tick_end(&core, now, pendulum_count, motor_count, frame, sizeof frame);
    tx_put(frame, n);
    IWDG_KR = IWDG_KEY_RELOAD;                           /* the sample clock runs */
    leds();
}

/* ---------------------------------------------------------------- the link */
void USART2_IRQHandler(void)
{
    uint32_t sr = USART_SR(USART2);
    if (sr & (USART_SR_RXNE | USART_SR_ORE | USART_SR_FE | USART_SR_NF | USART_SR_PE)) {
        uint8_t b = (uint8_t)USART_DR(USART2);           /* SR then DR: clears the error flags */
        if (sr & USART_SR_ORE)
            hal.rx_overruns++;
        if (sr & (USART_SR_FE | USART_SR_NF | USART_SR_PE))
            hal.rx_line_errors++;
        uint32_t head = rx_head, next = (head + 1u) & (RX_RING - 1u);
        if (next == rx_tail) {
            hal.rx_ring_full++;
        } else {
            rx_buf[head] = b;
            barrier();
            rx_head = next;
        }
        SCB_ICSR = SCB_ICSR_PENDSVSET;
    }
}

/* The bytes received, through the core. */
void PendSV_Handler(void)
{
    uint8_t in[32];
    uint8_t out[RW_REPLY_CAP(sizeof in)];
    while (rx_tail != rx_head) {
        size_t n = 0;
        uint32_t tail = rx_tail;
        while (tail != rx_head && n < sizeof in) {
            in[n++] = rx_buf[tail];
            tail = (tail + 1u) & (RX_RING - 1u);
        }
        barrier();
        rx_tail = tail;
        size_t m = rw_core_receive(&core, in, n, device_time_us(), out, sizeof out);
        tx_put(out, m);
        apply(rw_core_drive(&core));                     /* "held from now on" */
    }
}

static void usart_init(void)
{
    gpio_af(PIN_USART_TX, GPIO_PULL_NONE);
    gpio_af(PIN_USART_RX, GPIO_PULL_UP);
    /* 8N1, oversampling by 16: BRR = f_pclk / baud (RM0090 30.3.4); 42 MHz -> 913 043 baud,
     * -0.9 % from 921 600 (the receivers tolerate about 3 %) */
    USART_BRR(USART2) = (hal.pclk1_hz + RW_BAUD / 2u) / RW_BAUD;
    USART_CR2(USART2) = 0;
    USART_CR3(USART2) = 0;
    USART_CR1(USART2) = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    NVIC_IPR_BYTE(IRQ_USART2) = PRIO_USART;
    NVIC_ISER(IRQ_USART2 / 32u) = 1u << (IRQ_USART2 % 32u);
}

/* ---------------------------------------------------------------- independent watchdog */
static void iwdg_init(void)
{
    /* LSI ~32 kHz / 32 = 1 kHz, 100 counts: a reset when the sample clock stops for ~0.1 s
     * (the amplifier enable then falls to its pull-down). Frozen while a debugger halts. */
    DBGMCU_APB1_FZ |= DBGMCU_APB1_FZ_IWDG_STOP;
    IWDG_KR = IWDG_KEY_START;
    IWDG_KR = IWDG_KEY_ACCESS;
    IWDG_PR = 3u;                                        /* /32 */
    IWDG_RLR = 100u;
    IWDG_KR = IWDG_KEY_RELOAD;
}

static const rw_config CONFIG = {
    .counts_per_rev_pendulum = RW_COUNTS_PER_REV,
    .counts_per_rev_motor = RW_COUNTS_PER_REV,
    .sample_period_us = RW_SAMPLE_PERIOD_US,
    .u_max_milli = RW_U_MAX_MILLI,
    .watchdog_ms = RW_WATCHDOG_POWER_UP_MS,
    .serial = RW_SERIAL,
    /* omega_max in counts per period: omega * cpr * h / (2 pi) */
    .overspeed_counts = (uint32_t)((uint64_t)RW_OMEGA_MAX_RAD_S * RW_COUNTS_PER_REV *
                                   RW_SAMPLE_PERIOD_US / 6283185u),
};

int main(void)
{
    clock_init();
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOA | RCC_AHB1ENR_GPIOB | RCC_AHB1ENR_GPIOC | RCC_AHB1ENR_GPIOD;
    RCC_APB1ENR |= RCC_APB1ENR_TIM2 | RCC_APB1ENR_TIM3 | RCC_APB1ENR_USART2;
    RCC_APB2ENR |= RCC_APB2ENR_TIM1;
    (void)RCC_APB2ENR;                                   /* the clocks settle (RM0090 6.3.10) */

    amplifier_init();                                    /* first: the amplifier is off */
#if RW_LEDS
    gpio_output(PIN_LED_HEARTBEAT, 0);
    gpio_output(PIN_LED_ENABLED, 0);
    gpio_output(PIN_LED_TRIPPED, 0);
#endif
    encoders_init();
    if (rw_core_init(&core, &CONFIG, NULL, NULL) != 0) {
        for (;;) {
        }                                                /* a bad board.h: never runs the motor */
    }
    SCB_SHPR3 = (SCB_SHPR3 & ~(0xFFu << 16)) | (PRIO_CORE << 16);   /* PendSV */
    usart_init();
    iwdg_init();
    sample_clock_init();

    for (;;) {
        /* the TX ring out, byte by byte as the USART takes them */
        uint32_t tail = tx_tail;
        while (tail != tx_head) {
            while (!(USART_SR(USART2) & USART_SR_TXE)) {
            }
            USART_DR(USART2) = tx_buf[tail];
            tail = (tail + 1u) & (TX_RING - 1u);
            tx_tail = tail;
        }
        /* then sleep until the next interrupt; with interrupts masked between the test and
         * the WFI, a frame put in meanwhile wakes it at once (no lost wake-up) */
        __asm__ volatile("cpsid i" ::: "memory");
        if (tx_tail == tx_head)
            __asm__ volatile("wfi");
        __asm__ volatile("cpsie i" ::: "memory");
    }
}
