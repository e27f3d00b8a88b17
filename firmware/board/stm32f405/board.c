/* STM32F405 board layer: registers and ISRs only; all logic is in core/.
 *
 * Time base: SysTick at the 168 MHz core clock, reloading every 16 800 cycles (the 10 kHz control
 * tick), extended by its wrap count to the 32-bit board_ticks() (wraps every 25.6 s). SysTick is
 * core, so it behaves the same on the chip and in QEMU. Hardware timers on the chip:
 *   TIM1 CH1  motor PWM, 20 kHz, 8400 steps (168 MHz timer clock)
 *   TIM8      quadrature encoder x4, 16-bit, extended to 32 bits at each control tick
 *   TIM2 CH3/4 input capture of the optical and zero pulses (84 MHz), mapped onto board_ticks()
 *   TIM4      one-pulse timer that wakes the stepper service at the next step's due time
 * QEMU's netduinoplus2 (7.2) models SysTick, USART1 (receive interrupt only: the transmit side
 * is polled as well, see board_tx_service) and TIM2..5 as plain counters; RCC, GPIO, TIM1/TIM8,
 * input capture and the IWDG are absent there, so PWM, encoder, pulse and stepper timing are
 * exercised on the host build (board/host) instead. */
#include "board.h"

#include "board_stm32.h"
#include "core.h"
#include "pins.h"
#include "protocol_gen.h"
#include "stepper.h"
#include "stm32f405.h"

#define HCLK_HZ 168000000u
#define TIM_APB1_HZ 84000000u /* APB1 = HCLK/4, timers x2 */
#ifndef HSE_MHZ
#define HSE_MHZ 8u /* crystal; 12 on the Feather and pyboard: make ... HSE_MHZ=12 */
#endif
#ifndef BOARD_BAUD
#define BOARD_BAUD 2000000u
#endif
#define PCLK2_HZ 84000000u
#define SYSTICK_RELOAD (HCLK_HZ / CORE_TICK_HZ) /* 16 800 */
#define PWM_TOP 8400u                           /* 168 MHz / 8400 = 20 kHz */
#define STEP_TIM_DIV 16u                        /* TIM4 at 84 MHz / 8 = 10.5 MHz: 16 HCLK each */

_Static_assert(BOARD_CLOCK_HZ == HCLK_HZ, "board_ticks() counts HCLK cycles");
_Static_assert(SYSTICK_RELOAD * CORE_TICK_HZ == HCLK_HZ, "the control tick is whole cycles");

volatile board_load_t board_load;
static volatile uint32_t systick_base; /* board_ticks() at the last SysTick reload */
static volatile int32_t encoder;       /* TIM8 extended to 32 bits */
static uint16_t enc_last;

/* Control ticks due, each with its own time and encoder count: when the main loop runs late by
 * a tick or more (a stepper_move's planning, a burst of frames), every tick still reports its
 * own sample. Beyond TICK_QUEUE behind, ticks are dropped and counted (stats ticks_dropped; the
 * host sees a stamp gap), never replayed. */
#define TICK_QUEUE 8u
static uint32_t tq_time[TICK_QUEUE];
static int32_t tq_encoder[TICK_QUEUE];
static volatile uint32_t tq_head, tq_tail;

#define RX_RING 256u
static uint8_t rx_buf[RX_RING];
static volatile uint32_t rx_head, rx_tail;

/* --- time ------------------------------------------------------------------------------------- */

/* Interrupts off. A reload not yet handled (PENDSTSET) belongs to this reading: read again after
 * it, and count its period. */
static inline uint32_t ticks_locked(void)
{
    uint32_t v = SYST_CVR, base = systick_base;
    if (SCB_ICSR & SCB_ICSR_PENDSTSET) {
        v = SYST_CVR;
        base += SYSTICK_RELOAD;
    }
    return base + (SYSTICK_RELOAD - 1u - v);
}

uint32_t board_ticks(void)
{
    uint32_t s = irq_disable_save();
    uint32_t t = ticks_locked();
    irq_restore(s);
    return t;
}

