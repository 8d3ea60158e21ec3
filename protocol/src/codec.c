/*
 * Message codec: every field is written and read one at a time, little endian, through a bounds-checked
 * cursor. Nothing here casts a struct onto the wire, so the layout does not depend on the compiler, the
 * padding or the host's endianness.
 */
#include <string.h>

#include "rotoscan_protocol.h"

/* ---- little endian ---- */

void proto_put_u16(uint8_t* p, uint16_t v) {
  p[0] = (uint8_t)v;
  p[1] = (uint8_t)(v >> 8);
}
void proto_put_u32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = (uint8_t)(v >> (8 * i));
}
void proto_put_u64(uint8_t* p, uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = (uint8_t)(v >> (8 * i));
}
uint16_t proto_get_u16(const uint8_t* p) {
  return (uint16_t)(p[0] | (p[1] << 8));
}
uint32_t proto_get_u32(const uint8_t* p) {
  uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}
uint64_t proto_get_u64(const uint8_t* p) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}

/* ---- names ---- */

bool proto_is_command(uint8_t type) {
  return type >= PROTO_GET_INFO && type <= PROTO_GET_DIAG;
}

const char* proto_type_name(uint8_t type) {
  switch (type) {
    case PROTO_GET_INFO: return "GET_INFO";
    case PROTO_PING: return "PING";
    case PROTO_SET_CONFIG: return "SET_CONFIG";
    case PROTO_MOTOR_ENABLE: return "MOTOR_ENABLE";
    case PROTO_MOVE: return "MOVE";
    case PROTO_SET_LASERS: return "SET_LASERS";
    case PROTO_TRIGGER: return "TRIGGER";
    case PROTO_LOAD_PROGRAM: return "LOAD_PROGRAM";
    case PROTO_START: return "START";
    case PROTO_ABORT: return "ABORT";
    case PROTO_GET_STATUS: return "GET_STATUS";
    case PROTO_GET_DIAG: return "GET_DIAG";
    case PROTO_ACK: return "ACK";
    case PROTO_NACK: return "NACK";
    case PROTO_INFO: return "INFO";
    case PROTO_PONG: return "PONG";
    case PROTO_DIAG: return "DIAG";
    case PROTO_TRIGGER_EVENT: return "TRIGGER_EVENT";
    case PROTO_MOVE_DONE: return "MOVE_DONE";
    case PROTO_STATUS: return "STATUS";
    case PROTO_LOG: return "LOG";
    default: return "UNKNOWN";
  }
}

const char* proto_status_name(uint8_t status) {
  switch (status) {
    case PROTO_ST_OK: return "ok";
    case PROTO_ST_BAD_FRAME: return "bad frame";
    case PROTO_ST_BAD_CRC: return "bad crc";
    case PROTO_ST_VERSION: return "protocol version mismatch";
    case PROTO_ST_UNKNOWN_TYPE: return "unknown message type";
    case PROTO_ST_BAD_LENGTH: return "bad payload length";
    case PROTO_ST_BAD_VALUE: return "value out of range";
    case PROTO_ST_BUSY: return "busy";
    case PROTO_ST_NO_PROGRAM: return "no program loaded";
    case PROTO_ST_MOTOR_DISABLED: return "motor disabled";
    case PROTO_ST_OVERFLOW: return "receive overflow";
    case PROTO_ST_INTERNAL: return "internal error";
    default: return "unknown";
  }
}

uint8_t proto_status_from_error(int err) {
  switch (err) {
    case 0: return PROTO_ST_OK;
    case -EPROTO: return PROTO_ST_VERSION;
    case -ENOMSG: return PROTO_ST_UNKNOWN_TYPE;
    case -EMSGSIZE: return PROTO_ST_BAD_LENGTH;
    case -EINVAL: return PROTO_ST_BAD_VALUE;
    case -ENOSPC: return PROTO_ST_OVERFLOW;
    case -EBADMSG: return PROTO_ST_BAD_FRAME;
    default: return PROTO_ST_INTERNAL;
  }
}

void proto_msg_init(proto_msg_t* msg, uint8_t type, uint16_t seq) {
  memset(msg, 0, sizeof(*msg));
  msg->version = PROTO_VERSION_MAJOR;
  msg->type = type;
  msg->seq = seq;
}

/* ---- payload sizes ---- */

