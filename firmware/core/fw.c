/*
 * The firmware's top level: configuration, the main-loop pass, the interrupt entry points, events and the
 * laser safety timeout.
 *
 * Laser safety: every frame from the host with a good CRC restarts a timer of laser_timeout_ms (SET_CONFIG,
 * default FW_DEFAULT_LASER_TIMEOUT_MS). When it runs out while a laser is on or a program or trigger is
 * running, the lasers are switched off, the program is stopped where it was (STATUS.program_next_step says
 * where to resume with START), and a STATUS event with cause SAFETY and a LOG warning are sent. A host
 * keeps a scan alive by sending PING (which it does anyway for clock synchronisation).
 */
#include "fw.h"

#include <string.h>

#include "dispatch.h"
#include "fw_internal.h"
#include "hal.h"
#include "link.h"
#include "sequencer.h"
#include "timebase.h"

static struct {
  proto_config_t config;
  bool motor_enabled;
  enum fw_move_owner move_owner;
  bool move_done_pending; /* a MOVE_DONE waiting for transmit room */
  proto_move_done_t move_done;
  uint32_t move_seq;
  uint32_t status_seq;
  uint32_t log_seq;
  uint16_t event_frame_seq;
  uint32_t events_dropped;
  uint32_t rx_errors;
  uint64_t host_seen_at;
  bool safety_tripped;
} g_fw;

/* ---- configuration and state ---- */

const proto_config_t* fw_config(void) {
  return &g_fw.config;
}

step_profile_cfg_t fw_profile(void) {
  step_profile_cfg_t p;
  p.start_rate_hz = g_fw.config.start_rate_hz;
  p.max_rate_hz = g_fw.config.max_rate_hz;
  p.accel_hz_per_s = g_fw.config.accel_hz_per_s;
  return p;
}

void fw_set_config(const proto_config_t* config) {
  g_fw.config = *config;
}

bool fw_motor_enabled(void) {
  return g_fw.motor_enabled;
}
void fw_set_motor_enabled(bool enabled) {
  g_fw.motor_enabled = enabled;
  hal_motor_enable(enabled);
}

void fw_host_seen(void) {
  g_fw.host_seen_at = tb_now();
}
bool fw_safety_tripped(void) {
  return g_fw.safety_tripped;
}
void fw_clear_safety(void) {
  g_fw.safety_tripped = false;
}
uint32_t fw_rx_errors(void) {
  return g_fw.rx_errors;
}
void fw_count_rx_error(void) {
  ++g_fw.rx_errors;
}

/* ---- events ---- */

bool fw_event_room(void) {
  return usb_tx_room(PROTO_MAX_WIRE_FRAME);
}

bool fw_send_event(proto_msg_t* msg) {
  msg->seq = g_fw.event_frame_seq;
  uint8_t wire[PROTO_MAX_WIRE_FRAME];
  const int n = proto_encode_frame(msg, wire, sizeof(wire));
  if (n <= 0 || !usb_send_wire(wire, (size_t)n)) {
    ++g_fw.events_dropped;
    return false;
  }
  ++g_fw.event_frame_seq;
  return true;
}

void fw_fill_status(proto_status_t* s, uint8_t cause) {
  memset(s, 0, sizeof(*s));
  s->status_seq = g_fw.status_seq++;
  s->time_us = tb_now();
  s->cause = cause;
  if (seq_running()) {
    s->state = PROTO_STATE_RUNNING;
  } else if (seq_busy()) {
    s->state = PROTO_STATE_TRIGGER;
  } else if (g_fw.move_owner != FW_MOVE_NONE) {
    s->state = PROTO_STATE_MOVING;
  } else {
    s->state = PROTO_STATE_IDLE;
  }
  s->flags = (uint8_t)((g_fw.motor_enabled ? PROTO_FLAG_MOTOR_ENABLED : 0u) |
                       (seq_program_loaded() ? PROTO_FLAG_PROGRAM_LOADED : 0u) |
                       (g_fw.safety_tripped ? PROTO_FLAG_SAFETY_TRIPPED : 0u));
  s->lasers = hal_lasers_get();
  s->position = step_position();
  s->program_next_step = seq_next_step();
  s->program_steps = seq_program_steps();
  s->trigger_count = seq_trigger_count();
  s->rx_errors = g_fw.rx_errors;
  s->events_dropped = g_fw.events_dropped;
}

bool fw_send_status(uint8_t cause, uint16_t reply_seq) {
  proto_msg_t msg;
  proto_msg_init(&msg, PROTO_STATUS, reply_seq);
  fw_fill_status(&msg.body.status, cause);
  if (cause != PROTO_CAUSE_REPLY) return fw_send_event(&msg);
  uint8_t wire[PROTO_MAX_WIRE_FRAME];
  const int n = proto_encode_frame(&msg, wire, sizeof(wire));
  return n > 0 && usb_send_wire(wire, (size_t)n);
}

void fw_log(uint8_t level, const char* text) {
  proto_msg_t msg;
  proto_msg_init(&msg, PROTO_LOG, 0);
  msg.body.log.log_seq = g_fw.log_seq++;
  msg.body.log.level = level;
  size_t n = strlen(text);
  if (n > PROTO_MAX_LOG_TEXT) n = PROTO_MAX_LOG_TEXT;
  memcpy(msg.body.log.text, text, n);
  msg.body.log.length = (uint8_t)n;
  (void)fw_send_event(&msg);
}