static inline int32_t encoder_locked(void)
{
    uint16_t c = (uint16_t)TIM8->CNT;
    int32_t e = encoder + (int16_t)(uint16_t)(c - enc_last); /* < 32768 counts per 100 us */
    encoder = e;
    enc_last = c;
    return e;
}

int32_t board_encoder(void)
{
    uint32_t s = irq_disable_save();
    int32_t e = encoder_locked();
    irq_restore(s);
    return e;
}

uint8_t board_irq_save(void) { return (uint8_t)irq_disable_save(); }
void board_irq_restore(uint8_t s) { irq_restore(s); }

/* --- outputs ---------------------------------------------------------------------------------- */

void board_set_pwm(int16_t duty)
{
    uint32_t mag = (uint32_t)(duty < 0 ? -(int32_t)duty : duty);
    uint32_t ccr = (mag * (PWM_TOP + 1u)) >> 15; /* 32767 -> 8400 = always on */
    if (ccr)
        GPIOB->BSRR = duty < 0 ? 1u << PIN_MOTOR_DIR : 1u << (PIN_MOTOR_DIR + 16u);
    TIM1->CCR[0] = ccr; /* 0: low for the whole period (no spike in PWM mode 1) */
    board_load.pwm_duty = duty;
}

void board_set_laser(bool on)
{
    GPIOB->BSRR = on ? 1u << PIN_LASER : 1u << (PIN_LASER + 16u);
    board_load.laser = on;
}

void board_step_dir(uint8_t axis, bool negative)
{
    uint32_t pin = axis ? PIN_DIR1 : PIN_DIR0;
    GPIOC->BSRR = negative ? 1u << pin : 1u << (pin + 16u);
}

void board_step_pulse(uint8_t axis)
{
    uint32_t pin = axis ? PIN_STEP1 : PIN_STEP0;
    GPIOC->BSRR = 1u << pin;
    for (uint32_t i = 0; i < 120u; i++) /* >= 2 us high at 168 MHz: A4988 1 us, DRV8825 1.9 us */
        __asm volatile("nop");
    GPIOC->BSRR = 1u << (pin + 16u);
}

bool board_limit(uint8_t axis)
{
    return !(GPIOC->IDR & (1u << (axis ? PIN_LIMIT1 : PIN_LIMIT0)));
}

/* --- stepper timer ---------------------------------------------------------------------------- */

/* Interrupts off. TIM4 in one-pulse mode fires its update no earlier than 4 us from now (a due
 * time already past is served at once) and no later than 6 ms (16-bit: far steps re-arm). */
static void arm_step_timer(uint32_t due)
{
    int32_t d = (int32_t)(due - ticks_locked());
    if (d < 672)
        d = 672;
    uint32_t n = (uint32_t)d / STEP_TIM_DIV;
    if (n > 0xFFFFu)
        n = 0xFFFFu;
    TIM4->CR1 = TIM_CR1_URS | TIM_CR1_OPM;
    TIM4->ARR = n;
    TIM4->CNT = 0;
    TIM4->SR = 0;
    TIM4->DIER = TIM_DIER_UIE;
    TIM4->CR1 = TIM_CR1_URS | TIM_CR1_OPM | TIM_CR1_CEN;
}

void board_stepper_wake(void)
{
    uint32_t s = irq_disable_save();
    arm_step_timer(ticks_locked());
    irq_restore(s);
}

void TIM4_IRQHandler(void)
{
    TIM4->SR = 0;
    uint32_t due;
    if (stepper_service(board_ticks(), &due)) {
        uint32_t s = irq_disable_save();
        arm_step_timer(due);
        irq_restore(s);
    } else {
        TIM4->DIER = 0;
        TIM4->CR1 = TIM_CR1_URS | TIM_CR1_OPM;
    }
}

/* --- pulses ----------------------------------------------------------------------------------- */

/* A capture latched at TIM2 count `ccr` (84 MHz, two HCLK each): its board_ticks() is now minus
 * its age, both clocks read together. */
static uint32_t capture_time(uint32_t ccr)
{
    uint32_t s = irq_disable_save();
    uint32_t now = ticks_locked(), cnt = TIM2->CNT;
    irq_restore(s);
    return now - 2u * (cnt - ccr);
}