/* Fixed payload size of a type, -1 for variable (program, log), -ENOMSG for unknown. */
static int fixed_size(uint8_t type) {
  switch (type) {
    case PROTO_GET_INFO:
    case PROTO_ABORT:
    case PROTO_GET_STATUS:
    case PROTO_GET_DIAG: return 0;
    case PROTO_PING: return PROTO_PING_SIZE;
    case PROTO_SET_CONFIG: return PROTO_CONFIG_SIZE;
    case PROTO_MOTOR_ENABLE: return PROTO_MOTOR_ENABLE_SIZE;
    case PROTO_MOVE: return PROTO_MOVE_SIZE;
    case PROTO_SET_LASERS: return PROTO_SET_LASERS_SIZE;
    case PROTO_TRIGGER: return PROTO_TRIGGER_SIZE;
    case PROTO_START: return PROTO_START_SIZE;
    case PROTO_ACK:
    case PROTO_NACK: return PROTO_ACK_SIZE;
    case PROTO_INFO: return PROTO_INFO_SIZE;
    case PROTO_PONG: return PROTO_PONG_SIZE;
    case PROTO_TRIGGER_EVENT: return PROTO_TRIGGER_EVENT_SIZE;
    case PROTO_MOVE_DONE: return PROTO_MOVE_DONE_SIZE;
    case PROTO_STATUS: return PROTO_STATUS_SIZE;
    case PROTO_DIAG: return PROTO_DIAG_SIZE;
    case PROTO_LOAD_PROGRAM:
    case PROTO_LOG: return -1;
    default: return -ENOMSG;
  }
}

int proto_payload_size(const proto_msg_t* msg) {
  if (msg == NULL) return -EINVAL;
  const int fixed = fixed_size(msg->type);
  if (fixed >= 0 || fixed == -ENOMSG) return fixed;
  if (msg->type == PROTO_LOAD_PROGRAM) {
    const uint8_t n = msg->body.program.shot_count;
    if (n < 1 || n > PROTO_MAX_SHOTS) return -EINVAL;
    return PROTO_PROGRAM_SIZE(n);
  }
  if (msg->body.log.length > PROTO_MAX_LOG_TEXT) return -EINVAL;
  return PROTO_LOG_FIXED_SIZE + msg->body.log.length;
}

/* ---- cursor ---- */

typedef struct {
  uint8_t* p;
  size_t at;
} writer_t;

static void w8(writer_t* w, uint8_t v) {
  w->p[w->at++] = v;
}
static void w16(writer_t* w, uint16_t v) {
  proto_put_u16(w->p + w->at, v);
  w->at += 2;
}
static void w32(writer_t* w, uint32_t v) {
  proto_put_u32(w->p + w->at, v);
  w->at += 4;
}
static void wi32(writer_t* w, int32_t v) {
  w32(w, (uint32_t)v);
}
static void w64(writer_t* w, uint64_t v) {
  proto_put_u64(w->p + w->at, v);
  w->at += 8;
}

typedef struct {
  const uint8_t* p;
  size_t at;
} reader_t;

static uint8_t r8(reader_t* r) {
  return r->p[r->at++];
}
static uint16_t r16(reader_t* r) {
  const uint16_t v = proto_get_u16(r->p + r->at);
  r->at += 2;
  return v;
}
static uint32_t r32(reader_t* r) {
  const uint32_t v = proto_get_u32(r->p + r->at);
  r->at += 4;
  return v;
}
static int32_t ri32(reader_t* r) {
  const uint32_t u = r32(r);
  /* Two's complement without implementation-defined conversion. */
  return u <= (uint32_t)INT32_MAX ? (int32_t)u : (int32_t)(u - 0x80000000u) + INT32_MIN;
}
static uint64_t r64(reader_t* r) {
  const uint64_t v = proto_get_u64(r->p + r->at);
  r->at += 8;
  return v;
}

/* ---- encode ---- */

