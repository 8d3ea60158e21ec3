/*
 * The STM32F411 port of the firmware core: hal.h on TIM2, TIM3 and GPIO, and the main loop.
 *
 * Step interrupt cycle budget (GRBL style; SYSCLK 96 MHz, 1 us timer ticks):
 *   fastest step rate allowed (SET_CONFIG max_rate_hz)      100 kHz = one interrupt per 10 us = 960 cycles
 *   DESIGN.md's ceiling for the step interrupt                5 us = 480 cycles (50 % of the CPU at 100 kHz)
 *   exception entry + exit (Cortex-M4, FPU lazy stacking on)  12 + 12 cycles (plus flash wait states)
 *   the path's instructions in the -Os image (arm-none-eabi-objdump, 2026-11-23): TIM3_IRQHandler 30,
 *   step_timer_load 16, step_isr 27 (+1 for fw_isr_step), ring_pop 8 + ring_peek 17 + newlib's memcpy for
 *   the 4-byte interval (~20 of its 100 run), hal_step_pulse 13 (two CCMR writes and a CCR write: the
 *   pulse's falling edge is TIM3's compare, no second interrupt)          ~130 instructions
 *   expected total, at about one cycle per instruction from the flash cache   ~160 cycles = 1.7 us, 1/3 of
 *   the budget (the generic memcpy in ring_peek is the first thing to cut if it ever matters)
 * Measured on the chip with the DWT cycle counter around the handler's body, every time it runs:
 * port_step_isr_cycles_last / _max (g_port.isr_cycles_*), reported by GET_DIAG (protocol 1.1, hal_diag).
 * Measured on the image under emulation (firmware/tests/emu, issue 18; the emulator's cycle model, not the
 * chip): 231 cycles between the two DWT reads, 283 cycles from exception entry to return, worst case over a
 * 200-step scan (firmware/README.md). No floating point, no division, no loop in the interrupt: all the
 * profile arithmetic runs in the main loop (core/stepper.c).
 *
 * Interrupt priorities (lower = more urgent): TIM3 step 0, TIM2 trigger / laser / exposure 1, USB and UART 2.
 * The core's queues are single-producer single-consumer between one interrupt and the main loop.
 *
 * Sleep. When a main-loop pass is done the CPU waits in WFI until an interrupt or the core's next deadline
 * (fw_next_wakeup_us: a settle time, an exposure's end, the laser-safety timeout, at most 1 s away), which
 * TIM2's channel 4 compare turns into an interrupt. Wake-up sources: TIM2 (that compare, the trigger, the
 * laser switch, the exposure line), TIM3 (steps), OTG_FS (host traffic; USART1 in the UART image). No work
 * is slept on: every handler sets g_port.woke, cleared before the pass; the decision to sleep is taken with
 * interrupts masked (PRIMASK), and WFI still wakes on an interrupt that becomes pending while they are
 * masked, which then runs at the CPSIE after it. Checked on the emulated image (issue 18): it enumerates and
 * scans with the sleep, and the time asleep is counted.
 */
#include <stdbool.h>
#include <stdint.h>

#include "board.h"
#include "fw.h"
#include "hal.h"
#include "port.h"
#include "timebase.h"

#define TIM2_REG(off) REG32(TIM2_BASE + (off))
#define TIM3_REG(off) REG32(TIM3_BASE + (off))
#define LASER_BITS ((1u << BOARD_LASER_L_PIN) | (1u << BOARD_LASER_R_PIN))
#define PRIO_STEP 0u
#define PRIO_TIMEBASE 1u
#define WAKE_CH 4u          /* TIM2 CH4: compare only, the main loop's wake-up deadline */
#define SLEEP_MIN_US 20u    /* a deadline nearer than this is polled for, not slept for */

static struct {
  volatile uint8_t laser_next;    /* mask the CH2 compare switches to */
  volatile uint32_t trigger_at;   /* the rising edge's counter value */
  volatile uint32_t trigger_pulse;
  volatile bool trigger_high;     /* the rising edge happened, the falling one is scheduled */
  volatile uint32_t step_long;    /* us of a long interval still to wait (TIM3 is 16 bit) */
  volatile uint32_t isr_cycles_last;
  volatile uint32_t isr_cycles_max;
  volatile bool woke;             /* an interrupt ran since the main loop's pass began */
} g_port;

/* ---- GPIO ---- */