void TIM2_IRQHandler(void)
{
    uint32_t sr = TIM2->SR;
    if (sr & TIM_SR_CC3IF) /* reading CCR clears the flag */
        core_pulse_isr(PULSE_CH_OPTICAL, capture_time(TIM2->CCR[2]));
    if (sr & TIM_SR_CC4IF)
        core_pulse_isr(PULSE_CH_ZERO, capture_time(TIM2->CCR[3]));
}

/* --- control tick ----------------------------------------------------------------------------- */

/* The tick's time is the reload instant: exact multiples of the period, whatever the latency. */
void SysTick_Handler(void)
{
    uint32_t t = systick_base + SYSTICK_RELOAD;
    systick_base = t;
    int32_t e = encoder_locked();
    uint32_t h = tq_head;
    if (h - tq_tail < TICK_QUEUE) {
        tq_time[h % TICK_QUEUE] = t;
        tq_encoder[h % TICK_QUEUE] = e;
        __asm volatile("" ::: "memory"); /* the slot before the index that publishes it */
        tq_head = h + 1u;
    } else {
        core_ticks_dropped++; /* the main loop is TICK_QUEUE ticks behind: drop, not replay */
    }
}

bool board_tick_pending(void) { return tq_head != tq_tail; }

bool board_tick_pop(uint32_t *t, int32_t *e)
{
    uint32_t tail = tq_tail;
    if (tail == tq_head)
        return false;
    __asm volatile("" ::: "memory");
    *t = tq_time[tail % TICK_QUEUE];
    *e = tq_encoder[tail % TICK_QUEUE];
    tq_tail = tail + 1u; /* the ISR writes a slot only once the tail has passed it */
    return true;
}

/* --- host link -------------------------------------------------------------------------------- */

void USART1_IRQHandler(void)
{
    uint32_t sr = USART1->SR;
    if (sr & (USART_SR_RXNE | USART_SR_ORE)) { /* reading DR clears both; an overrun's byte is lost */
        uint8_t b = (uint8_t)USART1->DR;
        if (sr & USART_SR_ORE)
            core_rx_overflows++; /* the byte before this one never reached DR */
        uint32_t h = rx_head;
        if (h - rx_tail < RX_RING) {
            rx_buf[h & (RX_RING - 1u)] = b;
            rx_head = h + 1u;
        } else {
            core_rx_overflows++; /* the byte is lost: the frame check throws its frame out */
        }
    }
    if ((USART1->CR1 & USART_CR1_TXEIE) && (sr & USART_SR_TXE)) {
        uint8_t b;
        if (core_tx_pop(&b))
            USART1->DR = b;
        else
            USART1->CR1 &= ~USART_CR1_TXEIE;
    }
}

bool board_rx_pending(void) { return rx_head != rx_tail; }

bool board_rx_pop(uint8_t *b)
{
    uint32_t t = rx_tail;
    if (t == rx_head)
        return false;
    *b = rx_buf[t & (RX_RING - 1u)];
    rx_tail = t + 1u;
    return true;
}

void board_tx_kick(void)
{
    uint32_t s = irq_disable_save();
    USART1->CR1 |= USART_CR1_TXEIE;
    irq_restore(s);
}

/* From the main loop: feed the data register while it is empty. On the chip this adds at most a
 * byte beside the TXE interrupt; QEMU's USART raises no TXE interrupt (its transmit is
 * synchronous, TXE always set), so there this loop is what sends. */
void board_tx_service(void)
{
    uint32_t s = irq_disable_save();
    uint8_t b;
    while ((USART1->SR & USART_SR_TXE) && core_tx_pop(&b))
        USART1->DR = b;
    irq_restore(s);
}

/* --- set-up ----------------------------------------------------------------------------------- */

static void gpio_mode(gpio_t *g, uint32_t pin, uint32_t mode, uint32_t af, uint32_t pull)
{
    g->MODER = (g->MODER & ~(3u << (2u * pin))) | (mode << (2u * pin));
    g->PUPDR = (g->PUPDR & ~(3u << (2u * pin))) | (pull << (2u * pin));
    g->OSPEEDR |= 2u << (2u * pin); /* fast: clean 2 Mbaud and step edges */
    volatile uint32_t *afr = &g->AFR[pin >> 3];
    uint32_t sh = 4u * (pin & 7u);
    *afr = (*afr & ~(0xFu << sh)) | (af << sh);
}

