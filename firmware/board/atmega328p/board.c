/* ATmega328P board layer: registers and ISRs only; all logic is in core/.
 *
 * Timer1 runs at F_CPU/1 = 16 MHz (62.5 ns ticks) and is the single time base: ICP1 latches
 * the optical pulse in hardware, OCR1A schedules step pulses, OCR1B paces the 10 kHz control
 * tick, and its overflow count extends it to the 32-bit board_ticks(). */
#include <avr/interrupt.h>
#include <avr/io.h>

#include "board.h"
#include "board_avr.h"
#include "core.h"
#include "pins.h"
#include "protocol_gen.h"
#include "stepper.h"

static volatile uint16_t t1_high; /* Timer1 overflows: bits 16..31 of the timestamp */
static volatile int32_t encoder;
static uint8_t enc_prev;

/* The tick queue (board_avr.h): filled here, emptied by board_tick_pop() in the main loop. */
board_tick_t board_tq[BOARD_TICK_QUEUE];
volatile uint8_t board_tq_head, board_tq_tail;

/* 64 B: 5 pwm_set frames of a host burst. Not larger, though RAM would allow it: the CPU is the
 * limit (a pwm_set takes ~2200 cycles to parse, 1.4 control ticks), and a 128 B ring let the
 * exchange's bursts hold the main loop past its 16-slot tick queue (tests/test_mcu_avr.py: ticks
 * lost, 1 run in ~10), trading harmless lost pwm_sets (the next one replaces them) for lost
 * control ticks. A byte without room is counted (core_rx_overflows), its torn frame fails the
 * frame check and the parser resyncs. */
#define RX_RING 64u
static uint8_t rx_buf[RX_RING];
volatile uint8_t board_rx_head, board_rx_tail;

/* Extend a 16-bit Timer1 value read with interrupts off: an overflow may be pending (TOV1 set,
 * ISR not yet run); a small value then belongs to the next 65536 block. */
static inline __attribute__((always_inline)) uint32_t extend(uint16_t low)
{
    uint16_t high = t1_high;
    if ((TIFR1 & _BV(TOV1)) && low < 0x8000u)
        high++;
    return ((uint32_t)high << 16) | low;
}

uint32_t board_ticks(void)
{
    uint8_t s = SREG;
    cli();
    uint32_t t = extend(TCNT1);
    SREG = s;
    return t;
}

int32_t board_encoder(void)
{
    uint8_t s = SREG;
    cli();
    int32_t e = encoder;
    SREG = s;
    return e;
}

uint8_t board_irq_save(void)
{
    uint8_t s = SREG;
    cli();
    return s;
}

void board_irq_restore(uint8_t s) { SREG = s; }

void board_set_pwm(int16_t duty)
{
    /* 15-bit magnitude to the 8-bit compare value; a shift, not a division (a 32-bit divide
     * is ~600 cycles, and pwm_set comes every control tick). */
    uint16_t mag = (uint16_t)(duty < 0 ? -duty : duty);
    uint16_t scaled = (uint16_t)((mag + 64u) >> 7);
    uint8_t ocr = scaled > 255u ? 255u : (uint8_t)scaled;
    if (ocr == 0) {
        /* Fast PWM still emits a one-cycle spike at OCR0A = 0: disconnect and drive low. */
        TCCR0A &= (uint8_t)~_BV(COM0A1);
        PORTD &= (uint8_t)~_BV(MOTOR_PWM);
        return;
    }
    if (duty < 0)
        PORTD |= _BV(MOTOR_DIR);
    else
        PORTD &= (uint8_t)~_BV(MOTOR_DIR);
    OCR0A = ocr;
    TCCR0A |= _BV(COM0A1);
}

void board_set_laser(bool on)
{
    if (on)
        PORTD |= _BV(LASER);
    else
        PORTD &= (uint8_t)~_BV(LASER);
}

void board_step_dir(uint8_t axis, bool negative)
{
    uint8_t bit = axis ? _BV(DIR1) : _BV(DIR0);
    if (negative)
        PORTB |= bit;
    else
        PORTB &= (uint8_t)~bit;
}

void board_step_pulse(uint8_t axis)
{
    uint8_t bit = axis ? _BV(STEP1) : _BV(STEP0);
    PORTB |= bit;
    __builtin_avr_delay_cycles(16); /* >= 1 us high: A4988/DRV8825 minimum */
    PORTB &= (uint8_t)~bit;
}

bool board_limit(uint8_t axis)
{
    return !(PINC & (axis ? _BV(LIMIT1) : _BV(LIMIT0)));
}

/* Interrupts off. Fires the compare no earlier than 4 us from now (so a due time already
 * past is served at once) and no later than 2 ms (OCR1A is 16 bits: far steps re-arm). */
static void arm_step_timer(uint32_t due)
{
    uint32_t now = extend(TCNT1);
    int32_t d = (int32_t)(due - now);
    if (d < 64)
        d = 64;
    if (d > 0x8000)
        d = 0x8000;
    OCR1A = (uint16_t)(now + (uint32_t)d);
    TIFR1 = _BV(OCF1A);
    TIMSK1 |= _BV(OCIE1A);
}