static void gpio_mode(uint32_t port, uint32_t pin, uint32_t mode, uint32_t af) {
  REG32(port + GPIO_MODER) = (REG32(port + GPIO_MODER) & ~(3u << (2u * pin))) | (mode << (2u * pin));
  REG32(port + GPIO_OSPEEDR) |= 2u << (2u * pin); /* fast: clean edges for STEP and the trigger */
  const uint32_t afr = pin < 8u ? GPIO_AFRL : GPIO_AFRH;
  const uint32_t shift = 4u * (pin % 8u);
  REG32(port + afr) = (REG32(port + afr) & ~(0xFu << shift)) | (af << shift);
}

static void gpio_write(uint32_t port, uint32_t pin, bool high) {
  REG32(port + GPIO_BSRR) = high ? 1u << pin : 1u << (pin + 16u);
}

static void board_gpio_init(void) {
  REG32(RCC_AHB1ENR) |= RCC_AHB1ENR_GPIOAEN | RCC_AHB1ENR_GPIOBEN | RCC_AHB1ENR_GPIOCEN;
  (void)REG32(RCC_AHB1ENR);
  /* Safe levels before the pins become outputs: lasers off, driver disabled (ENABLE high), LED off (high). */
  REG32(GPIOB_BASE + GPIO_BSRR) = BOARD_SAFE_BSRR_B;
  gpio_write(BOARD_LED_PORT, BOARD_LED_PIN, true);
  gpio_mode(BOARD_LASER_PORT, BOARD_LASER_L_PIN, GPIO_MODE_OUTPUT, 0);
  gpio_mode(BOARD_LASER_PORT, BOARD_LASER_R_PIN, GPIO_MODE_OUTPUT, 0);
  gpio_mode(BOARD_ENABLE_PORT, BOARD_ENABLE_PIN, GPIO_MODE_OUTPUT, 0);
  gpio_mode(BOARD_DIR_PORT, BOARD_DIR_PIN, GPIO_MODE_OUTPUT, 0);
  gpio_mode(BOARD_LED_PORT, BOARD_LED_PIN, GPIO_MODE_OUTPUT, 0);
  gpio_mode(BOARD_STEP_PORT, BOARD_STEP_PIN, GPIO_MODE_AF, BOARD_STEP_AF);
  gpio_mode(BOARD_TRIGGER_PORT, BOARD_TRIGGER_PIN, GPIO_MODE_AF, BOARD_TRIGGER_AF);
  gpio_mode(BOARD_EXPOSURE_PORT, BOARD_EXPOSURE_PIN, GPIO_MODE_AF, BOARD_EXPOSURE_AF);
}

/* ---- timers ---- */

/* Output-compare mode of channel ch (1..4) in CCMR1/CCMR2. */
static void oc_mode(uint32_t tim, uint32_t ch, uint32_t mode) {
  const uint32_t reg = tim + (ch <= 2u ? TIM_CCMR1 : TIM_CCMR2);
  const uint32_t shift = ((ch - 1u) % 2u) * 8u;
  REG32(reg) = (REG32(reg) & ~(0xFFu << shift)) | ((TIM_CCMR_CCS_OUTPUT | mode << 4) << shift);
}

static void timers_init(void) {
  REG32(RCC_APB1ENR) |= RCC_APB1ENR_TIM2EN | RCC_APB1ENR_TIM3EN;
  (void)REG32(RCC_APB1ENR);
  /* TIM2: the free-running 32-bit 1 MHz timebase (core/timebase.c extends it to 64 bits). */
  TIM2_REG(TIM_PSC) = CLOCK_TIMER_HZ / 1000000u - 1u;
  TIM2_REG(TIM_ARR) = 0xFFFFFFFFu;
  oc_mode(TIM2_BASE, BOARD_TRIGGER_CH, TIM_OCM_FORCE_INACTIVE);
  oc_mode(TIM2_BASE, BOARD_LASER_CH, TIM_OCM_FROZEN);
  TIM2_REG(TIM_CCER) = TIM_CCER_CCE(BOARD_TRIGGER_CH);
  TIM2_REG(TIM_EGR) = TIM_EGR_UG; /* load the prescaler */
  TIM2_REG(TIM_SR) = 0u;
  TIM2_REG(TIM_CR1) = TIM_CR1_CEN;
  /* TIM3: step intervals, 1 MHz, ARR written directly (no preload) from the update interrupt. */
  TIM3_REG(TIM_PSC) = CLOCK_TIMER_HZ / 1000000u - 1u;
  TIM3_REG(TIM_ARR) = 0xFFFFu;
  oc_mode(TIM3_BASE, BOARD_STEP_CH, TIM_OCM_FORCE_INACTIVE);
  TIM3_REG(TIM_CCER) = TIM_CCER_CCE(BOARD_STEP_CH);
  TIM3_REG(TIM_CR1) = TIM_CR1_URS;
  TIM3_REG(TIM_EGR) = TIM_EGR_UG;
  TIM3_REG(TIM_SR) = 0u;
  TIM3_REG(TIM_DIER) = TIM_DIER_UIE;
  nvic_enable(IRQ_TIM2, PRIO_TIMEBASE);
  nvic_enable(IRQ_TIM3, PRIO_STEP);
}

