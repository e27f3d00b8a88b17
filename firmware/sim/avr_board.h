/* What both simavr programs share (simavr_smoke.c, simavr_pty.c): the ATmega328P image booted at
 * 16 MHz, and its USART0 hooked for binary frames (bytes out to a callback, bytes in paced by
 * the UART's XON/XOFF). Header-only: each program is one file. */
#ifndef AVR_BOARD_H
#define AVR_BOARD_H
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_io.h"
#include "sim_irq.h"

#define AVR_BOARD_F_CPU 16000000ull

static bool uart_xon; /* the UART takes another input byte */

static void avr_board_on_xon(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xon = true;
}

static void avr_board_on_xoff(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xon = false;
}

/* The image in `elf` on a 16 MHz ATmega328P; NULL after one line on stderr. */
static avr_t *avr_board_boot(const char *elf, const char *who)
{
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "%s: cannot read the firmware image %s\n", who, elf);
        return NULL;
    }
    strcpy(fw.mmcu, "atmega328p");
    fw.frequency = (uint32_t)AVR_BOARD_F_CPU;
    avr_t *avr = avr_make_mcu_by_name(fw.mmcu);
    if (!avr || avr_init(avr) != 0) {
        fprintf(stderr, "%s: simavr has no %s core\n", who, fw.mmcu);
        return NULL;
    }
    avr_load_firmware(avr, &fw);
    return avr;
}

/* USART0 for frames: no stdio echo; each byte the AVR sends to `on_byte`; returns the input IRQ
 * (raise it with a byte only while uart_xon). */
static avr_irq_t *avr_board_uart0(avr_t *avr, avr_irq_notify_t on_byte)
{
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(uint32_t)AVR_UART_FLAG_STDIO; /* binary frames, not console text */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            on_byte, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            avr_board_on_xon, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            avr_board_on_xoff, NULL);
    return avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
}
#endif