/* HSE -> PLL -> 168 MHz, APB1 42 MHz, APB2 84 MHz, flash 5 wait states with the caches. */
static bool clock_init(void)
{
    /* HSION's reset value is 1 on every STM32F4: an RCC reading 0 is QEMU's, which has no RCC
     * model and already runs the core clock (SysTick) at 168 MHz. */
    if (RCC_CR == 0u)
        return true;
    RCC_CR |= RCC_CR_HSEON;
    for (uint32_t i = 0; !(RCC_CR & RCC_CR_HSERDY); i++)
        if (i > 1000000u) /* no crystal: stay off rather than stamp with the wrong clock */
            return false;
    RCC_PLLCFGR = HSE_MHZ | (336u << 6) | (0u << 16) /* P = 2 */ | RCC_PLLCFGR_SRC_HSE | (7u << 24);
    FLASH_ACR = FLASH_ACR_LATENCY_5WS | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
    RCC_CFGR = RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_PPRE2_DIV2;
    RCC_CR |= RCC_CR_PLLON;
    for (uint32_t i = 0; !(RCC_CR & RCC_CR_PLLRDY); i++)
        if (i > 1000000u)
            return false;
    RCC_CFGR |= RCC_CFGR_SW_PLL;
    while ((RCC_CFGR & RCC_CFGR_SWS_MASK) != RCC_CFGR_SWS_PLL) {
    }
    return true;
}

bool board_init(void)
{
    if (!clock_init())
        return false;
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOA | RCC_AHB1ENR_GPIOB | RCC_AHB1ENR_GPIOC;
    RCC_APB1ENR |= RCC_APB1ENR_TIM2 | RCC_APB1ENR_TIM4;
    RCC_APB2ENR |= RCC_APB2ENR_TIM1 | RCC_APB2ENR_TIM8 | RCC_APB2ENR_USART1;

    /* Outputs low (off) before they become outputs. */
    GPIOB->BSRR = (1u << (PIN_MOTOR_DIR + 16u)) | (1u << (PIN_LASER + 16u));
    GPIOC->BSRR = 0xFu << 16; /* STEP0, DIR0, STEP1, DIR1 */
    gpio_mode(GPIOB, PIN_MOTOR_DIR, GPIO_MODE_OUT, 0, 0);
    gpio_mode(GPIOB, PIN_LASER, GPIO_MODE_OUT, 0, 0);
    gpio_mode(GPIOC, PIN_STEP0, GPIO_MODE_OUT, 0, 0);
    gpio_mode(GPIOC, PIN_DIR0, GPIO_MODE_OUT, 0, 0);
    gpio_mode(GPIOC, PIN_STEP1, GPIO_MODE_OUT, 0, 0);
    gpio_mode(GPIOC, PIN_DIR1, GPIO_MODE_OUT, 0, 0);
    gpio_mode(GPIOC, PIN_LIMIT0, GPIO_MODE_IN, 0, GPIO_PULL_UP);
    gpio_mode(GPIOC, PIN_LIMIT1, GPIO_MODE_IN, 0, GPIO_PULL_UP);
    gpio_mode(GPIOA, PIN_MOTOR_PWM, GPIO_MODE_AF, 1, 0);
    gpio_mode(GPIOC, PIN_ENC_A, GPIO_MODE_AF, 3, GPIO_PULL_UP);
    gpio_mode(GPIOC, PIN_ENC_B, GPIO_MODE_AF, 3, GPIO_PULL_UP);
    gpio_mode(GPIOB, PIN_OPTICAL, GPIO_MODE_AF, 1, GPIO_PULL_UP);
    gpio_mode(GPIOB, PIN_ZERO, GPIO_MODE_AF, 1, GPIO_PULL_UP);
    gpio_mode(GPIOA, PIN_USART_TX, GPIO_MODE_AF, 7, 0);
    gpio_mode(GPIOA, PIN_USART_RX, GPIO_MODE_AF, 7, GPIO_PULL_UP);

    /* TIM1 CH1: PWM mode 1, preloaded compare, 20 kHz, output enabled, duty 0. */
    TIM1->PSC = 0;
    TIM1->ARR = PWM_TOP - 1u;
    TIM1->CCR[0] = 0;
    TIM1->CCMR1 = (6u << 4) | (1u << 3); /* OC1M = PWM 1, OC1PE */
    TIM1->CCER = 1u << 0;                /* CC1E */
    TIM1->BDTR = TIM_BDTR_MOE;
    TIM1->EGR = TIM_EGR_UG;
    TIM1->CR1 = TIM_CR1_ARPE | TIM_CR1_CEN;

    /* TIM8: encoder mode x4 on TI1/TI2, input filter 4 samples at fDTS (24 ns glitches out). */
    TIM8->ARR = 0xFFFFu;
    TIM8->CCMR1 = (1u << 0) | (1u << 8) | (2u << 4) | (2u << 12); /* CC1S=TI1, CC2S=TI2, IC1F/IC2F */
    TIM8->SMCR = TIM_SMCR_SMS_ENC3;
    TIM8->CR1 = TIM_CR1_CEN;
    enc_last = (uint16_t)TIM8->CNT;

    /* TIM2: free-running 32-bit at 84 MHz; CH3/CH4 capture rising edges of TI3/TI4, filtered. */
    TIM2->PSC = 0;
    TIM2->ARR = 0xFFFFFFFFu;
    TIM2->CCMR2 = (1u << 0) | (2u << 4) | (1u << 8) | (2u << 12); /* CC3S=TI3, CC4S=TI4, filter */
    TIM2->CCER = (1u << 8) | (1u << 12);                          /* CC3E, CC4E, rising */
    TIM2->EGR = TIM_EGR_UG;
    TIM2->SR = 0;
    TIM2->DIER = TIM_DIER_CC3IE | TIM_DIER_CC4IE;
    TIM2->CR1 = TIM_CR1_CEN;

    /* TIM4: the stepper one-pulse timer, prescaled to 10.5 MHz (PSC loads on the UG event). */
    TIM4->PSC = STEP_TIM_DIV / 2u - 1u;
    TIM4->CR1 = TIM_CR1_URS | TIM_CR1_OPM;
    TIM4->EGR = TIM_EGR_UG;
    TIM4->SR = 0;

    /* USART1: 2 Mbaud from PCLK2 84 MHz (USARTDIV 2.625, exact), 8N1, receive interrupt. */
    USART1->BRR = (PCLK2_HZ + BOARD_BAUD / 2u) / BOARD_BAUD;
    USART1->CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    return true;
}