static void write_payload(const proto_msg_t* m, writer_t* w) {
  switch (m->type) {
    case PROTO_PING: w64(w, m->body.ping.host_time_us); break;
    case PROTO_SET_CONFIG:
      w32(w, m->body.config.start_rate_hz);
      w32(w, m->body.config.max_rate_hz);
      w32(w, m->body.config.accel_hz_per_s);
      w32(w, m->body.config.trigger_pulse_us);
      w32(w, m->body.config.laser_timeout_ms);
      w8(w, m->body.config.flags);
      break;
    case PROTO_MOTOR_ENABLE: w8(w, m->body.motor_enable.enable); break;
    case PROTO_MOVE: wi32(w, m->body.move.steps); break;
    case PROTO_SET_LASERS: w8(w, m->body.set_lasers.mask); break;
    case PROTO_TRIGGER:
      w8(w, m->body.trigger.laser_mask);
      w32(w, m->body.trigger.laser_lead_us);
      w32(w, m->body.trigger.exposure_us);
      break;
    case PROTO_LOAD_PROGRAM: {
      const proto_program_t* p = &m->body.program;
      w32(w, p->step_count);
      wi32(w, p->steps_per_move);
      w32(w, p->settle_us);
      w32(w, p->laser_lead_us);
      w8(w, p->shot_count);
      for (uint8_t i = 0; i < p->shot_count; ++i) {
        w8(w, p->shots[i].laser_mask);
        w32(w, p->shots[i].exposure_us);
      }
      break;
    }
    case PROTO_START: w32(w, m->body.start.first_step); break;
    case PROTO_ACK:
    case PROTO_NACK:
      w16(w, m->body.ack.acked_seq);
      w8(w, m->body.ack.acked_type);
      w8(w, m->body.ack.status);
      w8(w, m->body.ack.detail);
      break;
    case PROTO_INFO: {
      const proto_info_t* i = &m->body.info;
      w8(w, i->proto_major);
      w8(w, i->proto_minor);
      w32(w, i->capabilities);
      w8(w, i->fw_major);
      w8(w, i->fw_minor);
      w8(w, i->fw_patch);
      w16(w, i->max_payload);
      w8(w, i->max_shots);
      for (int k = 0; k < PROTO_UID_SIZE; ++k) w8(w, i->uid[k]);
      break;
    }
    case PROTO_PONG:
      w64(w, m->body.pong.host_time_us);
      w64(w, m->body.pong.device_time_us);
      break;
    case PROTO_TRIGGER_EVENT: {
      const proto_trigger_event_t* t = &m->body.trigger_event;
      w32(w, t->trigger_seq);
      w64(w, t->time_us);
      w64(w, t->exposure_seen_us);
      wi32(w, t->position);
      w32(w, t->step_index);
      w8(w, t->laser_mask);
      w8(w, t->shot);
      w8(w, t->flags);
      break;
    }
    case PROTO_MOVE_DONE:
      w32(w, m->body.move_done.move_seq);
      w64(w, m->body.move_done.time_us);
      wi32(w, m->body.move_done.position);
      w8(w, m->body.move_done.status);
      break;
    case PROTO_STATUS: {
      const proto_status_t* s = &m->body.status;
      w32(w, s->status_seq);
      w64(w, s->time_us);
      w8(w, s->cause);
      w8(w, s->state);
      w8(w, s->flags);
      w8(w, s->lasers);
      wi32(w, s->position);
      w32(w, s->program_next_step);
      w32(w, s->program_steps);
      w32(w, s->trigger_count);
      w32(w, s->rx_errors);
      w32(w, s->events_dropped);
      break;
    }
    case PROTO_DIAG: {
      const proto_diag_t* d = &m->body.diag;
      w8(w, d->flags);
      w32(w, d->cpu_hz);
      w32(w, d->step_isr_cycles_max);
      w32(w, d->step_isr_cycles_last);
      w32(w, d->fault_count);
      w32(w, d->fault_vector);
      w32(w, d->fault_pc);
      w32(w, d->fault_lr);
      w32(w, d->fault_psr);
      w32(w, d->fault_cfsr);
      w32(w, d->fault_hfsr);
      break;
    }
    case PROTO_LOG:
      w32(w, m->body.log.log_seq);
      w8(w, m->body.log.level);
      w8(w, m->body.log.length);
      for (uint8_t k = 0; k < m->body.log.length; ++k) w8(w, (uint8_t)m->body.log.text[k]);
      break;
    default: break; /* GET_INFO, ABORT, GET_STATUS, GET_DIAG: empty */
  }
}

int proto_pack(const proto_msg_t* msg, uint8_t* out, size_t out_cap) {
  if (msg == NULL || out == NULL) return -EINVAL;
  const int payload = proto_payload_size(msg);
  if (payload < 0) return payload;
  const size_t total = PROTO_HEADER_SIZE + (size_t)payload + PROTO_CRC_SIZE;
  if (out_cap < total) return -ENOSPC;
  writer_t w = {out, 0};
  w8(&w, msg->version);
  w8(&w, msg->type);
  w16(&w, msg->seq);
  write_payload(msg, &w);
  if (w.at != PROTO_HEADER_SIZE + (size_t)payload) return -EINVAL; /* unreachable: sizes disagree */
  w32(&w, proto_crc32(0, out, w.at));
  return (int)w.at;
}

/* ---- decode ---- */