void TIM2_IRQHandler(void);
void TIM2_IRQHandler(void) {
  const uint32_t sr = TIM2_REG(TIM_SR) & TIM2_REG(TIM_DIER);
  g_port.woke = true;
  if (sr & TIM_SR_CCIF(WAKE_CH)) { /* the main loop's deadline: nothing to do but wake it */
    TIM2_REG(TIM_SR) = ~TIM_SR_CCIF(WAKE_CH);
    TIM2_REG(TIM_DIER) &= ~TIM_DIER_CCIE(WAKE_CH);
  }
  if (sr & TIM_SR_CCIF(BOARD_LASER_CH)) {
    TIM2_REG(TIM_SR) = ~TIM_SR_CCIF(BOARD_LASER_CH); /* rc_w0: write 0 to clear, 1 leaves the others */
    TIM2_REG(TIM_DIER) &= ~TIM_DIER_CCIE(BOARD_LASER_CH);
    const uint8_t m = g_port.laser_next;
    REG32(BOARD_LASER_PORT + GPIO_BSRR) =
        ((m & 1u) ? 1u << BOARD_LASER_L_PIN : 1u << (BOARD_LASER_L_PIN + 16u)) |
        ((m & 2u) ? 1u << BOARD_LASER_R_PIN : 1u << (BOARD_LASER_R_PIN + 16u));
  }
  if (sr & TIM_SR_CCIF(BOARD_TRIGGER_CH)) {
    TIM2_REG(TIM_SR) = ~TIM_SR_CCIF(BOARD_TRIGGER_CH);
    if (!g_port.trigger_high) {
      /* The compare made the rising edge at trigger_at; the falling edge is the next compare. */
      g_port.trigger_high = true;
      TIM2_REG(TIM_CCR1) = g_port.trigger_at + g_port.trigger_pulse;
      oc_mode(TIM2_BASE, BOARD_TRIGGER_CH, TIM_OCM_INACTIVE_ON_MATCH);
      fw_isr_trigger(g_port.trigger_at);
    } else {
      g_port.trigger_high = false;
      TIM2_REG(TIM_DIER) &= ~TIM_DIER_CCIE(BOARD_TRIGGER_CH);
    }
  }
  if (sr & TIM_SR_CCIF(BOARD_EXPOSURE_CH)) {
    const uint32_t at = TIM2_REG(TIM_CCR3); /* reading CCR3 clears CC3IF */
    const bool level = (REG32(BOARD_EXPOSURE_PORT + GPIO_IDR) & (1u << BOARD_EXPOSURE_PIN)) != 0u;
    fw_isr_exposure(at, level);
  }
}

static void step_timer_load(uint32_t delay_us) {
  /* TIM3 counts 16 bits: a longer interval is waited for in chunks of 65536 us. */
  if (delay_us > 65536u) {
    g_port.step_long = delay_us - 65536u;
    TIM3_REG(TIM_ARR) = 0xFFFFu;
  } else {
    g_port.step_long = 0u;
    TIM3_REG(TIM_ARR) = delay_us - 1u;
  }
}

void TIM3_IRQHandler(void);
void TIM3_IRQHandler(void) {
  const uint32_t t0 = dwt_cycles();
  TIM3_REG(TIM_SR) = ~TIM_SR_UIF;
  g_port.woke = true;
  if (g_port.step_long > 0u) {
    step_timer_load(g_port.step_long);
    return;
  }
  const uint32_t next = fw_isr_step();
  if (next == 0u) {
    TIM3_REG(TIM_CR1) &= ~TIM_CR1_CEN;
  } else {
    step_timer_load(next);
  }
  const uint32_t cycles = dwt_cycles() - t0;
  g_port.isr_cycles_last = cycles;
  if (cycles > g_port.isr_cycles_max) g_port.isr_cycles_max = cycles;
}

