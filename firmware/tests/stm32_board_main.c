/* The STM32F405 board layer (board/stm32f405/board.c) on the host, against its registers mapped
 * as memory at their real addresses: what QEMU does not model (TIM1 PWM, TIM8 encoder, TIM2
 * capture, the TIM4 step timer set-up, the time base's arithmetic) is checked here at the
 * register level. Linked with the real core. */
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>

#include "board.h"
#include "board_stm32.h"
#include "check.h"
#include "core.h"
#include "protocol_gen.h"
#include "pulse.h"
#include "stm32f405.h"

int check_failures, check_count;
uint32_t host_primask;

void SysTick_Handler(void);
void TIM2_IRQHandler(void);
void TIM4_IRQHandler(void);
void USART1_IRQHandler(void);

static int map_at(uintptr_t addr, size_t len)
{
    void *p = mmap((void *)addr, len, PROT_READ | PROT_WRITE,
                   MAP_PRIVATE | MAP_ANONYMOUS | MAP_FIXED_NOREPLACE, -1, 0);
    return p == (void *)addr ? 0 : -1;
}

static void test_init_registers(void)
{
    CHECK(board_init(), "RCC reads 0 here: the clock set-up is skipped, as in QEMU");
    CHECK_EQ(TIM1->ARR, 8399);                    /* 168 MHz / 8400 = 20 kHz */
    CHECK_EQ(TIM1->CCMR1 & 0x78u, (6u << 4) | 8u); /* PWM mode 1, preload */
    CHECK(TIM1->BDTR & TIM_BDTR_MOE, "advanced timer outputs enabled");
    CHECK_EQ(TIM8->SMCR & 7u, 3);                  /* encoder mode x4 */
    CHECK_EQ(TIM2->CCER, (1u << 8) | (1u << 12));  /* CC3, CC4 capture, rising */
    CHECK_EQ(TIM2->DIER, TIM_DIER_CC3IE | TIM_DIER_CC4IE);
    CHECK_EQ(TIM4->PSC, 7);                        /* 84 MHz / 8 */
    CHECK_EQ(USART1->BRR, 42);                     /* 84 MHz / 2 Mbaud = 2.625 = 0x2A */
    CHECK_EQ((GPIOA->MODER >> 16) & 3u, GPIO_MODE_AF); /* PA8 TIM1_CH1 */
    CHECK_EQ(GPIOA->AFR[1] & 0xFu, 1);
    CHECK_EQ((GPIOA->AFR[1] >> 4) & 0xFu, 7);      /* PA9 USART1_TX */
    CHECK_EQ((GPIOC->AFR[0] >> 24) & 0xFu, 3);     /* PC6 TIM8_CH1 */
    CHECK_EQ((GPIOB->AFR[1] >> 8) & 0xFu, 1);      /* PB10 TIM2_CH3 */
    board_start();
    CHECK_EQ(SYST_RVR, 16799);
    CHECK_EQ(SYST_CSR, 7);
    CHECK_EQ(IWDG_RLR, 240);
    core_init();
}

static void test_pwm_and_laser(void)
{
    board_set_pwm(32767);
    CHECK_EQ(TIM1->CCR[0], 8400); /* above ARR: always on */
    CHECK_EQ(GPIOB->BSRR, 1u << (12 + 16)); /* DIR low: forward */
    board_set_pwm(-16384);
    CHECK_EQ(TIM1->CCR[0], 4200);
    CHECK_EQ(GPIOB->BSRR, 1u << 12);
    CHECK_EQ(board_load.pwm_duty, -16384);
    board_set_pwm(0);
    CHECK_EQ(TIM1->CCR[0], 0);
    board_set_laser(true);
    CHECK_EQ(GPIOB->BSRR, 1u << 13);
    board_set_laser(false);
    CHECK_EQ(GPIOB->BSRR, 1u << (13 + 16));
    CHECK_EQ(board_load.laser, 0);
}

static uint32_t base; /* board_ticks() at the last SysTick, tracked here */

static void systick(void)
{
    SYST_CVR = 16799; /* just reloaded */
    SysTick_Handler();
    base += 16800;
}