/* Reads the payload of `len` bytes (already checked against the type's size). */
static void read_payload(proto_msg_t* m, reader_t* r) {
  switch (m->type) {
    case PROTO_PING: m->body.ping.host_time_us = r64(r); break;
    case PROTO_SET_CONFIG:
      m->body.config.start_rate_hz = r32(r);
      m->body.config.max_rate_hz = r32(r);
      m->body.config.accel_hz_per_s = r32(r);
      m->body.config.trigger_pulse_us = r32(r);
      m->body.config.laser_timeout_ms = r32(r);
      m->body.config.flags = r8(r);
      break;
    case PROTO_MOTOR_ENABLE: m->body.motor_enable.enable = r8(r); break;
    case PROTO_MOVE: m->body.move.steps = ri32(r); break;
    case PROTO_SET_LASERS: m->body.set_lasers.mask = r8(r); break;
    case PROTO_TRIGGER:
      m->body.trigger.laser_mask = r8(r);
      m->body.trigger.laser_lead_us = r32(r);
      m->body.trigger.exposure_us = r32(r);
      break;
    case PROTO_LOAD_PROGRAM: {
      proto_program_t* p = &m->body.program;
      p->step_count = r32(r);
      p->steps_per_move = ri32(r);
      p->settle_us = r32(r);
      p->laser_lead_us = r32(r);
      p->shot_count = r8(r);
      for (uint8_t i = 0; i < p->shot_count; ++i) {
        p->shots[i].laser_mask = r8(r);
        p->shots[i].exposure_us = r32(r);
      }
      break;
    }
    case PROTO_START: m->body.start.first_step = r32(r); break;
    case PROTO_ACK:
    case PROTO_NACK:
      m->body.ack.acked_seq = r16(r);
      m->body.ack.acked_type = r8(r);
      m->body.ack.status = r8(r);
      m->body.ack.detail = r8(r);
      break;
    case PROTO_INFO: {
      proto_info_t* i = &m->body.info;
      i->proto_major = r8(r);
      i->proto_minor = r8(r);
      i->capabilities = r32(r);
      i->fw_major = r8(r);
      i->fw_minor = r8(r);
      i->fw_patch = r8(r);
      i->max_payload = r16(r);
      i->max_shots = r8(r);
      for (int k = 0; k < PROTO_UID_SIZE; ++k) i->uid[k] = r8(r);
      break;
    }
    case PROTO_PONG:
      m->body.pong.host_time_us = r64(r);
      m->body.pong.device_time_us = r64(r);
      break;
    case PROTO_TRIGGER_EVENT: {
      proto_trigger_event_t* t = &m->body.trigger_event;
      t->trigger_seq = r32(r);
      t->time_us = r64(r);
      t->exposure_seen_us = r64(r);
      t->position = ri32(r);
      t->step_index = r32(r);
      t->laser_mask = r8(r);
      t->shot = r8(r);
      t->flags = r8(r);
      break;
    }
    case PROTO_MOVE_DONE:
      m->body.move_done.move_seq = r32(r);
      m->body.move_done.time_us = r64(r);
      m->body.move_done.position = ri32(r);
      m->body.move_done.status = r8(r);
      break;
    case PROTO_STATUS: {
      proto_status_t* s = &m->body.status;
      s->status_seq = r32(r);
      s->time_us = r64(r);
      s->cause = r8(r);
      s->state = r8(r);
      s->flags = r8(r);
      s->lasers = r8(r);
      s->position = ri32(r);
      s->program_next_step = r32(r);
      s->program_steps = r32(r);
      s->trigger_count = r32(r);
      s->rx_errors = r32(r);
      s->events_dropped = r32(r);
      break;
    }
    case PROTO_DIAG: {
      proto_diag_t* d = &m->body.diag;
      d->flags = r8(r);
      d->cpu_hz = r32(r);
      d->step_isr_cycles_max = r32(r);
      d->step_isr_cycles_last = r32(r);
      d->fault_count = r32(r);
      d->fault_vector = r32(r);
      d->fault_pc = r32(r);
      d->fault_lr = r32(r);
      d->fault_psr = r32(r);
      d->fault_cfsr = r32(r);
      d->fault_hfsr = r32(r);
      break;
    }
    case PROTO_LOG:
      m->body.log.log_seq = r32(r);
      m->body.log.level = r8(r);
      m->body.log.length = r8(r);
      for (uint8_t k = 0; k < m->body.log.length; ++k) m->body.log.text[k] = (char)r8(r);
      m->body.log.text[m->body.log.length] = '\0';
      break;
    default: break;
  }
}

