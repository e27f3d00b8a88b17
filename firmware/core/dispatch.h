#ifndef DISPATCH_H
#define DISPATCH_H
#include <stdint.h>

#include "frame.h"

/* Run the handler of a good frame; unknown id or wrong length -> fault bad_frame. */
void dispatch_frame(const frame_t *f);
void dispatch_send_stepper_state(uint8_t axis);

#endif
