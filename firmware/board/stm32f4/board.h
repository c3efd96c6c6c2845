/*
 * The board: STM32F4DISCOVERY (STM32F407VG) or any STM32F405/F407 board. Pins, clock and the
 * rig's constants; firmware/README.md shows the wiring. Each value can be overridden from the
 * make command line, e.g.  make -C firmware HSE_HZ=12000000 SERIAL=0x52570002
 */
#ifndef RW_BOARD_H
#define RW_BOARD_H

/* ---------------------------------------------------------------- clock */
#ifndef RW_HSE_HZ
#define RW_HSE_HZ 8000000u          /* the DISCOVERY's crystal; a whole number of MHz, 4..26 */
#endif

/* ---------------------------------------------------------------- the link */
#ifndef RW_BAUD
#define RW_BAUD 921600u             /* PROTOCOL.md "Physical layer" */
#endif

/* ---------------------------------------------------------------- the rig */
#ifndef RW_COUNTS_PER_REV
#define RW_COUNTS_PER_REV 4000u     /* both encoders: 1000 lines, counted x4 */
#endif
#ifndef RW_SAMPLE_PERIOD_US
#define RW_SAMPLE_PERIOD_US 1000u   /* h; the stack must run with the same (the driver checks) */
#endif
#ifndef RW_U_MAX_MILLI
#define RW_U_MAX_MILLI 10000u       /* |u| <= 10 control units = 100 % PWM duty */
#endif
#ifndef RW_OMEGA_MAX_RAD_S
#define RW_OMEGA_MAX_RAD_S 828u     /* back-EMF limit V_max / k_m (OVERSPEED) */
#endif
#ifndef RW_SERIAL
#define RW_SERIAL 0x52570001u       /* give each rig its own */
#endif

/* ---------------------------------------------------------------- the amplifier */
#ifndef RW_PWM_HZ
#define RW_PWM_HZ 20000u            /* PWM frequency (above hearing) */
#endif

/* ---------------------------------------------------------------- pins (all free on the
 * STM32F4DISCOVERY and present on the 64-pin STM32F405 packages; the LEDs are the
 * DISCOVERY's) */
#define PIN_USART_TX GPIOA, 2u, 7u   /* USART2_TX, AF7 -> adapter RX */
#define PIN_USART_RX GPIOA, 3u, 7u   /* USART2_RX, AF7 <- adapter TX */
#define PIN_PEND_A GPIOB, 4u, 2u     /* TIM3_CH1, AF2: pendulum encoder A */
#define PIN_PEND_B GPIOB, 5u, 2u     /* TIM3_CH2, AF2: pendulum encoder B */
#define PIN_MOTOR_A GPIOA, 15u, 1u   /* TIM2_CH1, AF1: motor encoder A */
#define PIN_MOTOR_B GPIOB, 3u, 1u    /* TIM2_CH2, AF1: motor encoder B */
#define PIN_PWM GPIOA, 8u, 1u        /* TIM1_CH1, AF1: amplifier PWM */
#define PIN_DIR GPIOB, 12u           /* amplifier direction (high: u < 0) */
#define PIN_ENABLE GPIOB, 13u        /* amplifier enable (high: on); pull it down externally */
#ifndef RW_LEDS
#define RW_LEDS 1                    /* 0 on boards without the DISCOVERY's LEDs on PD12-14 */
#endif
#define PIN_LED_HEARTBEAT GPIOD, 12u /* green: blinks at 1 Hz while the sample clock runs */
#define PIN_LED_ENABLED GPIOD, 13u   /* orange: amplifier on */
#define PIN_LED_TRIPPED GPIOD, 14u   /* red: watchdog tripped */

#endif /* RW_BOARD_H */
