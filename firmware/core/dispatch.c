#include "dispatch.h"

#include <string.h>

#include "hal.h"
#include "link.h"
#include "motion.h"
#include "sequencer.h"
#include "state.h"
#include "status.h"
#include "timebase.h"
#include "version.h"

/* The largest answer is DIAG (41 bytes), then STATUS (40). */
#define DISP_ANSWER_PAYLOAD_MAX (PROTO_DIAG_SIZE > PROTO_STATUS_SIZE ? PROTO_DIAG_SIZE : PROTO_STATUS_SIZE)
#define DISP_ANSWER_MAX \
  (PROTO_COBS_MAX_ENCODED(PROTO_HEADER_SIZE + DISP_ANSWER_PAYLOAD_MAX + PROTO_CRC_SIZE) + 1)
PROTO_STATIC_ASSERT(DISP_ANSWER_MAX <= 64, "answers stay small");
PROTO_STATIC_ASSERT(PROTO_INFO_SIZE <= DISP_ANSWER_PAYLOAD_MAX &&
                        PROTO_PONG_SIZE <= DISP_ANSWER_PAYLOAD_MAX &&
                        PROTO_ACK_SIZE <= DISP_ANSWER_PAYLOAD_MAX,
                    "DIAG or STATUS is the largest answer");

typedef struct {
  bool valid;
  uint16_t seq;
  uint8_t type;
  uint32_t crc; /* of the command frame */
  uint8_t len;
  uint8_t wire[DISP_ANSWER_MAX];
} answer_t;

static struct {
  answer_t cache[DISP_DUP_WINDOW];
  uint32_t next_slot;
  uint32_t duplicates;
} g_disp;

void disp_init(void) {
  memset(&g_disp, 0, sizeof(g_disp));
}
uint32_t disp_duplicates(void) {
  return g_disp.duplicates;
}

static void make_ack(proto_msg_t* reply, const proto_msg_t* cmd, uint8_t status, uint8_t detail) {
  proto_msg_init(reply, status == PROTO_ST_OK ? PROTO_ACK : PROTO_NACK, cmd->seq);
  reply->body.ack.acked_seq = cmd->seq;
  reply->body.ack.acked_type = cmd->type;
  reply->body.ack.status = status;
  reply->body.ack.detail = detail;
}

/* Sends a NACK for a frame that could not be (fully) decoded; not cached. */
static void send_nack(const proto_msg_t* cmd, uint8_t status) {
  proto_msg_t reply;
  make_ack(&reply, cmd, status, 0);
  uint8_t wire[DISP_ANSWER_MAX];
  const int n = proto_encode_frame(&reply, wire, sizeof(wire));
  if (n > 0) (void)usb_send_wire(wire, (size_t)n);
}

static uint8_t check_config(const proto_config_t* c, uint8_t* field) {
  if (c->start_rate_hz < 1u || c->start_rate_hz > c->max_rate_hz)
    *field = 1;
  else if (c->max_rate_hz > 100000u)
    *field = 2;
  else if (c->accel_hz_per_s < 1u || c->accel_hz_per_s > 10000000u)
    *field = 3;
  else if (c->trigger_pulse_us < 1u || c->trigger_pulse_us > 100000u)
    *field = 4;
  else if (c->laser_timeout_ms < 100u || c->laser_timeout_ms > 600000u)
    *field = 5;
  else if ((c->flags & ~PROTO_CONFIG_INVERT_DIR) != 0)
    *field = 6;
  return *field == 0 ? PROTO_ST_OK : PROTO_ST_BAD_VALUE;
}

static bool diag_supported(void) {
  hal_diag_t d;
  return hal_diag(&d) == 0;
}

static bool moving_or_running(void) {
  return fw_move_owner() != FW_MOVE_NONE || seq_busy();
}

/* Executes a decoded command and fills its answer. Sets *abort_after when ABORT's work must follow the ACK
 * (so that the host sees the ACK before the events the abort produces). */
