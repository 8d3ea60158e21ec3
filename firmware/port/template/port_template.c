/*
 * The template port: every hal.h hook, doing nothing, and the main loop. It is what a new port starts from
 * (copy it to port/<board>/ and fill the hooks in), and the cross build links it with the core so that the
 * image's size is measured and every hook the core needs is known to exist. It touches no register; the
 * STM32F411 port (port/stm32f411/) is a later issue.
 */
#include "fw.h"
#include "hal.h"

static uint32_t g_counter; /* a real port reads its 32-bit 1 MHz timer (TIM2->CNT) */
static uint8_t g_lasers;

uint32_t hal_timer_now(void) {
  return g_counter++;
}
void hal_lasers_set(uint8_t mask) {
  g_lasers = mask;
}
uint8_t hal_lasers_get(void) {
  return g_lasers;
}
int hal_lasers_schedule(uint8_t mask, uint32_t at) {
  (void)mask;
  (void)at;
  return -ENOSYS; /* the core then switches the lasers itself */
}
void hal_trigger_schedule(uint32_t at, uint32_t pulse_us) {
  (void)at;
  (void)pulse_us;
}
void hal_trigger_cancel(void) {}
int hal_exposure_capture_enable(void) {
  return -ENOSYS;
}
void hal_motor_enable(bool enable) {
  (void)enable;
}
void hal_step_dir(bool high) {
  (void)high;
}
void hal_step_timer_start(uint32_t delay_us) {
  (void)delay_us;
}
void hal_step_timer_stop(void) {}
void hal_step_pulse(void) {}
int hal_usb_tx_kick(void) {
  return -ENOSYS;
}
int hal_uid(uint8_t out[12]) {
  (void)out;
  return -ENOSYS;
}
bool hal_is_simulated(void) {
  return false;
}
int hal_diag(hal_diag_t* out) {
  (void)out;
  return -ENOSYS;
}

int main(void) {
  fw_init();
  for (;;) fw_poll();
}
