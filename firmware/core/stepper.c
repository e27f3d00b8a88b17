#include "stepper.h"

#include <math.h>
#include <string.h>

#include "board.h"
#include "core.h"
#include "core_config.h"

typedef struct {
    int32_t position;
    uint32_t total;        /* steps in the move */
    uint32_t index;        /* steps done */
    uint32_t accel_steps;  /* intervals 0..accel_steps-1 shrink */
    uint32_t decel_start;  /* intervals from here on grow */
    uint32_t c, c_min;     /* current and cruise step interval, ticks */
    uint32_t c0;           /* exact first (and last) ramp interval, f sqrt(2/a) */
    uint32_t rem;          /* division remainder carried to keep the ramp exact on average */
    uint32_t due;          /* time of the next step */
    uint32_t started;      /* when the move was commanded (max-on) */
    bool full_ramp;        /* the ramp reaches the commanded rate: cruise at c_min */
    bool negative, moving, homing, homed, at_limit;
    volatile bool changed;
    volatile int32_t fault; /* -1 none */
} axis_t;

static axis_t axes[STEPPER_AXES];

void stepper_reset(void)
{
    memset(axes, 0, sizeof axes);
    for (uint8_t i = 0; i < STEPPER_AXES; i++)
        axes[i].fault = -1;
}

static void begin(axis_t *a, uint8_t axis, uint32_t n, bool negative, uint32_t c0,
                  uint32_t c_min, uint32_t accel_steps, uint32_t now)
{
    uint8_t s = board_irq_save();
    a->total = n;
    a->index = 0;
    a->negative = negative;
    a->c_min = c_min;
    a->c0 = c0;
    a->accel_steps = accel_steps;
    a->decel_start = n - accel_steps;
    /* The first step comes at the exact time sqrt(2/a); the recurrence is seeded with the
     * 0.676 c0 that makes its following intervals right (AVR446). */
    a->c = accel_steps ? (uint32_t)(0.676 * c0) : c_min;
    a->rem = 0;
    a->due = now + (accel_steps ? c0 : c_min);
    a->started = now;
    a->moving = true;
    a->changed = true;
    core_events = true;
    board_step_dir(axis, negative);
    board_irq_restore(s);
    board_stepper_wake();
}

uint8_t stepper_move(uint8_t axis, int32_t steps, uint16_t rate_sps, uint16_t accel_sps2,
                     uint32_t now)
{
    if (axis >= STEPPER_AXES || rate_sps == 0 || rate_sps > STEPPER_MAX_SPS || accel_sps2 == 0)
        return ACK_BAD_ARG;
    axis_t *a = &axes[axis];
    if (a->moving)
        return ACK_BUSY;
    if (steps == 0)
        return ACK_OK;
    uint32_t n = steps < 0 ? (uint32_t)0 - (uint32_t)steps : (uint32_t)steps;
    uint32_t c_min = BOARD_CLOCK_HZ / rate_sps;
    /* Steps needed to reach the rate at this acceleration: v^2 / (2 a). */
    uint32_t ramp = (uint32_t)rate_sps * rate_sps / (2ul * accel_sps2);
    bool full = true;
    if (ramp > n / 2) {
        ramp = n / 2; /* triangle: not enough room to reach the rate */
        full = false;
    }
    uint32_t c0 = (uint32_t)((double)BOARD_CLOCK_HZ * sqrt(2.0 / accel_sps2));
    if (ramp == 0 || c0 <= c_min)
        ramp = 0; /* the first step already comes at cruise rate */
    a->homing = false;
    a->full_ramp = full;
    begin(a, axis, n, steps < 0, c0, c_min, ramp, now);
    return ACK_OK;
}

uint8_t stepper_home(uint8_t axis, uint32_t now)
{
    if (axis >= STEPPER_AXES)
        return ACK_BAD_ARG;
    axis_t *a = &axes[axis];
    if (a->moving)
        return ACK_BUSY;
    a->homing = true;
    a->homed = false;
    a->full_ramp = true;
    begin(a, axis, STEPPER_HOME_MAX_STEPS, true, 0, BOARD_CLOCK_HZ / STEPPER_HOME_SPS, 0, now);
    return ACK_OK;
}