void board_start(void)
{
    /* Priorities (upper 4 bits): the UART (no FIFO: a byte every 5 us at 2 Mbaud) and the control
     * tick first, neither preempting the other: both are a few dozen cycles, and nothing can then
     * see the tick's time base half updated. Then the captures, then the stepper timer. */
    NVIC_IPR8(IRQ_USART1) = 0x00;
    SCB_SHPR3 = (SCB_SHPR3 & 0x00FFFFFFu) | (0x00u << 24);
    NVIC_IPR8(IRQ_TIM2) = 0x40;
    NVIC_IPR8(IRQ_TIM4) = 0x80;
    NVIC_ISER(IRQ_USART1 / 32u) = 1u << (IRQ_USART1 % 32u);
    NVIC_ISER(IRQ_TIM2 / 32u) = 1u << (IRQ_TIM2 % 32u);
    NVIC_ISER(IRQ_TIM4 / 32u) = 1u << (IRQ_TIM4 % 32u);

    SYST_RVR = SYSTICK_RELOAD - 1u;
    SYST_CVR = 0;
    SYST_CSR = SYST_CSR_CLKSOURCE | SYST_CSR_TICKINT | SYST_CSR_ENABLE;

    /* IWDG: LSI 32 kHz / 4, reload 240 = 30 ms; the main loop kicks it every pass. */
    IWDG_KR = 0x5555u;
    IWDG_PR = 0;
    IWDG_RLR = 240u;
    IWDG_KR = 0xCCCCu;
    irq_restore(0);
}

void board_watchdog_kick(void) { IWDG_KR = 0xAAAAu; }