uint32_t port_step_isr_cycles_max(void) {
  return g_port.isr_cycles_max;
}
uint32_t port_step_isr_cycles_last(void) {
  return g_port.isr_cycles_last;
}

/* ---- hal.h ---- */

uint32_t hal_timer_now(void) {
  return TIM2_REG(TIM_CNT);
}

void hal_lasers_set(uint8_t mask) {
  TIM2_REG(TIM_DIER) &= ~TIM_DIER_CCIE(BOARD_LASER_CH);
  REG32(BOARD_LASER_PORT + GPIO_BSRR) = ((mask & 1u) ? 1u << BOARD_LASER_L_PIN : 1u << (BOARD_LASER_L_PIN + 16u)) |
                                        ((mask & 2u) ? 1u << BOARD_LASER_R_PIN : 1u << (BOARD_LASER_R_PIN + 16u));
}

uint8_t hal_lasers_get(void) {
  const uint32_t odr = REG32(BOARD_LASER_PORT + GPIO_ODR);
  return (uint8_t)(((odr >> BOARD_LASER_L_PIN) & 1u) | (((odr >> BOARD_LASER_R_PIN) & 1u) << 1));
}

int hal_lasers_schedule(uint8_t mask, uint32_t at) {
  TIM2_REG(TIM_DIER) &= ~TIM_DIER_CCIE(BOARD_LASER_CH);
  g_port.laser_next = mask;
  TIM2_REG(TIM_CCR2) = at;
  TIM2_REG(TIM_SR) = ~TIM_SR_CCIF(BOARD_LASER_CH);
  TIM2_REG(TIM_DIER) |= TIM_DIER_CCIE(BOARD_LASER_CH);
  return 0;
}

void hal_trigger_schedule(uint32_t at, uint32_t pulse_us) {
  TIM2_REG(TIM_DIER) &= ~TIM_DIER_CCIE(BOARD_TRIGGER_CH);
  g_port.trigger_at = at;
  g_port.trigger_pulse = pulse_us;
  g_port.trigger_high = false;
  oc_mode(TIM2_BASE, BOARD_TRIGGER_CH, TIM_OCM_FORCE_INACTIVE);
  TIM2_REG(TIM_CCR1) = at;
  oc_mode(TIM2_BASE, BOARD_TRIGGER_CH, TIM_OCM_ACTIVE_ON_MATCH); /* the pin goes high at `at`, in hardware */
  TIM2_REG(TIM_SR) = ~TIM_SR_CCIF(BOARD_TRIGGER_CH);
  TIM2_REG(TIM_DIER) |= TIM_DIER_CCIE(BOARD_TRIGGER_CH);
}

void hal_trigger_cancel(void) {
  TIM2_REG(TIM_DIER) &= ~TIM_DIER_CCIE(BOARD_TRIGGER_CH);
  oc_mode(TIM2_BASE, BOARD_TRIGGER_CH, TIM_OCM_FORCE_INACTIVE);
  g_port.trigger_high = false;
}

int hal_exposure_capture_enable(void) {
  /* CH3 as input capture on TI3, filter 8 samples at 96 MHz (83 ns), both edges. */
  const uint32_t ccmr = TIM2_REG(TIM_CCMR2) & ~0xFFu;
  TIM2_REG(TIM_CCMR2) = ccmr | TIM_CCMR_CCS_INPUT_TI | (3u << 4);
  TIM2_REG(TIM_CCER) |= TIM_CCER_CCE(BOARD_EXPOSURE_CH) | TIM_CCER_CCP(BOARD_EXPOSURE_CH) |
                        TIM_CCER_CCNP(BOARD_EXPOSURE_CH);
  TIM2_REG(TIM_SR) = ~TIM_SR_CCIF(BOARD_EXPOSURE_CH);
  TIM2_REG(TIM_DIER) |= TIM_DIER_CCIE(BOARD_EXPOSURE_CH);
  return 0;
}

void hal_motor_enable(bool enable) {
  gpio_write(BOARD_ENABLE_PORT, BOARD_ENABLE_PIN, !enable); /* active low */
}

void hal_step_dir(bool high) {
  gpio_write(BOARD_DIR_PORT, BOARD_DIR_PIN, high);
}

