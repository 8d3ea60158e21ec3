/*
 * The firmware's top level (the last layer of state.h's order): power-on, the main-loop pass, the interrupt
 * and link entry points, and the laser safety timeout.
 *
 * Laser safety: every frame from the host with a good CRC restarts a timer of laser_timeout_ms (SET_CONFIG,
 * default FW_DEFAULT_LASER_TIMEOUT_MS). When it runs out while a laser is on or a program or trigger is
 * running, the lasers are switched off, the program is stopped where it was (STATUS.program_next_step says
 * where to resume with START), and a STATUS event with cause SAFETY and a LOG warning are sent. A host
 * keeps a scan alive by sending PING (which it does anyway for clock synchronisation).
 */
#include "fw.h"

#include "dispatch.h"
#include "hal.h"
#include "link.h"
#include "motion.h"
#include "sequencer.h"
#include "state.h"
#include "status.h"
#include "stepper.h"
#include "timebase.h"

void fw_init(void) {
  state_init();
  tb_init();
  hal_lasers_set(0);
  hal_trigger_cancel();
  hal_motor_enable(false);
  usb_init();
  step_init();
  motion_init();
  seq_init();
  status_init();
  disp_init();
  (void)fw_send_status(PROTO_CAUSE_BOOT, 0);
}

static uint64_t safety_deadline(void) {
  return fw_host_seen_at() + (uint64_t)fw_config()->laser_timeout_ms * 1000u;
}

static bool safety_armed(void) {
  return hal_lasers_get() != 0 || seq_busy();
}

static void check_safety(uint64_t now) {
  if (!safety_armed() || now <= safety_deadline()) return;
  (void)seq_abort();
  if (fw_move_owner() == FW_MOVE_PROGRAM) fw_stop_move();
  fw_set_safety_tripped(true);
  (void)fw_send_status(PROTO_CAUSE_SAFETY, 0);
  fw_log(PROTO_LOG_WARNING, "laser safety: host silent, lasers off");
}

void fw_poll(void) {
  (void)tb_now(); /* keeps the 64-bit timebase across the counter's wrap */
  disp_poll();
  if (motion_poll() == FW_MOVE_PROGRAM) seq_move_done();
  const uint8_t cause = seq_poll();
  if (cause != SEQ_NO_STATUS) (void)fw_send_status(cause, 0);
  check_safety(tb_now());
}

uint64_t fw_next_wakeup_us(void) {
  const uint64_t now = tb_now();
  uint64_t next = now + TB_MAX_SLEEP_US;
  const uint64_t s = seq_next_wakeup();
  if (s < next) next = s;
  if (safety_armed() && safety_deadline() + 1u < next) next = safety_deadline() + 1u;
  if (motion_report_pending() && now + 100u < next) next = now + 100u;
  return next < now ? now : next;
}

/* ---- interrupt and link entry points ---- */

uint32_t fw_isr_step(void) {
  return step_isr();
}
void fw_isr_trigger(uint32_t at) {
  seq_isr_trigger(at);
}
void fw_isr_exposure(uint32_t at, bool level) {
  seq_isr_exposure(at, level);
}
size_t fw_usb_rx(const uint8_t* data, size_t len) {
  return usb_rx_isr(data, len);
}
size_t fw_usb_tx(uint8_t* out, size_t max) {
  return usb_tx_take(out, max);
}
size_t fw_usb_tx_pending(void) {
  return usb_tx_pending();
}