int proto_unpack(const uint8_t* raw, size_t len, proto_msg_t* msg) {
  if (msg == NULL || (raw == NULL && len > 0)) return -EINVAL;
  memset(msg, 0, sizeof(*msg));
  if (len < PROTO_HEADER_SIZE) return -EBADMSG;
  msg->version = raw[0];
  msg->type = raw[1];
  msg->seq = proto_get_u16(raw + 2);
  if (len < PROTO_HEADER_SIZE + PROTO_CRC_SIZE || len > PROTO_MAX_RAW_FRAME) return -EBADMSG;
  const size_t body_end = len - PROTO_CRC_SIZE;
  if (proto_crc32(0, raw, body_end) != proto_get_u32(raw + body_end)) return -EBADMSG;

  const uint8_t type = msg->type;
  const bool frozen = (type == PROTO_GET_INFO || type == PROTO_INFO);
  if (msg->version != PROTO_VERSION_MAJOR && !frozen) return -EPROTO;
  const size_t payload = body_end - PROTO_HEADER_SIZE;
  const uint8_t* p = raw + PROTO_HEADER_SIZE;
  int expected = fixed_size(type);
  if (expected == -ENOMSG) return -ENOMSG;
  if (type == PROTO_LOAD_PROGRAM) {
    if (payload < PROTO_PROGRAM_FIXED_SIZE) return -EMSGSIZE;
    const uint8_t shots = p[PROTO_PROGRAM_FIXED_SIZE - 1];
    if (shots < 1 || shots > PROTO_MAX_SHOTS) return -EMSGSIZE;
    expected = PROTO_PROGRAM_SIZE(shots);
  } else if (type == PROTO_LOG) {
    if (payload < PROTO_LOG_FIXED_SIZE) return -EMSGSIZE;
    const uint8_t text = p[PROTO_LOG_FIXED_SIZE - 1];
    if (text > PROTO_MAX_LOG_TEXT) return -EMSGSIZE;
    expected = PROTO_LOG_FIXED_SIZE + text;
  }
  /* Another major's GET_INFO/INFO may have grown at the end: read the frozen prefix. */
  const bool size_ok = frozen && msg->version != PROTO_VERSION_MAJOR ? payload >= (size_t)expected
                                                                     : payload == (size_t)expected;
  if (!size_ok) return -EMSGSIZE;
  reader_t r = {p, 0};
  read_payload(msg, &r);
  return 0;
}

/* ---- framing ---- */

int proto_encode_frame(const proto_msg_t* msg, uint8_t* out, size_t out_cap) {
  uint8_t raw[PROTO_MAX_RAW_FRAME];
  const int raw_len = proto_pack(msg, raw, sizeof(raw));
  if (raw_len < 0) return raw_len;
  if (out == NULL) return -EINVAL;
  if (out_cap < PROTO_COBS_MAX_ENCODED((size_t)raw_len) + 1) return -ENOSPC;
  const int n = proto_cobs_encode(raw, (size_t)raw_len, out, out_cap - 1);
  if (n < 0) return n;
  out[n] = 0x00;
  return n + 1;
}

int proto_decode_frame(const uint8_t* wire, size_t len, proto_msg_t* msg) {
  if (msg == NULL || (wire == NULL && len > 0)) return -EINVAL;
  memset(msg, 0, sizeof(*msg));
  if (len > 0 && wire[len - 1] == 0x00) --len;
  if (len > PROTO_COBS_MAX_ENCODED(PROTO_MAX_RAW_FRAME)) return -EBADMSG;
  uint8_t raw[PROTO_MAX_RAW_FRAME];
  const int n = proto_cobs_decode(wire, len, raw, sizeof(raw));
  if (n < 0) return n == -ENOSPC ? -EBADMSG : n;
  return proto_unpack(raw, (size_t)n, msg);
}

void proto_deframer_init(proto_deframer_t* d) {
  d->len = 0;
  d->overflow = false;
}

int proto_deframer_push(proto_deframer_t* d, uint8_t byte, size_t* frame_len) {
  if (byte != 0x00) {
    if (d->len < sizeof(d->buf)) {
      d->buf[d->len++] = byte;
    } else {
      d->overflow = true;
    }
    return 0;
  }
  const size_t n = d->len;
  const bool overflow = d->overflow;
  d->len = 0;
  d->overflow = false;
  if (overflow) return -EMSGSIZE;
  if (n == 0) return 0;
  if (frame_len != NULL) *frame_len = n;
  return 1;
}
