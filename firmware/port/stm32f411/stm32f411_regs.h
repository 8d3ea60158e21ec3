/*
 * stm32f411_regs.h -- the STM32F411's registers that this port touches, written from the reference manual
 * RM0383 (rev. 3) and the Cortex-M4 generic user guide; no vendor header is used. Each peripheral's base is
 * derived from its bus base plus its offset on that bus, and a static assertion checks the result against
 * RM0383's memory map (section 2.3, table 1); each register offset used is asserted against the register
 * map at the end of its chapter. A typo in either place fails the build, not the board.
 *
 * Access goes through REG32(base + offset) so that the same offsets serve the target (volatile loads and
 * stores) and a model (the host tests of the USB core reach the DWC2 registers through dwc2_io.h instead).
 */
#ifndef ROTOSCAN_FIRMWARE_STM32F411_REGS_H_
#define ROTOSCAN_FIRMWARE_STM32F411_REGS_H_

#include <stdint.h>

#define F4_ASSERT(expr, msg) __extension__ _Static_assert(expr, msg)
#define REG32(addr) (*(volatile uint32_t*)(uintptr_t)(addr))

/* ---- memory map (RM0383 2.3, table 1) ------------------------------------------------------------------ */
#define F4_FLASH_BASE 0x08000000u
#define F4_FLASH_SIZE (512u * 1024u)
#define F4_SRAM_BASE 0x20000000u
#define F4_SRAM_SIZE (128u * 1024u)
#define F4_APB1_BASE 0x40000000u
#define F4_APB2_BASE 0x40010000u
#define F4_AHB1_BASE 0x40020000u
#define F4_AHB2_BASE 0x50000000u

#define TIM2_BASE (F4_APB1_BASE + 0x0000u)
#define TIM3_BASE (F4_APB1_BASE + 0x0400u)
#define PWR_BASE (F4_APB1_BASE + 0x7000u)
#define USART1_BASE (F4_APB2_BASE + 0x1000u)
#define GPIOA_BASE (F4_AHB1_BASE + 0x0000u)
#define GPIOB_BASE (F4_AHB1_BASE + 0x0400u)
#define GPIOC_BASE (F4_AHB1_BASE + 0x0800u)
#define RCC_BASE (F4_AHB1_BASE + 0x3800u)
#define FLASH_R_BASE (F4_AHB1_BASE + 0x3C00u)
#define OTG_FS_BASE (F4_AHB2_BASE + 0x0000u)
F4_ASSERT(TIM2_BASE == 0x40000000u, "RM0383 table 1: TIM2");
F4_ASSERT(TIM3_BASE == 0x40000400u, "RM0383 table 1: TIM3");
F4_ASSERT(PWR_BASE == 0x40007000u, "RM0383 table 1: PWR");
F4_ASSERT(USART1_BASE == 0x40011000u, "RM0383 table 1: USART1");
F4_ASSERT(GPIOA_BASE == 0x40020000u && GPIOB_BASE == 0x40020400u && GPIOC_BASE == 0x40020800u,
          "RM0383 table 1: GPIOA..C");
F4_ASSERT(RCC_BASE == 0x40023800u, "RM0383 table 1: RCC");
F4_ASSERT(FLASH_R_BASE == 0x40023C00u, "RM0383 table 1: flash interface");
F4_ASSERT(OTG_FS_BASE == 0x50000000u, "RM0383 table 1: USB OTG FS");

/* The 96-bit unique device id (RM0383 24.1) and the flash size word (24.2), in system memory. */
#define F4_UID_BASE 0x1FFF7A10u
#define F4_FLASH_SIZE_REG 0x1FFF7A22u

