/* Virtual MCU: the portable core on the host, behind a C API for ctypes
 * (tvsd/sim/virtual_mcu.py). Simulated time runs only when vmcu_advance_to() is called; it
 * counts the same 16 MHz ticks as the ATmega328P's Timer1, so frames are bit-identical.
 * Not thread-safe: the caller serialises calls. One instance per process (the core is
 * a singleton, as on the chip). */
#ifndef VMCU_H
#define VMCU_H
#include <stddef.h>
#include <stdint.h>

#define VMCU_API __attribute__((visibility("default")))

VMCU_API void vmcu_init(void);                      /* power-on: time 0, outputs off */
VMCU_API uint32_t vmcu_clock_hz(void);              /* tick rate of the timestamps */
VMCU_API uint64_t vmcu_now(void);                   /* ticks since vmcu_init */
/* Run the core up to tick t: 10 kHz control ticks and step pulses, in time order. */
VMCU_API void vmcu_advance_to(uint64_t t);
/* Host -> MCU bytes (the UART receive side), handled at the current time. */
VMCU_API void vmcu_rx_bytes(const uint8_t *buf, size_t n);
/* Host -> MCU bytes that were on the wire at tick t <= now (a heartbeat the host's pty handed
 * over late): handled with board_ticks() reading t. Only for frames whose handling is a stamp
 * (the heartbeat: the watchdog's start and the ack's mcu_ticks); t > now: as vmcu_rx_bytes. */
VMCU_API void vmcu_rx_bytes_at(const uint8_t *buf, size_t n, uint64_t t);
/* The watchdog's edge: 1 and the tick at which it cuts (last heartbeat + watchdog) and the
 * watchdog in ticks while armed, else 0. For the wire model's hold (tvsd/sim/virtual_mcu.py). */
VMCU_API int vmcu_watchdog(uint64_t *edge, uint64_t *ticks);
/* The wire model's deferral: while on, an expired watchdog does not cut at the control tick;
 * vmcu_watchdog_check cuts now if it has expired (a heartbeat sent after the edge came). */
VMCU_API void vmcu_watchdog_defer(int on);
VMCU_API void vmcu_watchdog_check(void);
/* MCU -> host bytes: copies up to max pending bytes, returns how many. */
VMCU_API size_t vmcu_tx_bytes(uint8_t *buf, size_t max);
/* Plant inputs. */
VMCU_API void vmcu_set_encoder(int32_t count);
/* The encoder from tick t0 to t1: linear from c0 to c1 counts (unwrapped), rounded at each control
 * tick strictly between them, and c1 at and after t1 until vmcu_set_encoder (at t1) ends it. */
VMCU_API void vmcu_encoder_ramp(uint64_t t0, double c0, uint64_t t1, double c1);
/* A sensor edge latched at tick t (t >= now: time advances to t first; t < now: the edge
 * was latched earlier, as the capture register does, and is reported now). */
VMCU_API void vmcu_pulse(uint8_t channel, uint64_t t);
/* Home switch of an axis: closed while the mechanism is at or below pos (enabled != 0). */
VMCU_API void vmcu_set_limit(uint8_t axis, int enabled, int32_t pos);
/* Outputs, read back by the plant. */
VMCU_API int16_t vmcu_pwm(void);                    /* -32767..32767 */
VMCU_API int vmcu_laser(void);
VMCU_API int32_t vmcu_stepper_position(uint8_t axis); /* the mechanism's position, in steps */
VMCU_API uint32_t vmcu_step_count(uint8_t axis);      /* pulses emitted */

#endif