void hal_step_timer_start(uint32_t delay_us) {
  TIM3_REG(TIM_CR1) &= ~TIM_CR1_CEN;
  TIM3_REG(TIM_CNT) = 0u;
  step_timer_load(delay_us == 0u ? 1u : delay_us);
  TIM3_REG(TIM_SR) = ~TIM_SR_UIF;
  TIM3_REG(TIM_CR1) |= TIM_CR1_CEN;
}

void hal_step_timer_stop(void) {
  TIM3_REG(TIM_CR1) &= ~TIM_CR1_CEN;
  TIM3_REG(TIM_SR) = ~TIM_SR_UIF;
  g_port.step_long = 0u;
}

void hal_step_pulse(void) {
  /* Rising edge now (forced), falling edge by TIM3's compare BOARD_STEP_PULSE_US later, in hardware. */
  oc_mode(TIM3_BASE, BOARD_STEP_CH, TIM_OCM_FORCE_ACTIVE);
  TIM3_REG(TIM_CCR1) = TIM3_REG(TIM_CNT) + BOARD_STEP_PULSE_US;
  oc_mode(TIM3_BASE, BOARD_STEP_CH, TIM_OCM_INACTIVE_ON_MATCH);
}

int hal_uid(uint8_t out[12]) {
  for (uint32_t i = 0; i < 12u; ++i) out[i] = *(const volatile uint8_t*)(uintptr_t)(F4_UID_BASE + i);
  return 0;
}

bool hal_is_simulated(void) {
  return false;
}

static const fault_record_t* g_last_fault; /* the record of the fault before the last reset, or NULL */

int hal_diag(hal_diag_t* out) {
  out->cycles_valid = true;
  out->cpu_hz = CLOCK_SYSCLK_HZ;
  out->step_isr_cycles_max = g_port.isr_cycles_max;
  out->step_isr_cycles_last = g_port.isr_cycles_last;
  out->fault_valid = g_last_fault != NULL;
  if (g_last_fault != NULL) {
    out->fault_count = g_last_fault->count;
    out->fault_vector = g_last_fault->vector;
    out->fault_pc = g_last_fault->pc;
    out->fault_lr = g_last_fault->lr;
    out->fault_psr = g_last_fault->psr;
    out->fault_cfsr = g_last_fault->cfsr;
    out->fault_hfsr = g_last_fault->hfsr;
  } else {
    out->fault_count = out->fault_vector = out->fault_pc = out->fault_lr = out->fault_psr = 0u;
    out->fault_cfsr = out->fault_hfsr = 0u;
  }
  return 0;
}

/* ---- sleep ---- */

void port_note_wake(void) {
  g_port.woke = true;
}

/* Waits in WFI for an interrupt or until device time `wake` (see the top of this file). */
static void sleep_until(uint64_t wake) {
  __asm__ volatile("cpsid i" ::: "memory");
  const uint64_t now = tb_now();
  if (!g_port.woke && wake > now + SLEEP_MIN_US) {
    TIM2_REG(TIM_CCR4) = tb_to_counter(wake);
    TIM2_REG(TIM_SR) = ~TIM_SR_CCIF(WAKE_CH);
    TIM2_REG(TIM_DIER) |= TIM_DIER_CCIE(WAKE_CH);
    __asm__ volatile("dsb\n\twfi" ::: "memory");
    TIM2_REG(TIM_DIER) &= ~TIM_DIER_CCIE(WAKE_CH);
  }
  __asm__ volatile("cpsie i" ::: "memory");
}

/* ---- main ---- */

int main(void) {
  const bool crystal = clock_init();
  dwt_init();
  board_gpio_init();
  timers_init();
  const fault_record_t* fault = fault_take_record();
  g_last_fault = fault; /* kept for GET_DIAG until the next reset */
  fw_init(); /* before the transport's interrupt can deliver bytes into the core's queues */
  transport_init();
  if (!crystal) fw_report(FW_REPORT_ERROR, "25 MHz crystal did not start: running from HSI", 0, 0);
  if (fault != NULL) {
    fw_report(FW_REPORT_ERROR, "fault before reset: vector, pc", fault->vector, fault->pc);
    fw_report(FW_REPORT_ERROR, "fault status: cfsr, hfsr", fault->cfsr, fault->hfsr);
  }
  gpio_write(BOARD_LED_PORT, BOARD_LED_PIN, false); /* up */
  for (;;) {
    g_port.woke = false;
    fw_poll();
    transport_poll();
    sleep_until(fw_next_wakeup_us());
  }
}
