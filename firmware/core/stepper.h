/* Stepper motion: acceleration-limited trapezoid planned per step for a timer-compare ISR.
 *
 * Step intervals follow D. Austin's recurrence (AVR446): c_n = c_{n-1} - 2 c_{n-1} / (4n + 1)
 * while accelerating, mirrored while decelerating, c_min = f / rate while cruising, with
 * c_0 = 0.676 f sqrt(2 / accel) (0.676 corrects the recurrence's error on the first steps).
 * One integer division per ramp step and none while cruising: cheap enough for an AVR ISR. */
#ifndef STEPPER_H
#define STEPPER_H
#include <stdbool.h>
#include <stdint.h>

#define STEPPER_FLAG_MOVING 1u
#define STEPPER_FLAG_HOMED 2u
#define STEPPER_FLAG_AT_LIMIT 4u

void stepper_reset(void);
/* Main context. Returns an ACK_* status. */
uint8_t stepper_move(uint8_t axis, int32_t steps, uint16_t rate_sps, uint16_t accel_sps2,
                     uint32_t now);
/* Move toward the home switch (negative) at STEPPER_HOME_SPS until it closes; position 0 there. */
uint8_t stepper_home(uint8_t axis, uint32_t now);
void stepper_stop(uint8_t axis);
bool stepper_moving(uint8_t axis);
uint32_t stepper_started(uint8_t axis);
int32_t stepper_position(uint8_t axis);
uint8_t stepper_flags(uint8_t axis);
/* Main context: true once after each change (start, end, limit); clears the mark. */
bool stepper_take_changed(uint8_t axis);
/* Main context: limit fault detail (axis, plus 0x100 when homing found no switch), or -1. */
int32_t stepper_take_fault(uint8_t axis);

/* Step-timer ISR: emit every step due at `now`, plan the next ones. Returns false when no axis
 * moves; otherwise *next_due is the earliest next step time. */
bool stepper_service(uint32_t now, uint32_t *next_due);

#endif