static void execute(const proto_msg_t* cmd, proto_msg_t* reply, bool* abort_after) {
  uint8_t st = PROTO_ST_OK;
  uint8_t field = 0;
  switch (cmd->type) {
    case PROTO_GET_INFO: {
      proto_msg_init(reply, PROTO_INFO, cmd->seq);
      proto_info_t* info = &reply->body.info;
      info->proto_major = PROTO_VERSION_MAJOR;
      info->proto_minor = PROTO_VERSION_MINOR;
      info->capabilities = PROTO_CAP_STEPPER | PROTO_CAP_LASERS | PROTO_CAP_TRIGGER_OUT | PROTO_CAP_PROGRAM |
                           PROTO_CAP_LASER_SAFETY | (seq_has_exposure_input() ? PROTO_CAP_EXPOSURE_IN : 0u) |
                           (hal_is_simulated() ? PROTO_CAP_SIMULATED : 0u) |
                           (diag_supported() ? PROTO_CAP_DIAG : 0u);
      info->fw_major = FW_VERSION_MAJOR;
      info->fw_minor = FW_VERSION_MINOR;
      info->fw_patch = FW_VERSION_PATCH;
      info->max_payload = PROTO_MAX_PAYLOAD;
      info->max_shots = PROTO_MAX_SHOTS;
      if (hal_uid(info->uid) != 0) memset(info->uid, 0, sizeof(info->uid));
      return;
    }
    case PROTO_PING:
      proto_msg_init(reply, PROTO_PONG, cmd->seq);
      reply->body.pong.host_time_us = cmd->body.ping.host_time_us;
      reply->body.pong.device_time_us = tb_now();
      return;
    case PROTO_GET_STATUS:
      proto_msg_init(reply, PROTO_STATUS, cmd->seq);
      fw_fill_status(&reply->body.status, PROTO_CAUSE_REPLY);
      return;
    case PROTO_GET_DIAG: {
      hal_diag_t d;
      memset(&d, 0, sizeof(d));
      if (hal_diag(&d) != 0) {
        st = PROTO_ST_UNKNOWN_TYPE; /* as a 1.0 device answers it */
        break;
      }
      proto_msg_init(reply, PROTO_DIAG, cmd->seq);
      proto_diag_t* out = &reply->body.diag;
      out->flags = (uint8_t)((d.cycles_valid ? PROTO_DIAG_CYCLES_VALID : 0u) |
                             (d.fault_valid ? PROTO_DIAG_FAULT_VALID : 0u));
      if (d.cycles_valid) {
        out->cpu_hz = d.cpu_hz;
        out->step_isr_cycles_max = d.step_isr_cycles_max;
        out->step_isr_cycles_last = d.step_isr_cycles_last;
      }
      if (d.fault_valid) {
        out->fault_count = d.fault_count;
        out->fault_vector = d.fault_vector;
        out->fault_pc = d.fault_pc;
        out->fault_lr = d.fault_lr;
        out->fault_psr = d.fault_psr;
        out->fault_cfsr = d.fault_cfsr;
        out->fault_hfsr = d.fault_hfsr;
      }
      return;
    }
    case PROTO_SET_CONFIG:
      if (moving_or_running()) {
        st = PROTO_ST_BUSY;
      } else if ((st = check_config(&cmd->body.config, &field)) == PROTO_ST_OK) {
        fw_set_config(&cmd->body.config);
      }
      break;
    case PROTO_MOTOR_ENABLE:
      if (cmd->body.motor_enable.enable > 1u) {
        st = PROTO_ST_BAD_VALUE;
        field = 1;
      } else if (moving_or_running()) {
        st = PROTO_ST_BUSY;
      } else {
        fw_set_motor_enabled(cmd->body.motor_enable.enable != 0);
      }
      break;
    case PROTO_MOVE: {
      const int32_t steps = cmd->body.move.steps;
      if (steps < -PROTO_MAX_MOVE_STEPS || steps > PROTO_MAX_MOVE_STEPS) {
        st = PROTO_ST_BAD_VALUE;
        field = 1;
      } else if (moving_or_running()) {
        st = PROTO_ST_BUSY;
      } else if (!fw_motor_enabled()) {
        st = PROTO_ST_MOTOR_DISABLED;
      } else if (!fw_start_move(steps, FW_MOVE_COMMAND)) {
        st = PROTO_ST_INTERNAL;
      }
      break;
    }
    case PROTO_SET_LASERS:
      if ((cmd->body.set_lasers.mask & ~PROTO_LASER_ALL) != 0) {
        st = PROTO_ST_BAD_VALUE;
        field = 1;
      } else if (seq_busy()) {
        st = PROTO_ST_BUSY;
      } else {
        seq_set_idle_lasers(cmd->body.set_lasers.mask);
      }
      break;
    case PROTO_TRIGGER: st = seq_trigger(&cmd->body.trigger, &field); break;
    case PROTO_LOAD_PROGRAM:
      st = fw_move_owner() != FW_MOVE_NONE ? PROTO_ST_BUSY : seq_load(&cmd->body.program, &field);
      break;
    case PROTO_START: st = seq_start(cmd->body.start.first_step, &field); break;
    case PROTO_ABORT: *abort_after = true; break;
    default: st = PROTO_ST_UNKNOWN_TYPE; break;
  }
  make_ack(reply, cmd, st, field);
}

