/* Compile-time constants of the core; a board may override them with -D. */
#ifndef CORE_CONFIG_H
#define CORE_CONFIG_H

#ifndef BOARD_CLOCK_HZ
#define BOARD_CLOCK_HZ 16000000ul /* timestamp ticks per second (ATmega328P Timer1, /1) */
#endif
#define CORE_TICK_HZ 10000u       /* control tick: state frames, watchdog, max-on */
#define CORE_TICKS_PER_TICK (BOARD_CLOCK_HZ / CORE_TICK_HZ)
#define CORE_TICKS_PER_MS (BOARD_CLOCK_HZ / 1000ul)

#ifndef CORE_TX_RING
#define CORE_TX_RING 128u /* bytes, power of two; 12 state frames of slack */
#endif
#define CORE_PULSE_QUEUE 8u /* power of two */

/* Defaults until the host sends config_set. */
#define CORE_DEFAULT_WATCHDOG_MS 200u
#define CORE_DEFAULT_STATE_DIV 10u /* 1 kHz state frames */
#define CORE_DEFAULT_MAX_ON_MS 0u  /* 0 = no max-on limit */
/* The state frame's stamp is the full 32-bit tick count (protocol v2), but encoder16 is only
 * unwrapped by the host from one frame to the next: state_div stays capped at 40 (4 ms), within
 * which the shaft cannot move 32768 counts. */
#define CORE_MAX_STATE_DIV 40u

#define STEPPER_AXES 2u
#define STEPPER_MAX_SPS 5000u     /* ISR cost: one 32-bit division per ramp step */
#define STEPPER_HOME_SPS 500u
#define STEPPER_HOME_MAX_STEPS 100000ul
#define STEPPER_STATE_EVERY 1000u /* ticks between stepper_state frames while moving (0.1 s) */

/* ack.status values (ACK_*): generated from protocol.yaml ack_status into protocol_gen.h. */

#endif
