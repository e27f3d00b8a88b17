/* The ATmega328P image in simavr with its USART0 on a pseudo-terminal, paced to wall time:
 * the host opens the pty like the board's serial port (tvsd/sim/simavr_mcu.py, McuLink).
 *
 *   simavr_pty firmware.elf
 *
 * stdout, one line each, flushed:
 *   pty /dev/pts/N                                   once, when the board runs
 *   out t_us=T pwm=0|1 ocr0a=N dir=0|1 laser=0|1     what the board drives, at each change
 *                                                    (pwm: OC0A connected to PD6)
 *   pace sim_ms=S wall_ms=W slipped_ms=L             every wall second
 *
 * Pacing: simulated time is held at or behind wall time (the firmware's watchdog and the
 * host's timeouts are both real ms): ahead, it waits for input or the wall clock; more than
 * SLIP_NS behind (this machine too slow or busy), it gives up the excess rather than run in
 * a burst to catch up, and counts it in slipped_ms. So the board's clock never runs faster
 * than real time; slipped_ms / wall_ms says how much slower it ran.
 *
 * The UART bridge is written here with simavr's UART IRQs rather than libsimavrparts' uart_pty
 * (its own thread, no pacing): one thread interleaves pacing, input and output. Host bytes go in
 * as fast as the UART's XON/XOFF allows (2 Mbaud in simulated time); the board's bytes go out
 * after each 100 us slice.
 * A slave fd stays open in raw mode: no echo before the host opens the pty, and no EIO on the
 * master when the host closes it. Ends on SIGTERM/SIGINT (status 0) or if the AVR stops. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_board.h"

#define F_CPU AVR_BOARD_F_CPU
#define SLICE_CYCLES 1600ull          /* 100 us: one control tick, the input latency bound */
#define SLIP_NS 20000000ll            /* behind wall time by more than 20 ms: drop the excess */
#define NS_PER_CYCLE_NUM 125ull       /* 1e9 / 16e6 = 125 / 2 */
#define NS_PER_CYCLE_DEN 2ull

/* data-space addresses of the ATmega328P registers that show the outputs (pins.h) */
#define REG_PORTD 0x2B
#define REG_TCCR0A 0x44
#define REG_OCR0A 0x47
#define COM0A1 7
#define PIN_MOTOR_DIR 7
#define PIN_LASER 4

static avr_t *avr;
static volatile sig_atomic_t stop;

static void on_signal(int sig) { (void)sig; stop = 1; }

/* host -> AVR */
static uint8_t inq[4096];
static size_t in_head, in_tail;
static avr_irq_t *uart_in;

/* AVR -> host: bytes of one slice; a line nobody reads drops them like a UART would */
static uint8_t outq[4096];
static size_t out_n;

static void on_uart_byte(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (out_n < sizeof outq)
        outq[out_n++] = (uint8_t)value;
}

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000ll + ts.tv_nsec;
}

static int64_t sim_ns(void)
{
    return (int64_t)(avr->cycle * NS_PER_CYCLE_NUM / NS_PER_CYCLE_DEN);
}

static void read_host(int master)
{
    while (in_head - in_tail < sizeof inq) {
        size_t at = in_head % sizeof inq;
        size_t room = sizeof inq - (in_head - in_tail);
        size_t n = sizeof inq - at < room ? sizeof inq - at : room;
        ssize_t got = read(master, inq + at, n);
        if (got <= 0)
            return; /* EAGAIN: nothing more for now */
        in_head += (size_t)got;
    }
}

static void write_host(int master)
{
    size_t done = 0;
    while (done < out_n) {
        ssize_t w = write(master, outq + done, out_n - done);
        if (w <= 0)
            break; /* the host does not read: the rest is lost, as on a real line */
        done += (size_t)w;
    }
    out_n = 0;
}

static void report_outputs(void)
{
    static int last = -1;
    uint8_t portd = avr->data[REG_PORTD];
    int pwm = (avr->data[REG_TCCR0A] >> COM0A1) & 1;
    int ocr = avr->data[REG_OCR0A];
    int dir = (portd >> PIN_MOTOR_DIR) & 1, laser = (portd >> PIN_LASER) & 1;
    int now = pwm | ocr << 1 | dir << 9 | laser << 10;
    if (now == last)
        return;
    last = now;
    printf("out t_us=%llu pwm=%d ocr0a=%d dir=%d laser=%d\n",
           (unsigned long long)(avr->cycle / (F_CPU / 1000000ull)), pwm, ocr, dir, laser);
    fflush(stdout);
}

static int open_pty(int *slave)
{
    int master = posix_openpt(O_RDWR | O_NOCTTY);
    if (master < 0 || grantpt(master) != 0 || unlockpt(master) != 0) {
        perror("simavr_pty: posix_openpt");
        return -1;
    }
    const char *name = ptsname(master);
    *slave = name ? open(name, O_RDWR | O_NOCTTY) : -1;
    struct termios tio;
    if (*slave < 0 || tcgetattr(*slave, &tio) != 0) {
        perror("simavr_pty: the pty's slave side");
        return -1;
    }
    cfmakeraw(&tio);
    tcsetattr(*slave, TCSANOW, &tio);
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    printf("pty %s\n", name);
    fflush(stdout);
    return master;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s firmware.elf\n", argv[0]);
        return 2;
    }
    avr = avr_board_boot(argv[1], "simavr_pty");
    if (!avr)
        return 2;
    avr->log = 1;
    uart_in = avr_board_uart0(avr, on_uart_byte);

    int slave;
    int master = open_pty(&slave);
    if (master < 0)
        return 2;
    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);

    int64_t t0 = now_ns(), slipped = 0, next_report = t0 + 1000000000ll;
    while (!stop) {
        int64_t wall = now_ns() - t0, ahead = sim_ns() - wall;
        if (ahead > 0) { /* wait for the wall clock, or for input to hand over early */
            struct pollfd p = {.fd = master, .events = POLLIN};
            struct timespec ts = {.tv_sec = ahead / 1000000000ll, .tv_nsec = ahead % 1000000000ll};
            ppoll(&p, 1, &ts, NULL);
        } else if (-ahead > SLIP_NS) {
            slipped += -ahead - SLIP_NS;
            t0 += -ahead - SLIP_NS;
        }
        read_host(master);
        while (uart_xon && in_tail != in_head)
            avr_raise_irq(uart_in, inq[in_tail++ % sizeof inq]);
        if (ahead > 0 && sim_ns() > now_ns() - t0)
            continue; /* still ahead: the input waits in the UART for its simulated time */
        avr_cycle_count_t end = avr->cycle + SLICE_CYCLES;
        while (avr->cycle < end) {
            int state = avr_run(avr);
            if (state == cpu_Done || state == cpu_Crashed) {
                fprintf(stderr, "simavr_pty: the AVR stopped (state %d) at cycle %llu\n", state,
                        (unsigned long long)avr->cycle);
                return 1;
            }
            while (uart_xon && in_tail != in_head)
                avr_raise_irq(uart_in, inq[in_tail++ % sizeof inq]);
        }
        report_outputs(); /* before the bytes: a reply the host sees follows its output line */
        write_host(master);
        int64_t t = now_ns();
        if (t >= next_report) {
            printf("pace sim_ms=%.1f wall_ms=%.1f slipped_ms=%.1f\n", sim_ns() / 1e6,
                   (t - t0 + slipped) / 1e6, slipped / 1e6);
            fflush(stdout);
            next_report = t + 1000000000ll;
        }
    }
    close(slave);
    close(master);
    return 0;
}
