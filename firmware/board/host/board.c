/* Host board layer: the virtual MCU. Time is simulated; the "pins" are variables read back
 * through vmcu.h. */
#include <math.h>
#include <string.h>

#include "board.h"
#include "core.h"
#include "outputs.h"
#include "stepper.h"
#include "vmcu.h"

static struct {
    uint64_t now, next_tick, step_due;
    bool step_active;
    int32_t encoder;
    /* The encoder between two plant feeds: linear from c0 at t0 to c1 at t1 (counts, unwrapped),
     * sampled at each control tick strictly inside, as a real encoder counts continuously. */
    bool ramp;
    uint64_t ramp_t0, ramp_t1;
    double ramp_c0, ramp_c1;
    int16_t pwm;
    bool laser;
    bool dir_negative[STEPPER_AXES];
    int32_t pos[STEPPER_AXES];
    uint32_t steps[STEPPER_AXES];
    bool limit_on[STEPPER_AXES];
    int32_t limit_pos[STEPPER_AXES];
} vm;

uint32_t board_ticks(void) { return (uint32_t)vm.now; }
int32_t board_encoder(void) { return vm.encoder; }
void board_set_pwm(int16_t duty) { vm.pwm = duty; }
void board_set_laser(bool on) { vm.laser = on; }
void board_step_dir(uint8_t axis, bool negative) { vm.dir_negative[axis] = negative; }
void board_tx_kick(void) {}
uint8_t board_irq_save(void) { return 0; }
void board_irq_restore(uint8_t s) { (void)s; }

void board_step_pulse(uint8_t axis)
{
    vm.steps[axis]++;
    vm.pos[axis] += vm.dir_negative[axis] ? -1 : 1;
}

bool board_limit(uint8_t axis)
{
    return vm.limit_on[axis] && vm.pos[axis] <= vm.limit_pos[axis];
}

/* The step timer: the core's 32-bit due time, placed on the 64-bit simulated clock. */
static void schedule(uint32_t due)
{
    vm.step_due = vm.now + (uint64_t)(uint32_t)(due - (uint32_t)vm.now);
}

void board_stepper_wake(void)
{
    uint32_t due;
    vm.step_active = stepper_service((uint32_t)vm.now, &due);
    if (vm.step_active)
        schedule(due);
}

VMCU_API void vmcu_init(void)
{
    memset(&vm, 0, sizeof vm);
    vm.next_tick = CORE_TICKS_PER_TICK;
    core_init();
}

VMCU_API uint32_t vmcu_clock_hz(void) { return BOARD_CLOCK_HZ; }
VMCU_API uint64_t vmcu_now(void) { return vm.now; }

static int32_t encoder_now(void)
{
    if (!vm.ramp || vm.now <= vm.ramp_t0)
        return vm.encoder;
    /* At the ramp's end and past it the shaft is at c1 even before the plant's feed sets the
     * count: a zero pulse latched on that very tick advances the core through it first (a
     * crossing within one timer tick of a 1 ms feed; the sample then held the count from the
     * feed before, 1 ms old, once in 31 SIL identify runs: a `cogging` at z 95). */
    if (vm.now >= vm.ramp_t1)
        return (int32_t)(uint32_t)(int64_t)llround(vm.ramp_c1);
    double f = (double)(vm.now - vm.ramp_t0) / (double)(vm.ramp_t1 - vm.ramp_t0);
    double c = vm.ramp_c0 + f * (vm.ramp_c1 - vm.ramp_c0);
    return (int32_t)(uint32_t)(int64_t)llround(c); /* wraps like the chip's 32-bit count */
}

VMCU_API void vmcu_advance_to(uint64_t t)
{
    while (true) {
        bool is_step = vm.step_active && vm.step_due < vm.next_tick;
        uint64_t at = is_step ? vm.step_due : vm.next_tick;
        if (at > t)
            break;
        vm.now = at;
        if (is_step) {
            board_stepper_wake();
        } else {
            vm.next_tick += CORE_TICKS_PER_TICK;
            core_tick((uint32_t)vm.now, encoder_now());
        }
        core_poll();
    }
    if (t > vm.now)
        vm.now = t;
}

VMCU_API void vmcu_rx_bytes(const uint8_t *buf, size_t n)
{
    for (size_t i = 0; i < n; i++)
        core_rx_byte(buf[i]);
    core_poll();
}

VMCU_API void vmcu_rx_bytes_at(const uint8_t *buf, size_t n, uint64_t t)
{
    core_poll(); /* what is pending goes out at the present time */
    uint64_t now = vm.now;
    if (t < now)
        vm.now = t; /* board_ticks() reads the time the bytes were on the wire */
    for (size_t i = 0; i < n; i++)
        core_rx_byte(buf[i]);
    core_poll();
    vm.now = now;
}

VMCU_API int vmcu_watchdog(uint64_t *edge, uint64_t *ticks)
{
    uint32_t last, wd;
    if (!outputs_watchdog_window(&last, &wd))
        return 0;
    int32_t age = (int32_t)((uint32_t)vm.now - last); /* the 32-bit stamp placed near now */
    *edge = (uint64_t)((int64_t)vm.now - age) + wd;
    *ticks = wd;
    return 1;
}

VMCU_API void vmcu_watchdog_defer(int on) { outputs_watchdog_defer(on != 0); }

VMCU_API void vmcu_watchdog_check(void)
{
    outputs_watchdog_check((uint32_t)vm.now);
    core_poll();
}

VMCU_API size_t vmcu_tx_bytes(uint8_t *buf, size_t max)
{
    size_t n = 0;
    while (n < max && core_tx_pop(&buf[n]))
        n++;
    return n;
}

VMCU_API void vmcu_set_encoder(int32_t count)
{
    vm.encoder = count;
    vm.ramp = false;
}

VMCU_API void vmcu_encoder_ramp(uint64_t t0, double c0, uint64_t t1, double c1)
{
    vm.ramp = t1 > t0;
    vm.ramp_t0 = t0;
    vm.ramp_t1 = t1;
    vm.ramp_c0 = c0;
    vm.ramp_c1 = c1;
}

VMCU_API void vmcu_pulse(uint8_t channel, uint64_t t)
{
    if (t > vm.now)
        vmcu_advance_to(t);
    core_pulse_isr(channel, (uint32_t)t);
    core_poll();
}

VMCU_API void vmcu_set_limit(uint8_t axis, int enabled, int32_t pos)
{
    if (axis >= STEPPER_AXES)
        return;
    vm.limit_on[axis] = enabled != 0;
    vm.limit_pos[axis] = pos;
}

VMCU_API int16_t vmcu_pwm(void) { return vm.pwm; }
VMCU_API int vmcu_laser(void) { return vm.laser; }

VMCU_API int32_t vmcu_stepper_position(uint8_t axis)
{
    return axis < STEPPER_AXES ? vm.pos[axis] : 0;
}

VMCU_API uint32_t vmcu_step_count(uint8_t axis)
{
    return axis < STEPPER_AXES ? vm.steps[axis] : 0;
}
