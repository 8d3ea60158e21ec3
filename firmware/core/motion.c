/* Stepper ownership and MOVE_DONE: see motion.h. */
#include "motion.h"

#include <string.h>

#include "rotoscan_protocol.h"
#include "state.h"
#include "stepper.h"
#include "timebase.h"

static struct {
  enum fw_move_owner owner;
  bool done_pending; /* a MOVE_DONE waiting for transmit room */
  proto_move_done_t done;
  uint32_t move_seq;
} g_motion;

void motion_init(void) {
  memset(&g_motion, 0, sizeof(g_motion));
}

static void queue_move_done(uint8_t status) {
  g_motion.done.move_seq = g_motion.move_seq++;
  g_motion.done.time_us = tb_now();
  g_motion.done.position = step_position();
  g_motion.done.status = status;
  g_motion.done_pending = true;
}

static void flush_move_done(void) {
  if (!g_motion.done_pending || !fw_event_room()) return;
  proto_msg_t msg;
  proto_msg_init(&msg, PROTO_MOVE_DONE, 0);
  msg.body.move_done = g_motion.done;
  g_motion.done_pending = !fw_send_event(&msg);
}

bool fw_start_move(int32_t steps, enum fw_move_owner owner) {
  if (g_motion.owner != FW_MOVE_NONE) return false;
  if (steps == 0) {
    if (owner == FW_MOVE_COMMAND) queue_move_done(PROTO_ST_OK); /* sent after the ACK, by fw_poll */
    return owner == FW_MOVE_COMMAND;
  }
  const step_profile_cfg_t profile = fw_profile();
  if (!step_start_move(steps, &profile, (fw_config()->flags & PROTO_CONFIG_INVERT_DIR) != 0)) return false;
  g_motion.owner = owner;
  return true;
}

enum fw_move_owner fw_move_owner(void) {
  return g_motion.owner;
}

void fw_stop_move(void) {
  if (g_motion.owner == FW_MOVE_NONE) return;
  step_abort();
  if (g_motion.owner == FW_MOVE_COMMAND) queue_move_done(PROTO_MOVE_ABORTED);
  g_motion.owner = FW_MOVE_NONE;
  flush_move_done();
}

enum fw_move_owner motion_poll(void) {
  enum fw_move_owner ended = FW_MOVE_NONE;
  if (step_poll()) {
    ended = g_motion.owner;
    g_motion.owner = FW_MOVE_NONE;
    if (ended == FW_MOVE_COMMAND) queue_move_done(PROTO_ST_OK);
  }
  flush_move_done();
  return ended;
}

bool motion_report_pending(void) {
  return g_motion.done_pending;
}
