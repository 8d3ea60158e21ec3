/* Shared between the STM32F411 port's files (not part of the core's contract). */
#ifndef ROTOSCAN_FIRMWARE_STM32F411_PORT_H_
#define ROTOSCAN_FIRMWARE_STM32F411_PORT_H_

#include <stdbool.h>
#include <stdint.h>

/* What the HardFault handler leaves in RAM that a reset does not clear (.noinit), read after the reset. */
#define FAULT_MAGIC 0x544C4146u /* "FALT" */
typedef struct {
  uint32_t magic; /* FAULT_MAGIC when the rest is valid */
  uint32_t count; /* faults since power-on (the record survives resets, not power cycles) */
  uint32_t vector; /* IPSR: 3 = HardFault, 16 + n = an unexpected interrupt n */
  uint32_t pc, lr, psr;
  uint32_t cfsr, hfsr, mmfar, bfar;
  uint32_t check; /* the words above xor'ed with FAULT_MAGIC: a half-written record is not believed */
} fault_record_t;

/* The record of the fault before the last reset, or NULL; then cleared so it is reported once. */
const fault_record_t* fault_take_record(void);
uint32_t fault_record_check(const fault_record_t* r);

/* Clocks: 25 MHz HSE -> 96 MHz SYSCLK, 48 MHz USB. Returns false when the crystal did not start (then the
 * same PLL runs from the 16 MHz HSI: USB timing is out of specification). */
bool clock_init(void);
#define CLOCK_SYSCLK_HZ 96000000u
#define CLOCK_TIMER_HZ 96000000u /* APB1 /2 doubles back for its timers (RM0383 6.2) */
#define CLOCK_APB2_HZ 96000000u

/* The DWT cycle counter, for the step interrupt's measured cost. */
void dwt_init(void);
static inline uint32_t dwt_cycles(void) {
  return *(volatile uint32_t*)(uintptr_t)0xE0001004u; /* DWT_CYCCNT */
}

/* The step interrupt's cost in cycles, measured with DWT on every run: the last and the worst. */
uint32_t port_step_isr_cycles_max(void);
uint32_t port_step_isr_cycles_last(void);

/* The transport (transport_usb.c or transport_uart.c, one per image): set up, and serviced from the main
 * loop. */
void transport_init(void);
void transport_poll(void);

/* Every interrupt handler of the port calls this (or sets the flag itself): the main loop then makes another
 * pass before it sleeps (port_stm32f411.c, "Sleep"). */
void port_note_wake(void);

void nvic_enable(uint32_t irq, uint8_t priority);
void nvic_pend(uint32_t irq);

#endif /* ROTOSCAN_FIRMWARE_STM32F411_PORT_H_ */
