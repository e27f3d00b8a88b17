/* Motor PWM and laser, with the fail-safes that guard every output: the heartbeat watchdog
 * and the max-on duration (steppers are guarded here too; their motion is in stepper.c). */
#ifndef OUTPUTS_H
#define OUTPUTS_H
#include <stdbool.h>
#include <stdint.h>

#define OUTPUT_PWM 0u
#define OUTPUT_LASER 1u
#define OUTPUT_STEPPER0 2u /* + axis */

void outputs_reset(void);
void outputs_heartbeat(uint32_t now);
/* True while heartbeats arrive within watchdog_ms: only then are outputs accepted. */
bool outputs_armed(void);
/* Watchdog expiries since outputs_clear_counts (core_init: boot), for stats. */
uint16_t outputs_watchdog_expiries(void);
void outputs_clear_counts(void);
void outputs_set_pwm(int16_t duty, uint32_t now);
void outputs_set_laser(bool on, uint32_t now);
int16_t outputs_pwm(void);
bool outputs_laser(void);
/* Everything off: PWM 0, laser off, steppers stopped. */
void outputs_cut(void);
/* Control tick: watchdog and max-on checks; sends the fault frames. */
void outputs_tick(uint32_t now);

#ifdef CORE_SIL_HOOKS
/* The virtual MCU's wire model only (firmware/board/host, never a hardware build): the last
 * heartbeat's tick and the watchdog in ticks; false while not armed. */
bool outputs_watchdog_window(uint32_t *last, uint32_t *ticks);
/* While on, the control tick does not cut on an expired watchdog (the wire may still bring a
 * heartbeat sent in time); outputs_watchdog_check cuts now if it has expired (as the tick would). */
void outputs_watchdog_defer(bool on);
void outputs_watchdog_check(uint32_t now);
#endif

#endif
