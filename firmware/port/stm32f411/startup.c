/*
 * Startup for the STM32F411: the vector table, the reset handler (.data copied from flash, .bss zeroed, the
 * FPU on, then main), and the fault handler.
 *
 * Faults. HardFault (and every configurable fault, which escalates to it while disabled) and any interrupt
 * without a handler end in fault_handler: it first drives both lasers off and disables the stepper driver with
 * raw register writes (no function of the core, whose state may be the cause), then stores the stacked PC,
 * LR, xPSR and the fault status registers in a RAM record the reset does not clear (.noinit, with a magic
 * and a check word), and resets the chip. After the reset fault_take_record hands the record over once, and
 * the firmware reports it (LOG at boot).
 */
#include <stdint.h>
#include <string.h>

#include "board.h"
#include "port.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);

void Reset_Handler(void);
void HardFault_Handler(void);
void fault_handler(const uint32_t* frame, uint32_t vector);

void NMI_Handler(void) __attribute__((weak, alias("HardFault_Handler")));
void MemManage_Handler(void) __attribute__((weak, alias("HardFault_Handler")));
void BusFault_Handler(void) __attribute__((weak, alias("HardFault_Handler")));
void UsageFault_Handler(void) __attribute__((weak, alias("HardFault_Handler")));
void SVC_Handler(void) __attribute__((weak, alias("HardFault_Handler")));
void DebugMon_Handler(void) __attribute__((weak, alias("HardFault_Handler")));
void PendSV_Handler(void) __attribute__((weak, alias("HardFault_Handler")));
void SysTick_Handler(void) __attribute__((weak, alias("HardFault_Handler")));
void TIM2_IRQHandler(void) __attribute__((weak, alias("HardFault_Handler")));
void TIM3_IRQHandler(void) __attribute__((weak, alias("HardFault_Handler")));
void USART1_IRQHandler(void) __attribute__((weak, alias("HardFault_Handler")));
void OTG_FS_IRQHandler(void) __attribute__((weak, alias("HardFault_Handler")));

typedef void (*vector_t)(void);
#define VECTORS (16u + F4_IRQ_COUNT)

/* The table: initial stack pointer, then the handlers by position (ARMv7-M B1.5.3; RM0383 table 37). */
__attribute__((section(".isr_vector"), used)) const vector_t g_vectors[VECTORS] = {
    [0] = (vector_t)(uintptr_t)&_estack,
    [1] = Reset_Handler,
    [2] = NMI_Handler,
    [3] = HardFault_Handler,
    [4] = MemManage_Handler,
    [5] = BusFault_Handler,
    [6] = UsageFault_Handler,
    [11] = SVC_Handler,
    [12] = DebugMon_Handler,
    [14] = PendSV_Handler,
    [15] = SysTick_Handler,
    [16 + IRQ_TIM2] = TIM2_IRQHandler,
    [16 + IRQ_TIM3] = TIM3_IRQHandler,
    [16 + IRQ_USART1] = USART1_IRQHandler,
    [16 + IRQ_OTG_FS] = OTG_FS_IRQHandler,
};
F4_ASSERT(sizeof(g_vectors) == 4u * 102u, "RM0383 table 37: 16 system vectors + 86 interrupt positions");

__attribute__((section(".noinit"))) static fault_record_t g_fault;

void Reset_Handler(void) {
  /* The FPU first: the compiler may use its registers anywhere (-mfloat-abi=hard). */
  REG32(SCB_CPACR) |= SCB_CPACR_CP10_CP11_FULL;
  __asm__ volatile("dsb\n\tisb" ::: "memory");
  const uint32_t* src = &_sidata;
  for (uint32_t* dst = &_sdata; dst < &_edata;) *dst++ = *src++;
  for (uint32_t* dst = &_sbss; dst < &_ebss;) *dst++ = 0u;
  (void)main();
  for (;;) {
  }
}

/* Also every handler the port does not define (weak aliases above): LR still holds EXC_RETURN, IPSR says which
 * vector it was. Finds the exception frame (main or process stack, EXC_RETURN bit 2) and hands it to
 * fault_handler. Unused positions of the table are 0: taking one is itself a fault. */
__attribute__((naked)) void HardFault_Handler(void) {
  __asm__ volatile(
      "tst lr, #4\n\t"
      "ite eq\n\t"
      "mrseq r0, msp\n\t"
      "mrsne r0, psp\n\t"
      "mrs r1, ipsr\n\t"
      "b fault_handler\n\t");
}

uint32_t fault_record_check(const fault_record_t* r) {
  return FAULT_MAGIC ^ r->count ^ r->vector ^ r->pc ^ r->lr ^ r->psr ^ r->cfsr ^ r->hfsr ^ r->mmfar ^ r->bfar;
}

__attribute__((used, noreturn)) void fault_handler(const uint32_t* frame, uint32_t vector) {
  /* Safety first: lasers off, stepper driver disabled, trigger output low (pin back to a GPIO output). */
  REG32(GPIOB_BASE + GPIO_BSRR) = BOARD_SAFE_BSRR_B;
  REG32(BOARD_TRIGGER_PORT + GPIO_BSRR) = 1u << (BOARD_TRIGGER_PIN + 16u);
  REG32(BOARD_TRIGGER_PORT + GPIO_MODER) =
      (REG32(BOARD_TRIGGER_PORT + GPIO_MODER) & ~(3u << (2u * BOARD_TRIGGER_PIN))) |
      (GPIO_MODE_OUTPUT << (2u * BOARD_TRIGGER_PIN));
  const uint32_t count = g_fault.magic == FAULT_MAGIC ? g_fault.count + 1u : 1u;
  g_fault.magic = 0;
  g_fault.count = count;
  g_fault.vector = vector & 0x1FFu;
  g_fault.pc = frame[6]; /* stacked r0-r3, r12, lr, pc, xpsr */
  g_fault.lr = frame[5];
  g_fault.psr = frame[7];
  g_fault.cfsr = REG32(SCB_CFSR);
  g_fault.hfsr = REG32(SCB_HFSR);
  g_fault.mmfar = REG32(SCB_MMFAR);
  g_fault.bfar = REG32(SCB_BFAR);
  g_fault.check = fault_record_check(&g_fault);
  g_fault.magic = FAULT_MAGIC;
  __asm__ volatile("dsb" ::: "memory");
  REG32(SCB_AIRCR) = SCB_AIRCR_RESET;
  __asm__ volatile("dsb" ::: "memory");
  for (;;) {
  }
}

const fault_record_t* fault_take_record(void) {
  static fault_record_t taken;
  if (g_fault.magic != FAULT_MAGIC || g_fault.check != fault_record_check(&g_fault)) {
    memset(&g_fault, 0, sizeof(g_fault));
    return NULL;
  }
  taken = g_fault;
  g_fault.magic = 0; /* reported once; count goes on from here if it faults again */
  g_fault.check = 0;
  return &taken;
}