static void handle_frame(const uint8_t* stuffed, size_t len) {
  uint8_t raw[PROTO_MAX_RAW_FRAME];
  proto_msg_t cmd;
  memset(&cmd, 0, sizeof(cmd));
  const int n = proto_cobs_decode(stuffed, len, raw, sizeof(raw));
  if (n < 0) {
    fw_count_rx_error();
    send_nack(&cmd, PROTO_ST_BAD_FRAME);
    return;
  }
  const int rc = proto_unpack(raw, (size_t)n, &cmd);
  if (rc == -EBADMSG) {
    fw_count_rx_error();
    const bool long_enough = (size_t)n >= PROTO_HEADER_SIZE + PROTO_CRC_SIZE;
    send_nack(&cmd, long_enough ? PROTO_ST_BAD_CRC : PROTO_ST_BAD_FRAME);
    return;
  }
  /* From here the CRC matched: the host is talking to us. */
  fw_host_seen();
  if (rc < 0) {
    fw_count_rx_error();
    send_nack(&cmd, proto_status_from_error(rc));
    return;
  }
  if (!proto_is_command(cmd.type)) {
    fw_count_rx_error();
    send_nack(&cmd, PROTO_ST_UNKNOWN_TYPE);
    return;
  }

  const uint32_t crc = proto_get_u32(raw + n - PROTO_CRC_SIZE);
  for (uint32_t i = 0; i < DISP_DUP_WINDOW; ++i) {
    const answer_t* a = &g_disp.cache[i];
    if (a->valid && a->seq == cmd.seq && a->type == cmd.type && a->crc == crc) {
      ++g_disp.duplicates;
      (void)usb_send_wire(a->wire, a->len); /* a retransmission: answer again, do not execute again */
      return;
    }
  }

  proto_msg_t reply;
  bool abort_after = false;
  execute(&cmd, &reply, &abort_after);
  fw_set_safety_tripped(false); /* after the answer, so that a GET_STATUS still reports the trip */
  answer_t* slot = &g_disp.cache[g_disp.next_slot++ % DISP_DUP_WINDOW];
  const int w = proto_encode_frame(&reply, slot->wire, sizeof(slot->wire));
  if (w <= 0) { /* unreachable: every answer fits */
    slot->valid = false;
    send_nack(&cmd, PROTO_ST_INTERNAL);
    return;
  }
  slot->valid = true;
  slot->seq = cmd.seq;
  slot->type = cmd.type;
  slot->crc = crc;
  slot->len = (uint8_t)w;
  (void)usb_send_wire(slot->wire, slot->len);
  if (abort_after) {
    const bool stopped_program = seq_abort();
    const bool stopped_move = fw_move_owner() != FW_MOVE_NONE;
    fw_stop_move();
    if (stopped_program || stopped_move) (void)fw_send_status(PROTO_CAUSE_ABORTED, 0);
  }
}

void disp_poll(void) {
  /* One answer and the events an ABORT makes must fit before a frame is taken off the queue. */
  while (usb_tx_room(3u * PROTO_MAX_WIRE_FRAME)) {
    const uint8_t* frame = NULL;
    size_t len = 0;
    const int r = usb_next_frame(&frame, &len);
    if (r == 0) break;
    if (r < 0) {
      proto_msg_t none;
      memset(&none, 0, sizeof(none));
      fw_count_rx_error();
      send_nack(&none, PROTO_ST_OVERFLOW);
      continue;
    }
    handle_frame(frame, len);
  }
}
