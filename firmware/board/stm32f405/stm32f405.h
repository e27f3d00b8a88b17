/* STM32F405 registers used by this board (RM0090), written out here so no vendor SDK is needed.
 * Only what board.c touches; names follow the reference manual. */
#ifndef STM32F405_H
#define STM32F405_H
#include <stdint.h>

#define REG(addr) (*(volatile uint32_t *)(addr))

/* --- Cortex-M4 core (ARMv7-M ARM, PM0214) --- */
#define SYST_CSR REG(0xE000E010u)
#define SYST_RVR REG(0xE000E014u)
#define SYST_CVR REG(0xE000E018u)
#define SYST_CSR_ENABLE (1u << 0)
#define SYST_CSR_TICKINT (1u << 1)
#define SYST_CSR_CLKSOURCE (1u << 2) /* 1 = processor clock (HCLK) */
#define SCB_ICSR REG(0xE000ED04u)
#define SCB_ICSR_PENDSTSET (1u << 26)
#define SCB_VTOR REG(0xE000ED08u)
#define SCB_SHPR3 REG(0xE000ED20u) /* bits 31:24 SysTick priority */
#define SCB_CPACR REG(0xE000ED88u)
#define NVIC_ISER(n) REG(0xE000E100u + 4u * (n))
#define NVIC_IPR8(n) (*(volatile uint8_t *)(0xE000E400u + (n)))

/* --- RCC, FLASH, IWDG --- */
#define RCC_BASE 0x40023800u
#define RCC_CR REG(RCC_BASE + 0x00u)
#define RCC_PLLCFGR REG(RCC_BASE + 0x04u)
#define RCC_CFGR REG(RCC_BASE + 0x08u)
#define RCC_AHB1ENR REG(RCC_BASE + 0x30u)
#define RCC_APB1ENR REG(RCC_BASE + 0x40u)
#define RCC_APB2ENR REG(RCC_BASE + 0x44u)
#define RCC_CR_HSION (1u << 0)
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_PLLCFGR_SRC_HSE (1u << 22)
#define RCC_CFGR_SW_PLL 2u
#define RCC_CFGR_SWS_MASK (3u << 2)
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_PPRE1_DIV4 (5u << 10)
#define RCC_CFGR_PPRE2_DIV2 (4u << 13)
#define RCC_AHB1ENR_GPIOA (1u << 0)
#define RCC_AHB1ENR_GPIOB (1u << 1)
#define RCC_AHB1ENR_GPIOC (1u << 2)
#define RCC_APB1ENR_TIM2 (1u << 0)
#define RCC_APB1ENR_TIM4 (1u << 2)
#define RCC_APB2ENR_TIM1 (1u << 0)
#define RCC_APB2ENR_TIM8 (1u << 1)
#define RCC_APB2ENR_USART1 (1u << 4)

#define FLASH_ACR REG(0x40023C00u)
#define FLASH_ACR_LATENCY_5WS 5u
#define FLASH_ACR_PRFTEN (1u << 8)
#define FLASH_ACR_ICEN (1u << 9)
#define FLASH_ACR_DCEN (1u << 10)

#define IWDG_KR REG(0x40003000u)
#define IWDG_PR REG(0x40003004u)
#define IWDG_RLR REG(0x40003008u)

/* --- GPIO --- */
typedef struct {
    volatile uint32_t MODER, OTYPER, OSPEEDR, PUPDR, IDR, ODR, BSRR, LCKR, AFR[2];
} gpio_t;
#define GPIOA ((gpio_t *)0x40020000u)
#define GPIOB ((gpio_t *)0x40020400u)
#define GPIOC ((gpio_t *)0x40020800u)
#define GPIO_MODE_IN 0u
#define GPIO_MODE_OUT 1u
#define GPIO_MODE_AF 2u
#define GPIO_PULL_UP 1u

/* --- Timers (general purpose and advanced share this layout) --- */
typedef struct {
    volatile uint32_t CR1, CR2, SMCR, DIER, SR, EGR, CCMR1, CCMR2, CCER, CNT, PSC, ARR, RCR;
    volatile uint32_t CCR[4];
    volatile uint32_t BDTR, DCR, DMAR, OR;
} tim_t;
#define TIM1 ((tim_t *)0x40010000u)
#define TIM2 ((tim_t *)0x40000000u)
#define TIM4 ((tim_t *)0x40000800u)
#define TIM8 ((tim_t *)0x40010400u)
#define TIM_CR1_CEN (1u << 0)
#define TIM_CR1_URS (1u << 2)
#define TIM_CR1_OPM (1u << 3)
#define TIM_CR1_ARPE (1u << 7)
#define TIM_SR_UIF (1u << 0)
#define TIM_SR_CC3IF (1u << 3)
#define TIM_SR_CC4IF (1u << 4)
#define TIM_DIER_UIE (1u << 0)
#define TIM_DIER_CC3IE (1u << 3)
#define TIM_DIER_CC4IE (1u << 4)
#define TIM_EGR_UG (1u << 0)
#define TIM_BDTR_MOE (1u << 15)
#define TIM_SMCR_SMS_ENC3 3u /* encoder mode 3: count on both edges of both inputs (x4) */

/* --- USART --- */
typedef struct {
    volatile uint32_t SR, DR, BRR, CR1, CR2, CR3, GTPR;
} usart_t;
#define USART1 ((usart_t *)0x40011000u)
#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_TXEIE (1u << 7)
#define USART_CR1_UE (1u << 13)

/* IRQ numbers (vector = 16 + IRQ) */
#define IRQ_TIM2 28u
#define IRQ_TIM4 30u
#define IRQ_USART1 37u
#define IRQ_COUNT 82u

#if defined(__arm__)
static inline uint32_t irq_disable_save(void)
{
    uint32_t primask;
    __asm volatile("mrs %0, primask\n\tcpsid i" : "=r"(primask)::"memory");
    return primask;
}

static inline void irq_restore(uint32_t primask)
{
    __asm volatile("msr primask, %0" ::"r"(primask) : "memory");
}
#else
/* Host unit tests (tests/stm32_board_main.c): the register blocks are memory mapped at their
 * addresses, PRIMASK is a variable. */
extern uint32_t host_primask;
static inline uint32_t irq_disable_save(void)
{
    uint32_t p = host_primask;
    host_primask = 1u;
    return p;
}
static inline void irq_restore(uint32_t primask) { host_primask = primask; }
#endif

#endif