/* ---- RCC (RM0383 6.3) ---------------------------------------------------------------------------------- */
#define RCC_CR (RCC_BASE + 0x00u)
#define RCC_PLLCFGR (RCC_BASE + 0x04u)
#define RCC_CFGR (RCC_BASE + 0x08u)
#define RCC_AHB1ENR (RCC_BASE + 0x30u)
#define RCC_AHB2ENR (RCC_BASE + 0x34u)
#define RCC_APB1ENR (RCC_BASE + 0x40u)
#define RCC_APB2ENR (RCC_BASE + 0x44u)
#define RCC_CSR (RCC_BASE + 0x74u)
F4_ASSERT(RCC_PLLCFGR - RCC_BASE == 0x04u && RCC_CFGR - RCC_BASE == 0x08u, "RM0383 6.3.1-6.3.3");
F4_ASSERT(RCC_AHB1ENR - RCC_BASE == 0x30u && RCC_AHB2ENR - RCC_BASE == 0x34u, "RM0383 6.3.9, 6.3.10");
F4_ASSERT(RCC_APB1ENR - RCC_BASE == 0x40u && RCC_APB2ENR - RCC_BASE == 0x44u, "RM0383 6.3.11, 6.3.12");
F4_ASSERT(RCC_CSR - RCC_BASE == 0x74u, "RM0383 6.3.20");
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_PLLCFGR_PLLM_POS 0u  /* 6 bits, 2..63 */
#define RCC_PLLCFGR_PLLN_POS 6u  /* 9 bits, 50..432 */
#define RCC_PLLCFGR_PLLP_POS 16u /* 2 bits: 00 = /2, 01 = /4, 10 = /6, 11 = /8 */
#define RCC_PLLCFGR_PLLSRC_HSE (1u << 22)
#define RCC_PLLCFGR_PLLQ_POS 24u /* 4 bits, 2..15 */
#define RCC_CFGR_SW_PLL 2u       /* SW[1:0] */
#define RCC_CFGR_SWS_MASK (3u << 2)
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_HPRE_DIV1 (0u << 4)
#define RCC_CFGR_PPRE1_DIV2 (4u << 10) /* PPRE1[2:0] = 100 */
#define RCC_CFGR_PPRE2_DIV1 (0u << 13)
#define RCC_AHB1ENR_GPIOAEN (1u << 0)
#define RCC_AHB1ENR_GPIOBEN (1u << 1)
#define RCC_AHB1ENR_GPIOCEN (1u << 2)
#define RCC_AHB2ENR_OTGFSEN (1u << 7)
#define RCC_APB1ENR_TIM2EN (1u << 0)
#define RCC_APB1ENR_TIM3EN (1u << 1)
#define RCC_APB1ENR_PWREN (1u << 28)
#define RCC_APB2ENR_USART1EN (1u << 4)
#define RCC_CSR_RMVF (1u << 24)
#define RCC_CSR_RESET_FLAGS (0xFEu << 24) /* BORRSTF .. LPWRRSTF, bits 25..31 */

/* ---- PWR (RM0383 5.4) ---------------------------------------------------------------------------------- */
#define PWR_CR (PWR_BASE + 0x00u)
#define PWR_CR_VOS_MASK (3u << 14)
#define PWR_CR_VOS_SCALE1 (3u << 14) /* VOS = 11: scale 1, needed above 84 MHz */

/* ---- Flash interface (RM0383 3.8) ---------------------------------------------------------------------- */
#define FLASH_ACR (FLASH_R_BASE + 0x00u)
#define FLASH_ACR_LATENCY_MASK 0xFu
#define FLASH_ACR_PRFTEN (1u << 8)
#define FLASH_ACR_ICEN (1u << 9)
#define FLASH_ACR_DCEN (1u << 10)
#define FLASH_ACR_ICRST (1u << 11)
#define FLASH_ACR_DCRST (1u << 12)

/* ---- GPIO (RM0383 8.4) --------------------------------------------------------------------------------- */
#define GPIO_MODER 0x00u
#define GPIO_OTYPER 0x04u
#define GPIO_OSPEEDR 0x08u
#define GPIO_PUPDR 0x0Cu
#define GPIO_IDR 0x10u
#define GPIO_ODR 0x14u
#define GPIO_BSRR 0x18u
#define GPIO_AFRL 0x20u
#define GPIO_AFRH 0x24u
F4_ASSERT(GPIO_IDR == 0x10u && GPIO_ODR == 0x14u && GPIO_BSRR == 0x18u, "RM0383 8.4.5-8.4.7");
F4_ASSERT(GPIO_AFRL == 0x20u && GPIO_AFRH == 0x24u, "RM0383 8.4.9, 8.4.10");
#define GPIO_MODE_INPUT 0u
#define GPIO_MODE_OUTPUT 1u
#define GPIO_MODE_AF 2u

/* ---- TIM2 / TIM3, general-purpose timers (RM0383 13.4) ------------------------------------------------- */
#define TIM_CR1 0x00u
#define TIM_DIER 0x0Cu
#define TIM_SR 0x10u
#define TIM_EGR 0x14u
#define TIM_CCMR1 0x18u
#define TIM_CCMR2 0x1Cu
#define TIM_CCER 0x20u
#define TIM_CNT 0x24u
#define TIM_PSC 0x28u
#define TIM_ARR 0x2Cu
#define TIM_CCR1 0x34u
#define TIM_CCR2 0x38u
#define TIM_CCR3 0x3Cu
#define TIM_CCR4 0x40u
F4_ASSERT(TIM_DIER == 0x0Cu && TIM_SR == 0x10u && TIM_EGR == 0x14u, "RM0383 13.4.4-13.4.6");
F4_ASSERT(TIM_CCMR1 == 0x18u && TIM_CCMR2 == 0x1Cu && TIM_CCER == 0x20u, "RM0383 13.4.7-13.4.9");
F4_ASSERT(TIM_CNT == 0x24u && TIM_PSC == 0x28u && TIM_ARR == 0x2Cu, "RM0383 13.4.10-13.4.12");
F4_ASSERT(TIM_CCR1 == 0x34u && TIM_CCR2 == 0x38u && TIM_CCR3 == 0x3Cu && TIM_CCR4 == 0x40u,
          "RM0383 13.4.13-13.4.16");
