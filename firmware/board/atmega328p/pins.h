/* ATmega328P (Arduino Nano/Uno) pin map of the TVS controller. */
#ifndef PINS_H
#define PINS_H
#include <avr/io.h>

/* Inputs */
#define OPTICAL_ICP PB0  /* ICP1: optical sensor, timestamped by the Timer1 capture latch */
#define ZERO_INT PD2     /* INT0: zero-position sensor, timestamped in the ISR */
#define ENC_A PC0        /* PCINT8  quadrature encoder */
#define ENC_B PC1        /* PCINT9 */
#define LIMIT0 PC2       /* home switch axis 0, active low, pull-up */
#define LIMIT1 PC3       /* home switch axis 1 */
/* Outputs */
#define MOTOR_PWM PD6    /* OC0A, Timer0 fast PWM 62.5 kHz, to the H-bridge enable/PWM input */
#define MOTOR_DIR PD7    /* H-bridge direction */
#define LASER PD4        /* laser enable, active high */
#define STEP0 PB1
#define DIR0 PB2
#define STEP1 PB3
#define DIR1 PB4

#endif