PROTO_STATIC_ASSERT(FW_REPORT_INFO == PROTO_LOG_INFO && FW_REPORT_WARNING == PROTO_LOG_WARNING &&
                        FW_REPORT_ERROR == PROTO_LOG_ERROR,
                    "fw_report levels are LOG levels");

static size_t append_hex(char* out, size_t at, size_t cap, uint32_t v) {
  static const char digits[] = "0123456789abcdef";
  const char head[3] = {' ', '0', 'x'};
  for (size_t i = 0; i < 3u && at < cap; ++i) out[at++] = head[i];
  for (int shift = 28; shift >= 0 && at < cap; shift -= 4) out[at++] = digits[(v >> (uint32_t)shift) & 0xFu];
  return at;
}

void fw_report(uint8_t level, const char* text, uint32_t a, uint32_t b) {
  char line[PROTO_MAX_LOG_TEXT + 1];
  size_t n = strlen(text);
  if (n > PROTO_MAX_LOG_TEXT) n = PROTO_MAX_LOG_TEXT;
  memcpy(line, text, n);
  n = append_hex(line, n, PROTO_MAX_LOG_TEXT, a);
  n = append_hex(line, n, PROTO_MAX_LOG_TEXT, b);
  line[n] = '\0';
  fw_log(level, line);
}

/* ---- moves ---- */

static void queue_move_done(uint8_t status) {
  g_fw.move_done.move_seq = g_fw.move_seq++;
  g_fw.move_done.time_us = tb_now();
  g_fw.move_done.position = step_position();
  g_fw.move_done.status = status;
  g_fw.move_done_pending = true;
}

static void flush_move_done(void) {
  if (!g_fw.move_done_pending || !fw_event_room()) return;
  proto_msg_t msg;
  proto_msg_init(&msg, PROTO_MOVE_DONE, 0);
  msg.body.move_done = g_fw.move_done;
  g_fw.move_done_pending = !fw_send_event(&msg);
}

bool fw_start_move(int32_t steps, enum fw_move_owner owner) {
  if (g_fw.move_owner != FW_MOVE_NONE) return false;
  if (steps == 0) {
    if (owner == FW_MOVE_COMMAND) queue_move_done(PROTO_ST_OK); /* sent after the ACK, by fw_poll */
    return owner == FW_MOVE_COMMAND;
  }
  const step_profile_cfg_t profile = fw_profile();
  if (!step_start_move(steps, &profile, (g_fw.config.flags & PROTO_CONFIG_INVERT_DIR) != 0)) return false;
  g_fw.move_owner = owner;
  return true;
}

enum fw_move_owner fw_move_owner(void) {
  return g_fw.move_owner;
}

void fw_stop_move(void) {
  if (g_fw.move_owner == FW_MOVE_NONE) return;
  step_abort();
  if (g_fw.move_owner == FW_MOVE_COMMAND) queue_move_done(PROTO_MOVE_ABORTED);
  g_fw.move_owner = FW_MOVE_NONE;
  flush_move_done();
}

/* ---- main loop ---- */

void fw_init(void) {
  memset(&g_fw, 0, sizeof(g_fw));
  g_fw.config.start_rate_hz = FW_DEFAULT_START_RATE_HZ;
  g_fw.config.max_rate_hz = FW_DEFAULT_MAX_RATE_HZ;
  g_fw.config.accel_hz_per_s = FW_DEFAULT_ACCEL_HZ_PER_S;
  g_fw.config.trigger_pulse_us = FW_DEFAULT_TRIGGER_PULSE_US;
  g_fw.config.laser_timeout_ms = FW_DEFAULT_LASER_TIMEOUT_MS;
  tb_init();
  hal_lasers_set(0);
  hal_trigger_cancel();
  hal_motor_enable(false);
  usb_init();
  step_init();
  seq_init();
  disp_init();
  (void)fw_send_status(PROTO_CAUSE_BOOT, 0);
}

static uint64_t safety_deadline(void) {
  return g_fw.host_seen_at + (uint64_t)g_fw.config.laser_timeout_ms * 1000u;
}

static bool safety_armed(void) {
  return hal_lasers_get() != 0 || seq_busy();
}

static void check_safety(uint64_t now) {
  if (!safety_armed() || now <= safety_deadline()) return;
  (void)seq_abort();
  if (g_fw.move_owner == FW_MOVE_PROGRAM) fw_stop_move();
  g_fw.safety_tripped = true;
  (void)fw_send_status(PROTO_CAUSE_SAFETY, 0);
  fw_log(PROTO_LOG_WARNING, "laser safety: host silent, lasers off");
}

void fw_poll(void) {
  (void)tb_now(); /* keeps the 64-bit timebase across the counter's wrap */
  disp_poll();
  if (step_poll()) {
    const enum fw_move_owner owner = g_fw.move_owner;
    g_fw.move_owner = FW_MOVE_NONE;
    if (owner == FW_MOVE_COMMAND) queue_move_done(PROTO_ST_OK);
    if (owner == FW_MOVE_PROGRAM) seq_move_done();
  }
  flush_move_done();
  seq_poll();
  check_safety(tb_now());
}

uint64_t fw_next_wakeup_us(void) {
  const uint64_t now = tb_now();
  uint64_t next = now + TB_MAX_SLEEP_US;
  const uint64_t s = seq_next_wakeup();
  if (s < next) next = s;
  if (safety_armed() && safety_deadline() + 1u < next) next = safety_deadline() + 1u;
  if (g_fw.move_done_pending && now + 100u < next) next = now + 100u;
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
