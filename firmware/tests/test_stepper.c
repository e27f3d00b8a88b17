/* Stepper planner against the ideal constant-acceleration trapezoid.
 *
 * Tolerance: the first and last intervals are exact (f sqrt(2/a)); the ones between come from
 * Austin's recurrence, whose relative error per interval falls as 1/n^2, so the step times stay
 * within a small fraction of the first interval sqrt(2/a) of the ideal curve. We allow 5 % of
 * it (0.5 ms at 20000 sps^2); measured 2.4-2.7 %. Integer division adds < 1 tick per step. */
#include <math.h>

#include "check.h"
#include "fake_board.h"
#include "protocol_gen.h"
#include "stepper.h"

#define F ((double)BOARD_CLOCK_HZ)

static fake_frame_t last_fault; /* the last fault frame seen while running, id 0 if none */

/* Run until the axis stops, draining the TX ring as the host would and keeping faults. */
static void run_until_stopped(uint8_t axis, double max_s)
{
    uint32_t limit = (uint32_t)(max_s * F);
    uint32_t t0 = fb.now;
    last_fault.id = 0;
    do {
        fake_advance(CORE_TICKS_PER_TICK);
        fake_frame_t f;
        while (fake_recv(&f) >= 0)
            if (f.id == MSG_FAULT_ID)
                last_fault = f;
    } while (stepper_moving(axis) && fb.now - t0 < limit);
}

/* Ideal time of step n (1-based) of a trapezoid: accel a to rate v, cruise, decel. */
static double ideal_time(double n, double total, double v, double a)
{
    double ramp = fmin(v * v / (2 * a), total / 2);
    double vpk = sqrt(2 * a * ramp);
    double t_ramp = vpk / a;
    if (n <= ramp)
        return sqrt(2 * n / a);
    double t_cruise_end = t_ramp + (total - 2 * ramp) / vpk;
    if (n <= total - ramp)
        return t_ramp + (n - ramp) / vpk;
    double m = total - n; /* steps still to go: mirror of the ramp */
    return t_cruise_end + t_ramp - sqrt(2 * m / a);
}

static void check_profile(uint32_t n, double v, double a, double *peak_out)
{
    uint32_t t0 = fb.now;
    CHECK_EQ(stepper_move(0, (int32_t)n, (uint16_t)v, (uint16_t)a, t0), ACK_OK);
    run_until_stopped(0, 10.0);
    CHECK_EQ(fb.step_count[0], n);
    CHECK_EQ(stepper_position(0), (int32_t)n);
    double tol = 0.05 * sqrt(2 / a);
    double worst = 0, peak = 0;
    uint32_t worst_n = 0, nonmono = 0;
    for (uint32_t i = 0; i < n && i < FAKE_MAX_STEPS; i++) {
        double t = (fb.step_time[0][i] - t0) / F;
        double err = fabs(t - ideal_time(i + 1, n, v, a));
        if (err > worst) {
            worst = err;
            worst_n = i + 1;
        }
        if (i > 0) {
            uint32_t dt = fb.step_time[0][i] - fb.step_time[0][i - 1];
            peak = fmax(peak, F / dt);
            if (i + 1 < n) {
                uint32_t dt2 = fb.step_time[0][i + 1] - fb.step_time[0][i];
                /* speed rises in the first half and falls in the second, never the reverse */
                nonmono += (i < n / 2) ? dt2 > dt : dt2 < dt;
            }
        }
    }
    CHECK(worst <= tol, "step %u off the ideal trapezoid by %.6f s > %.6f s", worst_n, worst,
          tol);
    CHECK_EQ(nonmono, 0);
    CHECK(peak <= v * 1.0001, "peak %.1f sps above the commanded %.1f", peak, v);
    *peak_out = peak;
}

void test_stepper_trapezoid(void)
{
    fake_reset();
    double peak;
    /* 4000 sps at 20000 sps^2: 400 ramp steps (0.2 s) each side, 1200 cruise steps (0.3 s). */
    check_profile(2000, 4000, 20000, &peak);
    CHECK(peak >= 4000 * 0.999, "peak %.1f sps: cruise rate not reached", peak);
    double total = (fb.step_time[0][1999] - 1000) / F;
    CHECK(fabs(total - 0.7) < 0.05 * sqrt(2 / 20000.0), "move took %.4f s, ideal 0.7 s", total);
    /* A slower, softer move: 1000 sps at 2000 sps^2 (250 ramp steps, 0.5 s each side). */
    fake_reset();
    check_profile(1000, 1000, 2000, &peak);
    CHECK(peak >= 1000 * 0.999, "peak %.1f sps: cruise rate not reached", peak);
}