void stepper_stop(uint8_t axis)
{
    uint8_t s = board_irq_save();
    if (axes[axis].moving) {
        axes[axis].moving = false;
        axes[axis].homing = false;
        axes[axis].changed = true;
        core_events = true;
    }
    board_irq_restore(s);
}

bool stepper_moving(uint8_t axis) { return axes[axis].moving; }
uint32_t stepper_started(uint8_t axis) { return axes[axis].started; }

int32_t stepper_position(uint8_t axis)
{
    uint8_t s = board_irq_save();
    int32_t p = axes[axis].position;
    board_irq_restore(s);
    return p;
}

uint8_t stepper_flags(uint8_t axis)
{
    const axis_t *a = &axes[axis];
    return (uint8_t)((a->moving ? STEPPER_FLAG_MOVING : 0u) | (a->homed ? STEPPER_FLAG_HOMED : 0u) |
                     (a->at_limit ? STEPPER_FLAG_AT_LIMIT : 0u));
}

bool stepper_take_changed(uint8_t axis)
{
    uint8_t s = board_irq_save();
    bool c = axes[axis].changed;
    axes[axis].changed = false;
    board_irq_restore(s);
    return c;
}

int32_t stepper_take_fault(uint8_t axis)
{
    uint8_t s = board_irq_save();
    int32_t f = axes[axis].fault;
    axes[axis].fault = -1;
    board_irq_restore(s);
    return f;
}

static void finish(axis_t *a, int32_t fault)
{
    a->moving = false;
    a->homing = false;
    a->changed = true;
    if (fault >= 0)
        a->fault = fault;
    core_events = true;
}

/* One due step of one axis (ISR). */
/* The switch sits at the negative end: a negative move stops as soon as it closes. */
static bool stopped_at_limit(axis_t *a, uint8_t axis)
{
    a->at_limit = board_limit(axis);
    if (!(a->negative && a->at_limit))
        return false;
    if (a->homing) {
        a->position = 0;
        a->homed = true;
        finish(a, -1);
    } else {
        finish(a, axis);
    }
    return true;
}

static void step_axis(axis_t *a, uint8_t axis)
{
    if (stopped_at_limit(a, axis))
        return;
    board_step_pulse(axis);
    a->position += a->negative ? -1 : 1;
    a->index++;
    if (stopped_at_limit(a, axis))
        return;
    if (a->index >= a->total) {
        finish(a, a->homing ? (int32_t)(0x100 | axis) : -1);
        return;
    }
    uint32_t j = a->index; /* number of the next step */
    if (j < a->accel_steps) {
        uint32_t num = 2u * a->c + a->rem, den = 4u * j + 1u;
        a->c -= num / den;
        a->rem = num % den;
        if (a->c < a->c_min)
            a->c = a->c_min;
    } else if (j > a->decel_start) {
        /* Mirror of the ramp: step j gets accel interval m = total-1-j, from interval m+1
         * by c_m = c_{m+1} (1 + 2 / (4m + 3)); the last one is the exact c0. At j ==
         * decel_start the interval repeats the last ramp (or cruise) one. */
        uint32_t m = a->total - 1u - j;
        if (m == 0) {
            a->c = a->c0;
        } else {
            uint32_t num = 2u * a->c + a->rem, den = 4u * m + 3u;
            a->c += num / den;
            a->rem = num % den;
        }
    } else if (j == a->decel_start) {
        a->rem = 0;
    } else if (a->full_ramp) {
        a->c = a->c_min; /* cruise; a triangle keeps its peak interval instead */
    }
    a->due += a->c;
}

bool stepper_service(uint32_t now, uint32_t *next_due)
{
    bool any = false;
    uint32_t best = 0;
    for (uint8_t i = 0; i < STEPPER_AXES; i++) {
        axis_t *a = &axes[i];
        if (a->moving && (int32_t)(now - a->due) >= 0)
            step_axis(a, i);
        if (!a->moving)
            continue;
        if (!any || (int32_t)(a->due - best) < 0)
            best = a->due;
        any = true;
    }
    *next_due = best;
    return any;
}
