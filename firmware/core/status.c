/* STATUS frames: see status.h. */
#include "status.h"

#include <string.h>

#include "hal.h"
#include "link.h"
#include "motion.h"
#include "sequencer.h"
#include "state.h"
#include "stepper.h"
#include "timebase.h"

static uint32_t g_status_seq;

void status_init(void) {
  g_status_seq = 0;
}

void fw_fill_status(proto_status_t* s, uint8_t cause) {
  memset(s, 0, sizeof(*s));
  s->status_seq = g_status_seq++;
  s->time_us = tb_now();
  s->cause = cause;
  if (seq_running()) {
    s->state = PROTO_STATE_RUNNING;
  } else if (seq_busy()) {
    s->state = PROTO_STATE_TRIGGER;
  } else if (fw_move_owner() != FW_MOVE_NONE) {
    s->state = PROTO_STATE_MOVING;
  } else {
    s->state = PROTO_STATE_IDLE;
  }
  s->flags = (uint8_t)((fw_motor_enabled() ? PROTO_FLAG_MOTOR_ENABLED : 0u) |
                       (seq_program_loaded() ? PROTO_FLAG_PROGRAM_LOADED : 0u) |
                       (fw_safety_tripped() ? PROTO_FLAG_SAFETY_TRIPPED : 0u));
  s->lasers = hal_lasers_get();
  s->position = step_position();
  s->program_next_step = seq_next_step();
  s->program_steps = seq_program_steps();
  s->trigger_count = seq_trigger_count();
  s->rx_errors = fw_rx_errors();
  s->events_dropped = fw_events_dropped();
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