void test_stepper_triangle(void)
{
    fake_reset();
    double peak;
    /* 100 steps cannot reach 4000 sps at 20000 sps^2: peak sqrt(a N) = 1414 sps. */
    check_profile(100, 4000, 20000, &peak);
    CHECK(fabs(peak - sqrt(20000.0 * 100)) < 0.05 * sqrt(20000.0 * 100),
          "triangle peak %.1f sps, ideal %.1f", peak, sqrt(20000.0 * 100));
}

void test_stepper_negative(void)
{
    fake_reset();
    CHECK_EQ(stepper_move(1, -300, 2000, 10000, fb.now), ACK_OK);
    CHECK(fb.dir_negative[1], "direction pin must say negative");
    run_until_stopped(1, 2.0);
    CHECK_EQ(stepper_position(1), -300);
    CHECK_EQ(fb.pos[1], -300);
    CHECK_EQ(stepper_flags(1), 0);
}

void test_stepper_home(void)
{
    fake_reset();
    fb.pos[0] = 300; /* the carriage starts 300 steps above the switch */
    fb.limit_on[0] = true;
    fb.limit_pos[0] = 0;
    uint32_t t0 = fb.now;
    CHECK_EQ(stepper_home(0, t0), ACK_OK);
    CHECK_EQ(stepper_flags(0), STEPPER_FLAG_MOVING);
    run_until_stopped(0, 2.0);
    CHECK_EQ(fb.step_count[0], 300);
    CHECK_EQ(stepper_position(0), 0);
    CHECK_EQ(stepper_flags(0), STEPPER_FLAG_HOMED | STEPPER_FLAG_AT_LIMIT);
    double t = (fb.now - t0) / F, ideal = 300.0 / STEPPER_HOME_SPS;
    CHECK(fabs(t - ideal) < 0.002, "homing took %.4f s, ideal %.4f", t, ideal);
    CHECK_EQ(last_fault.id, 0);
    /* Moving away from the switch is allowed. */
    CHECK_EQ(stepper_move(0, 50, 1000, 5000, fb.now), ACK_OK);
    run_until_stopped(0, 1.0);
    CHECK_EQ(stepper_position(0), 50);
    CHECK_EQ(stepper_flags(0), STEPPER_FLAG_HOMED);
}

void test_stepper_limit(void)
{
    fake_reset();
    fb.limit_on[1] = true;
    fb.limit_pos[1] = -40;
    CHECK_EQ(stepper_move(1, -1000, 1000, 5000, fb.now), ACK_OK);
    run_until_stopped(1, 2.0);
    CHECK_EQ(stepper_position(1), -40); /* stopped on the switch, not through it */
    CHECK_EQ(stepper_flags(1), STEPPER_FLAG_AT_LIMIT);
    CHECK_EQ(last_fault.id, MSG_FAULT_ID);
    CHECK_EQ(last_fault.payload[0], FAULT_STEPPER_LIMIT);
    CHECK_EQ(proto_get_u16(last_fault.payload + 1), 1);
    /* Homing with no switch gives up after STEPPER_HOME_MAX_STEPS with a fault. */
    fake_reset();
    CHECK_EQ(stepper_home(0, fb.now), ACK_OK);
    run_until_stopped(0, STEPPER_HOME_MAX_STEPS / (double)STEPPER_HOME_SPS + 1);
    CHECK_EQ(stepper_position(0), -(int32_t)STEPPER_HOME_MAX_STEPS);
    CHECK_EQ(last_fault.id, MSG_FAULT_ID);
    CHECK_EQ(last_fault.payload[0], FAULT_STEPPER_LIMIT);
    CHECK_EQ(proto_get_u16(last_fault.payload + 1), 0x100);
}

void test_stepper_args(void)
{
    fake_reset();
    CHECK_EQ(stepper_move(STEPPER_AXES, 10, 100, 100, fb.now), ACK_BAD_ARG);
    CHECK_EQ(stepper_move(0, 10, 0, 100, fb.now), ACK_BAD_ARG);
    CHECK_EQ(stepper_move(0, 10, STEPPER_MAX_SPS + 1, 100, fb.now), ACK_BAD_ARG);
    CHECK_EQ(stepper_move(0, 10, 100, 0, fb.now), ACK_BAD_ARG);
    CHECK_EQ(stepper_move(0, 1000, 100, 100, fb.now), ACK_OK);
    CHECK_EQ(stepper_move(0, 10, 100, 100, fb.now), ACK_BUSY);
    CHECK_EQ(stepper_home(0, fb.now), ACK_BUSY);
}