void board_stepper_wake(void)
{
    uint8_t s = board_irq_save();
    arm_step_timer(extend(TCNT1));
    board_irq_restore(s);
}

void board_tx_kick(void)
{
    uint8_t s = board_irq_save();
    UCSR0B |= _BV(UDRIE0);
    board_irq_restore(s);
}

bool board_rx_pop(uint8_t *b)
{
    uint8_t t = board_rx_tail;
    if (t == board_rx_head)
        return false;
    *b = rx_buf[t & (RX_RING - 1u)];
    board_rx_tail = (uint8_t)(t + 1u);
    return true;
}

void board_init(void)
{
    DDRD = _BV(MOTOR_PWM) | _BV(MOTOR_DIR) | _BV(LASER) | _BV(PD1);
    PORTD = _BV(ZERO_INT) | _BV(PD0); /* pull-ups on inputs; outputs low = off */
    DDRB = _BV(STEP0) | _BV(DIR0) | _BV(STEP1) | _BV(DIR1);
    PORTB = _BV(OPTICAL_ICP);
    DDRC = 0;
    PORTC = _BV(ENC_A) | _BV(ENC_B) | _BV(LIMIT0) | _BV(LIMIT1);

    /* Timer0: fast PWM (mode 3), no prescaler: 16 MHz / 256 = 62.5 kHz, output disconnected. */
    TCCR0A = _BV(WGM01) | _BV(WGM00);
    TCCR0B = _BV(CS00);
    OCR0A = 0;

    /* Timer1: normal mode, /1, capture on rising edge with the 4-cycle noise canceller. */
    TCCR1A = 0;
    TCCR1B = _BV(ICNC1) | _BV(ICES1) | _BV(CS10);
    OCR1B = CORE_TICKS_PER_TICK;
    TIFR1 = 0xFF;
    TIMSK1 = _BV(ICIE1) | _BV(TOIE1) | _BV(OCIE1B);

    /* INT0 on the rising edge; pin change on the encoder pins. */
    EICRA = _BV(ISC01) | _BV(ISC00);
    EIMSK = _BV(INT0);
    enc_prev = PINC & 3u;
    PCMSK1 = _BV(PCINT8) | _BV(PCINT9);
    PCICR = _BV(PCIE1);

    /* UART 2 Mbaud: U2X, UBRR 0 -> 16 MHz / (8 * 1), 0 % error; 8N1. U2X is set before UBRR
     * is written: the chip does not care, but simavr derives its byte time on the UBRR write. */
    UCSR0A = _BV(U2X0);
    UBRR0 = 0;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

ISR(TIMER1_OVF_vect) { t1_high++; }

ISR(TIMER1_CAPT_vect) { core_pulse_isr(PULSE_CH_OPTICAL, extend(ICR1)); }

/* The zero pulse is timestamped here, so it carries the interrupt latency (a few us of
 * jitter when another ISR is running); the optical pulse, the one beta is measured from,
 * uses the hardware capture latch. */
ISR(INT0_vect) { core_pulse_isr(PULSE_CH_ZERO, extend(TCNT1)); }

/* The tick's time is its compare value: exact multiples of the period, whatever the latency. */
ISR(TIMER1_COMPB_vect)
{
    uint16_t due = OCR1B;
    uint8_t h = board_tq_head;
    if ((uint8_t)(h - board_tq_tail) < BOARD_TICK_QUEUE) {
        board_tick_t *slot = &board_tq[h & (BOARD_TICK_QUEUE - 1u)];
        slot->time = extend(due);
        slot->encoder = encoder;
        __asm__ volatile("" ::: "memory"); /* the slot before the index that publishes it */
        board_tq_head = (uint8_t)(h + 1u);
    } else {
        core_ticks_dropped++; /* the main loop is BOARD_TICK_QUEUE ticks behind: drop, not replay */
    }
    OCR1B = (uint16_t)(due + CORE_TICKS_PER_TICK);
}

ISR(TIMER1_COMPA_vect)
{
    uint32_t due;
    if (stepper_service(extend(TCNT1), &due))
        arm_step_timer(due);
    else
        TIMSK1 &= (uint8_t)~_BV(OCIE1A);
}

ISR(PCINT1_vect)
{
    /* Quadrature decoding by table: index = previous AB << 2 | new AB; 4 counts per line. */
    static const int8_t step[16] = {0, 1, -1, 0, -1, 0, 0, 1, 1, 0, 0, -1, 0, -1, 1, 0};
    uint8_t ab = PINC & 3u;
    encoder += step[(uint8_t)(enc_prev << 2) | ab];
    enc_prev = ab;
}

ISR(USART_RX_vect)
{
    uint8_t b = UDR0, h = board_rx_head;
    if ((uint8_t)(h - board_rx_tail) < RX_RING) {
        rx_buf[h & (RX_RING - 1u)] = b;
        board_rx_head = (uint8_t)(h + 1u);
    } else {
        core_rx_overflows++; /* the byte is lost: the frame check throws its frame out */
    }
}

ISR(USART_UDRE_vect)
{
    uint8_t b;
    if (core_tx_pop(&b))
        UDR0 = b;
    else
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
}
