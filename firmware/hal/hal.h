/*
 * hal.h -- the contract between the firmware core (firmware/core, no register access) and a port
 * (firmware/port/<board>/). A port implements every hal_ function below and calls the core's entry points
 * (firmware/core/fw.h) from its main loop and its interrupt handlers.
 *
 * Contexts. "main" means called only from the main loop (fw_init / fw_poll); "any" means it may also be
 * called from an interrupt handler, so it must be short and reentrant with respect to the main loop; "isr"
 * means called only from the interrupt handler named. The core never calls a hal_ function from two
 * interrupt priorities at once.
 *
 * Timer model (the STM32F411 port: TIM2, 32 bit, 1 MHz): one free-running 32-bit microsecond counter is the
 * single timebase. Scheduled outputs (lasers, trigger) are given as absolute counter values; a port makes
 * them happen in hardware (output compare) at exactly that count, so their timestamps are exact.
 *
 * Optional hooks return -ENOSYS where the board lacks the feature; the core then falls back as each hook
 * says. Required hooks have no failure return.
 */
#ifndef ROTOSCAN_FIRMWARE_HAL_H_
#define ROTOSCAN_FIRMWARE_HAL_H_

#include <errno.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- Time ---------------------------------------------------------------------------------------------- */

/* The 32-bit, 1 MHz free-running counter, wrapping every 2^32 us (71.6 min). Context: any. Required. */
uint32_t hal_timer_now(void);

/* ---- Lasers -------------------------------------------------------------------------------------------- */

/* Switches the laser outputs to `mask` (PROTO_LASER_* bits) now, cancelling any scheduled change.
 * Context: any (the safety timeout may call it). Required. */
void hal_lasers_set(uint8_t mask);

/* The laser outputs' state now, as the pins are (not as requested). Context: any. Required. */
uint8_t hal_lasers_get(void);

/* Switches the lasers to `mask` when the counter reaches `at` (output compare), replacing a change already
 * scheduled. `at` is at most 2^31 us ahead. Context: main. Optional: -ENOSYS makes the core switch them
 * itself with hal_lasers_set as close to `at` as its main loop can. */
int hal_lasers_schedule(uint8_t mask, uint32_t at);

/* ---- Camera -------------------------------------------------------------------------------------------- */

/* Makes the camera trigger rising edge when the counter reaches `at` (output compare) and the falling edge
 * `pulse_us` later. When the rising edge happens the port calls fw_isr_trigger(at) from the compare
 * interrupt. Context: main. Required. */
void hal_trigger_schedule(uint32_t at, uint32_t pulse_us);

/* Cancels a scheduled trigger (no edge, no fw_isr_trigger) and drives the trigger output low. Context: main.
 * Required. */
void hal_trigger_cancel(void);

/* Enables input capture of the camera's exposure-active line: on each edge the port calls
 * fw_isr_exposure(capture_time, level) from the capture interrupt. Context: main. Optional: -ENOSYS means
 * the board does not read the line (no exposure-seen times, PROTO_CAP_EXPOSURE_IN not advertised). */
int hal_exposure_capture_enable(void);

/* ---- Stepper ------------------------------------------------------------------------------------------- */

/* Enables (true) or disables the stepper driver. Context: main. Required. */
void hal_motor_enable(bool enable);

/* Sets the DIR output (true = the pin high). The core waits at least HAL_DIR_SETUP_US before the next step.
 * Context: main. Required. */
void hal_step_dir(bool high);

/* Starts the step timer: its interrupt fires `delay_us` from now and calls fw_isr_step(), whose return value
 * is the delay to the next interrupt (from this one's scheduled time, not from when it ran, so that delays do
 * not accumulate latency); 0 stops the timer. Context: main. Required. */
void hal_step_timer_start(uint32_t delay_us);

/* Stops the step timer at once (no further fw_isr_step). Context: any. Required. */
void hal_step_timer_stop(void);

/* Makes one STEP pulse (rising edge now, falling edge after the driver's minimum pulse width, done by the
 * hardware or by the port). Context: isr (fw_isr_step). Required. */
void hal_step_pulse(void);

/* ---- USB / serial link --------------------------------------------------------------------------------- */

/* Tells the port that fw_usb_tx has bytes to send (e.g. to arm the bulk IN endpoint). Context: main.
 * Optional: -ENOSYS if the port polls fw_usb_tx on its own. */
int hal_usb_tx_kick(void);

/* ---- Board --------------------------------------------------------------------------------------------- */

/* The MCU's 96-bit unique id. Context: main. Optional: -ENOSYS reports an id of zeros. */
int hal_uid(uint8_t out[12]);

/* Whether the board is the host simulation (advertised as PROTO_CAP_SIMULATED). Context: main. Required. */
bool hal_is_simulated(void);

/* What only the port knows about itself, for GET_DIAG (protocol 1.1). */
typedef struct {
  bool cycles_valid;             /* the port measures its step interrupt in CPU cycles */
  uint32_t cpu_hz;               /* the clock of those cycles */
  uint32_t step_isr_cycles_max;  /* the worst run since power-on */
  uint32_t step_isr_cycles_last; /* the last run */
  bool fault_valid;              /* a fault was recorded before the last reset: the fields below */
  uint32_t fault_count, fault_vector, fault_pc, fault_lr, fault_psr, fault_cfsr, fault_hfsr;
} hal_diag_t;
/* Fills *out. Context: main. Optional: -ENOSYS (then GET_DIAG is not advertised and is refused). */
int hal_diag(hal_diag_t* out);

/* Compiler barrier for the single-producer single-consumer queues shared between an interrupt and the main
 * loop (a single-core Cortex-M4 needs no hardware barrier between them). */
#if defined(__GNUC__) || defined(__clang__)
#define HAL_BARRIER() __asm__ __volatile__("" ::: "memory")
#else
#error "HAL_BARRIER: unsupported compiler"
#endif

/* Time the DIR output must be stable before a STEP edge (DRV8825: 650 ns; A4988: 200 ns). */
#define HAL_DIR_SETUP_US 5

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_HAL_H_ */
