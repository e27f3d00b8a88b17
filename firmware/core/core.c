#include "core.h"

#include "board.h"
#include "dispatch.h"
#include "outputs.h"
#include "protocol_gen.h"
#include "pulse.h"
#include "stepper.h"

#ifndef BOARD_ID
#error "BOARD_ID must be defined by the board's build (protocol.yaml boards:)"
#endif

core_config_t core_cfg;
volatile bool core_events;
volatile uint16_t core_rx_overflows, core_ticks_dropped;
frame_parser_t core_parser;
static uint16_t state_count, stepper_count;
static uint16_t reported_drops; /* tx_dropped when the last tx_overflow fault went out */

void core_init(void)
{
    core_cfg = (core_config_t){CORE_DEFAULT_WATCHDOG_MS, CORE_DEFAULT_STATE_DIV,
                               CORE_DEFAULT_MAX_ON_MS};
    frame_parser_init(&core_parser, dispatch_frame);
    frame_tx_reset();
    pulse_reset();
    stepper_reset();
    outputs_reset();
    state_count = stepper_count = 0;
    reported_drops = 0;
    uint8_t irq = board_irq_save();
    core_rx_overflows = core_ticks_dropped = 0;
    outputs_clear_counts();
    board_irq_restore(irq);
}

void core_fault(uint8_t code, uint16_t detail)
{
    uint8_t p[MSG_FAULT_LEN];
    msg_fault_t m = {code, detail};
    msg_fault_pack(p, &m);
    frame_send(MSG_FAULT_ID, p, sizeof p);
}

void core_pulse_isr(uint8_t channel, uint32_t ticks)
{
    pulse_record(channel, ticks);
    core_events = true;
}

void core_stats(core_stats_t *s)
{
    s->rx_frames = core_parser.rx_frames;
    s->crc_errors = core_parser.crc_errors;
    s->resyncs = core_parser.resyncs;
    s->tx_dropped = frame_tx_dropped();
    s->duplicates = core_parser.duplicates;
    s->watchdog_expiries = outputs_watchdog_expiries(); /* main context, as the tick that counts it */
    uint8_t irq = board_irq_save(); /* ISR counters: a 16-bit read is two instructions on AVR */
    s->rx_overflows = core_rx_overflows;
    s->ticks_dropped = core_ticks_dropped;
    board_irq_restore(irq);
}

static void send_state(uint32_t now, int32_t encoder)
{
    uint8_t p[MSG_STATE_LEN];
    msg_state_t m = {now, (int16_t)encoder};
    msg_state_pack(p, &m);
    frame_send(MSG_STATE_ID, p, sizeof p);
}

void core_tick(uint32_t now, int32_t encoder)
{
    if (core_cfg.state_div && ++state_count >= core_cfg.state_div) {
        state_count = 0;
        send_state(now, encoder);
    }
    outputs_tick(now);
    if (++stepper_count >= STEPPER_STATE_EVERY) {
        stepper_count = 0;
        for (uint8_t i = 0; i < STEPPER_AXES; i++)
            if (stepper_moving(i))
                dispatch_send_stepper_state(i);
    }
    /* Report lost frames once the line has room again (else the fault would be lost too). */
    uint16_t drops = frame_tx_dropped();
    if (drops != reported_drops && frame_tx_free() >= 2u * (MSG_FAULT_LEN + PROTO_OVERHEAD)) {
        reported_drops = drops;
        core_fault(FAULT_TX_OVERFLOW, drops);
    }
}

void core_poll(void)
{
    /* Called after every wake-up (one per UART byte at 2 Mbaud): return at once if no ISR
     * left anything to report. */
    if (!core_events)
        return;
    core_events = false;
    pulse_event_t ev;
    while (pulse_pop(&ev)) {
        uint8_t p[MSG_PULSE_LEN];
        msg_pulse_t m = {ev.channel, ev.event_seq, ev.ticks};
        msg_pulse_pack(p, &m);
        frame_send(MSG_PULSE_ID, p, sizeof p);
    }
    for (uint8_t i = 0; i < STEPPER_AXES; i++) {
        int32_t fault = stepper_take_fault(i);
        if (fault >= 0)
            core_fault(FAULT_STEPPER_LIMIT, (uint16_t)fault);
        if (stepper_take_changed(i))
            dispatch_send_stepper_state(i);
    }
}
