/*
 * Clock tree, cycle counter and interrupt controller of the STM32F411 port.
 *
 * Clocks (RM0383 6.2, 6.3.2): HSE 25 MHz / PLLM 25 = 1 MHz into the PLL (RM0383 recommends 2 MHz for jitter;
 * 1 MHz is within range and is the only integer that gives both 96 MHz and exactly 48 MHz), x PLLN 192 =
 * VCO 192 MHz; / PLLP 2 = SYSCLK 96 MHz, / PLLQ 4 = 48 MHz for the USB core, which works at no other.
 * AHB /1 = 96 MHz, APB1 /2 = 48 MHz (its limit is 50; its timers run at 2 x 48 = 96 MHz), APB2 /1 = 96 MHz.
 * Above 84 MHz the regulator must be at scale 1 (PWR_CR.VOS = 11) and the flash needs 3 wait states at 2.7-
 * 3.6 V (RM0383 3.4.1, table 5: 90 < HCLK <= 100 MHz); prefetch and both caches on.
 */
#include <stdbool.h>
#include <stdint.h>

#include "board.h"
#include "port.h"

#define PLL_M 25u
#define PLL_N 192u
#define PLL_P 2u
#define PLL_Q 4u
#define PLL_M_HSI 16u /* the same 1 MHz from the 16 MHz HSI when the crystal does not start */
F4_ASSERT(BOARD_HSE_HZ / PLL_M == 1000000u, "PLL input 1 MHz (RM0383: 1..2 MHz)");
F4_ASSERT(BOARD_HSE_HZ / PLL_M * PLL_N >= 100000000u && BOARD_HSE_HZ / PLL_M * PLL_N <= 432000000u,
          "VCO within 100..432 MHz");
F4_ASSERT(BOARD_HSE_HZ / PLL_M * PLL_N / PLL_P == CLOCK_SYSCLK_HZ, "SYSCLK 96 MHz");
F4_ASSERT(BOARD_HSE_HZ / PLL_M * PLL_N / PLL_Q == 48000000u, "USB needs exactly 48 MHz");
F4_ASSERT(CLOCK_SYSCLK_HZ / 2u <= 50000000u, "APB1 at most 50 MHz");
#define FLASH_WAIT_STATES 3u

#define CLOCK_SPINS 1000000u

static bool wait_bits(uint32_t reg, uint32_t mask, uint32_t want) {
  for (uint32_t i = 0; i < CLOCK_SPINS; ++i) {
    if ((REG32(reg) & mask) == want) return true;
  }
  return false;
}

bool clock_init(void) {
  REG32(RCC_CR) |= RCC_CR_HSEON;
  const bool hse = wait_bits(RCC_CR, RCC_CR_HSERDY, RCC_CR_HSERDY);
  REG32(RCC_APB1ENR) |= RCC_APB1ENR_PWREN;
  (void)REG32(RCC_APB1ENR); /* the enable takes effect after one read back (RM0383 6.3.11 note) */
  REG32(PWR_CR) = (REG32(PWR_CR) & ~PWR_CR_VOS_MASK) | PWR_CR_VOS_SCALE1;
  /* Wait states before the clock goes up; caches reset then enabled. */
  REG32(FLASH_ACR) = FLASH_ACR_ICRST | FLASH_ACR_DCRST;
  REG32(FLASH_ACR) = FLASH_WAIT_STATES | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
  (void)wait_bits(FLASH_ACR, FLASH_ACR_LATENCY_MASK, FLASH_WAIT_STATES);
  REG32(RCC_PLLCFGR) = ((hse ? PLL_M : PLL_M_HSI) << RCC_PLLCFGR_PLLM_POS) | (PLL_N << RCC_PLLCFGR_PLLN_POS) |
                       (((PLL_P / 2u) - 1u) << RCC_PLLCFGR_PLLP_POS) | (hse ? RCC_PLLCFGR_PLLSRC_HSE : 0u) |
                       (PLL_Q << RCC_PLLCFGR_PLLQ_POS);
  REG32(RCC_CR) |= RCC_CR_PLLON;
  if (!wait_bits(RCC_CR, RCC_CR_PLLRDY, RCC_CR_PLLRDY)) return false; /* stays on the 16 MHz HSI */
  REG32(RCC_CFGR) = RCC_CFGR_HPRE_DIV1 | RCC_CFGR_PPRE1_DIV2 | RCC_CFGR_PPRE2_DIV1 | RCC_CFGR_SW_PLL;
  (void)wait_bits(RCC_CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_PLL);
  return hse;
}

void dwt_init(void) {
  REG32(DEMCR) |= DEMCR_TRCENA;
  REG32(DWT_CYCCNT) = 0u;
  REG32(DWT_CTRL) |= DWT_CTRL_CYCCNTENA;
}

void nvic_enable(uint32_t irq, uint8_t priority) {
  *(volatile uint8_t*)(uintptr_t)NVIC_IPR_BYTE(irq) = (uint8_t)(priority << 4); /* 4 priority bits */
  REG32(NVIC_ISER(irq / 32u)) = 1u << (irq % 32u);
}

void nvic_pend(uint32_t irq) {
  REG32(NVIC_ISPR(irq / 32u)) = 1u << (irq % 32u);
}
