#include <stdio.h>

#include "check.h"

int check_failures, check_count;

#define TESTS(X)                                                                           \
    X(test_crc_vectors) X(test_frame_good) X(test_frame_resync) X(test_frame_bad_len) X(test_frame_fuzz) \
    X(test_dispatch_identify) X(test_dispatch_bad_frame) X(test_dispatch_heartbeat_pwm) X(test_dispatch_duplicates) \
    X(test_dispatch_config) X(test_state_frames) X(test_tx_overflow) X(test_pulse_seq)      \
    X(test_watchdog_cutoff) X(test_watchdog_sample_before_heartbeat) X(test_watchdog_kept_alive) X(test_max_on)                     \
    X(test_stepper_trapezoid) X(test_stepper_triangle) X(test_stepper_negative)            \
    X(test_stepper_home) X(test_stepper_limit) X(test_stepper_args)

#define X(name) void name(void);
TESTS(X)
#undef X

int main(void)
{
#define X(name)                                                                            \
    {                                                                                      \
        int before = check_failures;                                                       \
        name();                                                                            \
        printf("%-28s %s\n", #name, check_failures == before ? "ok" : "FAIL");            \
    }
    TESTS(X)
#undef X
    printf("%d checks, %d failed\n", check_count, check_failures);
    return check_failures ? 1 : 0;
}
