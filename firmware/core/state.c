/* The core's shared state and event stream: see state.h. */
#include "state.h"

#include <string.h>

#include "fw.h" /* fw_report and its levels: the port-facing declaration */
#include "hal.h"
#include "link.h"
#include "timebase.h"

static struct {
  proto_config_t config;
  bool motor_enabled;
  uint32_t log_seq;
  uint16_t event_frame_seq;
  uint32_t events_dropped;
  uint32_t rx_errors;
  uint64_t host_seen_at;
  bool safety_tripped;
} g_state;

void state_init(void) {
  memset(&g_state, 0, sizeof(g_state));
  g_state.config.start_rate_hz = FW_DEFAULT_START_RATE_HZ;
  g_state.config.max_rate_hz = FW_DEFAULT_MAX_RATE_HZ;
  g_state.config.accel_hz_per_s = FW_DEFAULT_ACCEL_HZ_PER_S;
  g_state.config.trigger_pulse_us = FW_DEFAULT_TRIGGER_PULSE_US;
  g_state.config.laser_timeout_ms = FW_DEFAULT_LASER_TIMEOUT_MS;
}

const proto_config_t* fw_config(void) {
  return &g_state.config;
}

step_profile_cfg_t fw_profile(void) {
  step_profile_cfg_t p;
  p.start_rate_hz = g_state.config.start_rate_hz;
  p.max_rate_hz = g_state.config.max_rate_hz;
  p.accel_hz_per_s = g_state.config.accel_hz_per_s;
  return p;
}

void fw_set_config(const proto_config_t* config) {
  g_state.config = *config;
}

bool fw_motor_enabled(void) {
  return g_state.motor_enabled;
}
void fw_set_motor_enabled(bool enabled) {
  g_state.motor_enabled = enabled;
  hal_motor_enable(enabled);
}

void fw_host_seen(void) {
  g_state.host_seen_at = tb_now();
}
uint64_t fw_host_seen_at(void) {
  return g_state.host_seen_at;
}
bool fw_safety_tripped(void) {
  return g_state.safety_tripped;
}
void fw_set_safety_tripped(bool tripped) {
  g_state.safety_tripped = tripped;
}
uint32_t fw_rx_errors(void) {
  return g_state.rx_errors;
}
void fw_count_rx_error(void) {
  ++g_state.rx_errors;
}
uint32_t fw_events_dropped(void) {
  return g_state.events_dropped;
}

bool fw_event_room(void) {
  return usb_tx_room(PROTO_MAX_WIRE_FRAME);
}

bool fw_send_event(proto_msg_t* msg) {
  msg->seq = g_state.event_frame_seq;
  uint8_t wire[PROTO_MAX_WIRE_FRAME];
  const int n = proto_encode_frame(msg, wire, sizeof(wire));
  if (n <= 0 || !usb_send_wire(wire, (size_t)n)) {
    ++g_state.events_dropped;
    return false;
  }
  ++g_state.event_frame_seq;
  return true;
}

void fw_log(uint8_t level, const char* text) {
  proto_msg_t msg;
  proto_msg_init(&msg, PROTO_LOG, 0);
  msg.body.log.log_seq = g_state.log_seq++;
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