static void test_time_base(void)
{
    uint32_t t;
    int32_t e;
    while (board_tick_pop(&t, &e)) {
    }
    SYST_CVR = 16799;
    uint32_t t0 = board_ticks();
    SYST_CVR = 0;
    CHECK_EQ(board_ticks() - t0, 16799);
    /* a reload pending but not yet handled belongs to this reading */
    SCB_ICSR = SCB_ICSR_PENDSTSET;
    SYST_CVR = 16700;
    CHECK_EQ(board_ticks() - t0, 16800 + 99);
    SCB_ICSR = 0;
    base = t0;
    systick();
    SYST_CVR = 16799;
    CHECK_EQ(board_ticks(), base);

    /* each tick keeps its own time and encoder sample when the main loop runs late */
    TIM8->CNT = 100;
    systick();
    TIM8->CNT = 110;
    systick();
    TIM8->CNT = 125;
    systick();
    int32_t e0 = 0;
    for (int i = 0; i < 4; i++) {
        bool got = board_tick_pop(&t, &e);
        if (i == 0) {
            CHECK(got, "the tick before");
            continue;
        }
        CHECK(got, "tick %d queued", i);
        CHECK_EQ(t, base - (uint32_t)(3 - i) * 16800u);
        if (i == 1)
            e0 = e;
        else
            CHECK_EQ(e - e0, i == 2 ? 10 : 25);
    }
    CHECK(!board_tick_pop(&t, &e), "no more ticks");
    for (int i = 0; i < 12; i++)
        systick();
    int n = 0;
    while (board_tick_pop(&t, &e))
        n++;
    CHECK_EQ(n, 8); /* the queue's depth: older ticks beyond it are dropped */
}

static void test_encoder_wraps(void)
{
    TIM8->CNT = 65530;
    int32_t e0 = board_encoder();
    TIM8->CNT = 4;
    CHECK_EQ(board_encoder() - e0, 10);
    TIM8->CNT = 65534;
    CHECK_EQ(board_encoder() - e0, 4);
}

static void test_capture_maps_onto_board_ticks(void)
{
    pulse_event_t ev;
    while (pulse_pop(&ev)) {
    }
    SYST_CVR = 16799 - 500; /* board_ticks() = base + 500 */
    TIM2->CNT = 1000;
    TIM2->CCR[2] = 900; /* latched 100 TIM2 counts (200 HCLK) ago */
    TIM2->SR = TIM_SR_CC3IF;
    TIM2_IRQHandler();
    CHECK(pulse_pop(&ev), "an optical pulse queued");
    CHECK_EQ(ev.channel, PULSE_CH_OPTICAL);
    CHECK_EQ(ev.ticks, base + 500 - 200);
    TIM2->CNT = 5; /* the 32-bit counter wrapped since the capture */
    TIM2->CCR[3] = 0xFFFFFFFBu;
    TIM2->SR = TIM_SR_CC4IF;
    TIM2_IRQHandler();
    CHECK(pulse_pop(&ev), "a zero pulse queued");
    CHECK_EQ(ev.channel, PULSE_CH_ZERO);
    CHECK_EQ(ev.ticks, base + 500 - 20);
}

static void test_step_timer_and_limits(void)
{
    board_stepper_wake();
    CHECK_EQ(TIM4->ARR, 672 / 16); /* a due time already past: 4 us from now */
    CHECK_EQ(TIM4->DIER, TIM_DIER_UIE);
    CHECK_EQ(TIM4->CR1, TIM_CR1_URS | TIM_CR1_OPM | TIM_CR1_CEN);
    TIM4_IRQHandler(); /* no move planned: the timer stops */
    CHECK_EQ(TIM4->DIER, 0);
    CHECK_EQ(TIM4->CR1 & TIM_CR1_CEN, 0);
    GPIOC->IDR = 0;
    CHECK(board_limit(0) && board_limit(1), "switches to GND: pressed");
    GPIOC->IDR = 1u << 4;
    CHECK(!board_limit(0) && board_limit(1), "PC4 high: axis 0 released");
    board_step_dir(1, true);
    CHECK_EQ(GPIOC->BSRR, 1u << 3);
}

static void test_uart(void)
{
    uint8_t b;
    USART1->SR = USART_SR_RXNE;
    USART1->DR = 0x5A;
    USART1_IRQHandler();
    CHECK(board_rx_pop(&b) && b == 0x5A, "the received byte is queued");
    CHECK(!board_rx_pop(&b), "one byte only");
    core_fault(FAULT_WATCHDOG_EXPIRED, 7); /* queues a frame and kicks the transmitter */
    CHECK(USART1->CR1 & USART_CR1_TXEIE, "TXE interrupt on");
    USART1->SR = USART_SR_TXE;
    USART1_IRQHandler();
    CHECK_EQ(USART1->DR, PROTO_SYNC);
    board_tx_service(); /* TXE stays set here: the rest goes out */
    CHECK(!core_tx_pop(&b), "the ring is empty");
    USART1_IRQHandler(); /* nothing left: the interrupt switches itself off */
    CHECK_EQ(USART1->CR1 & USART_CR1_TXEIE, 0);
}

int main(void)
{
    if (map_at(0x40000000u, 0x24000u) || map_at(0xE000E000u, 0x1000u)) {
        fprintf(stderr, "cannot map the register blocks at their addresses; skipped\n");
        return 0;
    }
    test_init_registers();
    test_pwm_and_laser();
    test_time_base();
    test_encoder_wraps();
    test_capture_maps_onto_board_ticks();
    test_step_timer_and_limits();
    test_uart();
    printf("stm32 board tests: %d checks, %d failed\n", check_count, check_failures);
    return check_failures != 0;
}
