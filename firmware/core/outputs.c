#include "outputs.h"

#include "board.h"
#include "core.h"
#include "protocol_gen.h"
#include "stepper.h"

static bool armed;
static uint32_t last_heartbeat;
static int16_t pwm;
static bool laser;
static uint32_t pwm_since, laser_since; /* last command that kept the output on */
/* Limits in timer ticks, recomputed only when config_set changes them (a 32-bit multiply
 * per check would cost the AVR ~100 cycles per control tick). */
static uint16_t limits_for_wd, limits_for_max_on;
static uint32_t wd_ticks, max_on_ticks;
static uint16_t wd_expiries; /* since boot (core_init), modulo 65536: stats watchdog_expiries */

void outputs_reset(void)
{
    limits_for_wd = limits_for_max_on = 0;
    wd_ticks = max_on_ticks = 0;
    armed = false;
    pwm = 0;
    laser = false;
    board_set_pwm(0);
    board_set_laser(false);
}

void outputs_heartbeat(uint32_t now)
{
    armed = true;
    last_heartbeat = now;
}

bool outputs_armed(void) { return armed; }

#ifdef CORE_SIL_HOOKS
static bool wd_deferred; /* the SIL's wire model: the expiry waits for a heartbeat still on the pty */

bool outputs_watchdog_window(uint32_t *last, uint32_t *ticks)
{
    *last = last_heartbeat;
    *ticks = (uint32_t)core_cfg.watchdog_ms * CORE_TICKS_PER_MS; /* as outputs_tick computes it */
    return armed;
}

void outputs_watchdog_defer(bool on) { wd_deferred = on; }

void outputs_watchdog_check(uint32_t now)
{
    uint32_t wd = (uint32_t)core_cfg.watchdog_ms * CORE_TICKS_PER_MS;
    if (armed && (int32_t)(now - last_heartbeat) >= (int32_t)wd) {
        armed = false;
        wd_expiries++;
        outputs_cut();
        core_fault(FAULT_WATCHDOG_EXPIRED, core_cfg.watchdog_ms);
    }
}
#endif

uint16_t outputs_watchdog_expiries(void) { return wd_expiries; }
void outputs_clear_counts(void) { wd_expiries = 0; }
int16_t outputs_pwm(void) { return pwm; }
bool outputs_laser(void) { return laser; }

void outputs_set_pwm(int16_t duty, uint32_t now)
{
    pwm = duty;
    pwm_since = now;
    board_set_pwm(duty);
}

void outputs_set_laser(bool on, uint32_t now)
{
    laser = on;
    laser_since = now;
    board_set_laser(on);
}

void outputs_cut(void)
{
    pwm = 0;
    laser = false;
    board_set_pwm(0);
    board_set_laser(false);
    for (uint8_t i = 0; i < STEPPER_AXES; i++)
        stepper_stop(i);
}


/* Signed: `now` is the tick's sampled time, which can precede a command handled just after
 * the tick fell due; that must read as "just now", not as 2^32 ticks ago. */
static bool expired(uint32_t now, uint32_t since, uint32_t ticks)
{
    return (int32_t)(now - since) >= (int32_t)ticks;
}

void outputs_tick(uint32_t now)
{
    if (limits_for_wd != core_cfg.watchdog_ms || limits_for_max_on != core_cfg.max_on_ms) {
        limits_for_wd = core_cfg.watchdog_ms;
        limits_for_max_on = core_cfg.max_on_ms;
        wd_ticks = (uint32_t)limits_for_wd * CORE_TICKS_PER_MS;
        max_on_ticks = (uint32_t)limits_for_max_on * CORE_TICKS_PER_MS;
    }
#ifdef CORE_SIL_HOOKS
    if (armed && expired(now, last_heartbeat, wd_ticks) && !wd_deferred) {
#else
    if (armed && expired(now, last_heartbeat, wd_ticks)) {
#endif
        armed = false;
        wd_expiries++;
        outputs_cut();
        core_fault(FAULT_WATCHDOG_EXPIRED, core_cfg.watchdog_ms);
        return;
    }
    if (limits_for_max_on == 0)
        return;
    uint32_t max_on = max_on_ticks;
    if (pwm != 0 && expired(now, pwm_since, max_on)) {
        pwm = 0;
        board_set_pwm(0);
        core_fault(FAULT_OUTPUT_TIMEOUT, OUTPUT_PWM);
    }
    if (laser && expired(now, laser_since, max_on)) {
        laser = false;
        board_set_laser(false);
        core_fault(FAULT_OUTPUT_TIMEOUT, OUTPUT_LASER);
    }
    for (uint8_t i = 0; i < STEPPER_AXES; i++) {
        if (stepper_moving(i) && expired(now, stepper_started(i), max_on)) {
            stepper_stop(i);
            core_fault(FAULT_OUTPUT_TIMEOUT, (uint16_t)(OUTPUT_STEPPER0 + i));
        }
    }
}
