/* STM32F405 (LQFP64, e.g. Adafruit Feather STM32F405, Olimex STM32-H405, pyboard) pin map of the
 * TVS controller. hil/README.md has the wiring table. */
#ifndef PINS_H
#define PINS_H

/* Host link: USART1 (AF7), 2 Mbaud 8N1, 3.3 V levels (the Pi's UART directly). */
#define PIN_USART_TX 9u   /* PA9  */
#define PIN_USART_RX 10u  /* PA10 */
/* Motor H-bridge: TIM1_CH1 (AF1) PWM 20 kHz, direction on a GPIO. */
#define PIN_MOTOR_PWM 8u  /* PA8  */
#define PIN_MOTOR_DIR 12u /* PB12 */
#define PIN_LASER 13u     /* PB13, laser enable, active high */
/* Quadrature encoder: TIM8 in encoder mode x4 (AF3). */
#define PIN_ENC_A 6u      /* PC6 TIM8_CH1 */
#define PIN_ENC_B 7u      /* PC7 TIM8_CH2 */
/* Sensor pulses: TIM2 input capture (AF1), latched in hardware. */
#define PIN_OPTICAL 10u   /* PB10 TIM2_CH3 */
#define PIN_ZERO 11u      /* PB11 TIM2_CH4 */
/* Steppers (step/dir drivers, e.g. A4988/DRV8825) and home switches (active low, pull-up). */
#define PIN_STEP0 0u      /* PC0 */
#define PIN_DIR0 1u       /* PC1 */
#define PIN_STEP1 2u      /* PC2 */
#define PIN_DIR1 3u       /* PC3 */
#define PIN_LIMIT0 4u     /* PC4 */
#define PIN_LIMIT1 5u     /* PC5 */

#endif