#define TIM_CR1_CEN (1u << 0)
#define TIM_CR1_URS (1u << 2) /* only an overflow sets UIF, not the UG bit */
#define TIM_DIER_UIE (1u << 0)
#define TIM_DIER_CCIE(ch) (1u << (ch)) /* ch 1..4 */
#define TIM_SR_UIF (1u << 0)
#define TIM_SR_CCIF(ch) (1u << (ch))
#define TIM_EGR_UG (1u << 0)
/* CCMRx: each channel has 8 bits (channel 1 and 3 at 0, 2 and 4 at 8): CCxS[1:0], OCxM[2:0] at 4..6. */
#define TIM_CCMR_CCS_OUTPUT 0u
#define TIM_CCMR_CCS_INPUT_TI 1u  /* ICx mapped on TIx */
#define TIM_OCM_FROZEN 0u
#define TIM_OCM_ACTIVE_ON_MATCH 1u
#define TIM_OCM_INACTIVE_ON_MATCH 2u
#define TIM_OCM_FORCE_INACTIVE 4u
#define TIM_OCM_FORCE_ACTIVE 5u
#define TIM_CCER_CCE(ch) (1u << (4u * ((ch)-1u)))
#define TIM_CCER_CCP(ch) (1u << (4u * ((ch)-1u) + 1u))
#define TIM_CCER_CCNP(ch) (1u << (4u * ((ch)-1u) + 3u)) /* CCxP = CCxNP = 1: both edges */

/* ---- USART1 (RM0383 19.6) ------------------------------------------------------------------------------ */
#define USART_SR 0x00u
#define USART_DR 0x04u
#define USART_BRR 0x08u
#define USART_CR1 0x0Cu
F4_ASSERT(USART_DR == 0x04u && USART_BRR == 0x08u && USART_CR1 == 0x0Cu, "RM0383 19.6.2-19.6.4");
#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_TXEIE (1u << 7)
#define USART_CR1_UE (1u << 13)

/* ---- Cortex-M4 system control space (ARMv7-M ARM B3.2; Cortex-M4 generic user guide 4) ----------------- */
#define SCB_ICSR 0xE000ED04u
#define SCB_VTOR 0xE000ED08u
#define SCB_AIRCR 0xE000ED0Cu
#define SCB_SHCSR 0xE000ED24u
#define SCB_CFSR 0xE000ED28u
#define SCB_HFSR 0xE000ED2Cu
#define SCB_MMFAR 0xE000ED34u
#define SCB_BFAR 0xE000ED38u
#define SCB_CPACR 0xE000ED88u
#define SCB_AIRCR_RESET (0x05FAu << 16 | 1u << 2) /* VECTKEY + SYSRESETREQ */
#define SCB_CPACR_CP10_CP11_FULL (0xFu << 20)
#define NVIC_ISER(n) (0xE000E100u + 4u * (n))
#define NVIC_ICER(n) (0xE000E180u + 4u * (n))
#define NVIC_ISPR(n) (0xE000E200u + 4u * (n))
#define NVIC_IPR_BYTE(irq) (0xE000E400u + (irq)) /* one byte per interrupt, top 4 bits used on the F411 */
#define DEMCR 0xE000EDFCu
#define DEMCR_TRCENA (1u << 24)
#define DWT_CTRL 0xE0001000u
#define DWT_CYCCNT 0xE0001004u
#define DWT_CTRL_CYCCNTENA (1u << 0)
F4_ASSERT(SCB_VTOR == 0xE000ED08u && SCB_CFSR == 0xE000ED28u && SCB_HFSR == 0xE000ED2Cu, "ARMv7-M B3.2.2");
F4_ASSERT(DWT_CYCCNT == DWT_CTRL + 4u, "ARMv7-M C1.8.7");

/* Interrupt numbers (RM0383 10.2, table 37: position). */
#define IRQ_TIM2 28u
#define IRQ_TIM3 29u
#define IRQ_USART1 37u
#define IRQ_OTG_FS 67u
#define F4_IRQ_COUNT 86u /* positions 0..85: the last is SPI5 (RM0383 table 37) */

#endif /* ROTOSCAN_FIRMWARE_STM32F411_REGS_H_ */
