/*
 * Scan sequencer. States of a program, per table step i (origin + i * steps_per_move):
 *
 *   MOVING    the table moves to step i's position (skipped when it is already there)
 *   SETTLING  wait settle_us after the move
 *   ARMING    wait for room in the transmit queue for the TRIGGER_EVENT (back-pressure instead of loss),
 *             then choose the edge time T = now + SEQ_ARM_MARGIN_US + laser_lead_us and schedule two
 *             hardware compares: lasers to the shot's mask at T - laser_lead_us, trigger edge at T
 *   EXPOSING  wait until the trigger interrupt has reported the edge and T + exposure_us has passed, then
 *             send TRIGGER_EVENT; next shot (ARMING), or lasers off and the next step (MOVING), or done
 *
 * A single TRIGGER command runs ARMING and EXPOSING once, then puts the lasers back at the SET_LASERS mask.
 * All arithmetic and all protocol work happens here in the main loop; the interrupts only push
 * {kind, counter stamp, lasers, position} records into a queue.
 */
#include "sequencer.h"

#include "hal.h"
#include "motion.h"
#include "ring.h"
#include "state.h"
#include "timebase.h"

enum seq_state { SEQ_IDLE = 0, SEQ_MOVING, SEQ_SETTLING, SEQ_ARMING, SEQ_EXPOSING };
enum isr_kind { ISR_TRIGGER = 1, ISR_EXPOSURE_RISE = 2 };

typedef struct {
  uint8_t kind;
  uint8_t lasers;
  uint16_t reserved;
  uint32_t at;
  int32_t position;
} isr_record_t;

#define SEQ_ISR_QUEUE 16u

static struct {
  isr_record_t isr_storage[SEQ_ISR_QUEUE];
  ring_t isr_queue; /* isr -> main */

  proto_program_t program;
  bool loaded;
  int32_t origin;

  enum seq_state state;
  bool in_program;        /* false: a single TRIGGER */
  proto_trigger_t single; /* the single trigger's parameters */
  uint32_t step;          /* program step being taken (next_step while idle) */
  uint8_t shot;
  uint64_t deadline;  /* SETTLING / EXPOSING: device time to wait for */
  uint64_t edge_time; /* EXPOSING: the scheduled trigger edge */
  bool edge_seen;
  uint8_t edge_lasers;
  int32_t edge_position;
  bool exposure_seen;
  uint64_t exposure_time;

  uint8_t idle_lasers;
  uint32_t trigger_count;
  bool exposure_input;
  uint8_t status_due; /* a STATUS cause for the caller of seq_poll to send, or SEQ_NO_STATUS */
} g_seq;

void seq_init(void) {
  (void)ring_init(&g_seq.isr_queue, g_seq.isr_storage, SEQ_ISR_QUEUE, sizeof(isr_record_t));
  g_seq.loaded = false;
  g_seq.origin = 0;
  g_seq.state = SEQ_IDLE;
  g_seq.in_program = false;
  g_seq.step = 0;
  g_seq.shot = 0;
  g_seq.idle_lasers = 0;
  g_seq.trigger_count = 0;
  g_seq.exposure_input = hal_exposure_capture_enable() == 0;
  g_seq.status_due = SEQ_NO_STATUS;
}

/* ---- validation ---- */

#define MAX_WAIT_US 10000000u
#define MAX_LEAD_US 1000000u

static bool shot_ok(const proto_shot_t* shot) {
  return (shot->laser_mask & ~PROTO_LASER_ALL) == 0 && shot->exposure_us >= 1u &&
         shot->exposure_us <= MAX_WAIT_US;
}

uint8_t seq_load(const proto_program_t* p, uint8_t* field) {
  if (seq_busy()) return PROTO_ST_BUSY;
  *field = 0;
  if (p->step_count < 1u || p->step_count > PROTO_MAX_PROGRAM_STEPS)
    *field = 1;
  else if (p->steps_per_move < -PROTO_MAX_MOVE_STEPS || p->steps_per_move > PROTO_MAX_MOVE_STEPS)
    *field = 2;
  else if (p->settle_us > MAX_WAIT_US)
    *field = 3;
  else if (p->laser_lead_us < 1u || p->laser_lead_us > MAX_LEAD_US)
    *field = 4;
  else if (p->shot_count < 1u || p->shot_count > PROTO_MAX_SHOTS)
    *field = 5;
  for (uint8_t i = 0; *field == 0 && i < p->shot_count; ++i) {
    if (!shot_ok(&p->shots[i])) *field = (uint8_t)(6u + i);
  }
  /* The farthest table position must fit an int32 with room to spare. */
  if (*field == 0) {
    const int64_t span = (int64_t)p->steps_per_move * (int64_t)(p->step_count - 1u);
    const int64_t end = (int64_t)step_position() + span;
    if (end > INT32_MAX / 2 || end < INT32_MIN / 2) *field = 2;
  }
  if (*field != 0) return PROTO_ST_BAD_VALUE;
  g_seq.program = *p;
  g_seq.loaded = true;
  g_seq.origin = step_position();
  g_seq.step = 0;
  return PROTO_ST_OK;
}

uint8_t seq_start(uint32_t first_step, uint8_t* field) {
  *field = 0;
  if (!g_seq.loaded) return PROTO_ST_NO_PROGRAM;
  if (seq_busy() || fw_move_owner() != FW_MOVE_NONE) return PROTO_ST_BUSY;
  if (first_step >= g_seq.program.step_count) {
    *field = 1;
    return PROTO_ST_BAD_VALUE;
  }
  if (g_seq.program.steps_per_move != 0 && !fw_motor_enabled()) return PROTO_ST_MOTOR_DISABLED;
  g_seq.in_program = true;
  g_seq.step = first_step;
  g_seq.shot = 0;
  hal_lasers_set(0);
  g_seq.state = SEQ_MOVING;
  const int32_t target = g_seq.origin + g_seq.program.steps_per_move * (int32_t)first_step;
  const int32_t delta = target - step_position();
  if (delta == 0 || !fw_start_move(delta, FW_MOVE_PROGRAM)) seq_move_done();
  return PROTO_ST_OK;
}

uint8_t seq_trigger(const proto_trigger_t* t, uint8_t* field) {
  *field = 0;
  if (seq_busy()) return PROTO_ST_BUSY;
  if ((t->laser_mask & ~PROTO_LASER_ALL) != 0)
    *field = 1;
  else if (t->laser_lead_us < 1u || t->laser_lead_us > MAX_LEAD_US)
    *field = 2;
  else if (t->exposure_us < 1u || t->exposure_us > MAX_WAIT_US)
    *field = 3;
  if (*field != 0) return PROTO_ST_BAD_VALUE;
  g_seq.single = *t;
  g_seq.in_program = false;
  g_seq.shot = 0;
  g_seq.state = SEQ_ARMING;
  return PROTO_ST_OK;
}

bool seq_abort(void) {
  const bool was_busy = seq_busy();
  hal_trigger_cancel();
  hal_lasers_set(0);
  g_seq.idle_lasers = 0;
  g_seq.state = SEQ_IDLE;
  return was_busy;
}

void seq_set_idle_lasers(uint8_t mask) {
  g_seq.idle_lasers = mask;
  hal_lasers_set(mask);
}
uint8_t seq_idle_lasers(void) {
  return g_seq.idle_lasers;
}

bool seq_running(void) {
  return g_seq.state != SEQ_IDLE && g_seq.in_program;
}
bool seq_busy(void) {
  return g_seq.state != SEQ_IDLE;
}
bool seq_program_loaded(void) {
  return g_seq.loaded;
}
uint32_t seq_next_step(void) {
  return g_seq.step;
}
uint32_t seq_program_steps(void) {
  return g_seq.loaded ? g_seq.program.step_count : 0u;
}
uint32_t seq_trigger_count(void) {
  return g_seq.trigger_count;
}
bool seq_has_exposure_input(void) {
  return g_seq.exposure_input;
}
bool seq_lasers_in_use(void) {
  return g_seq.state == SEQ_ARMING || g_seq.state == SEQ_EXPOSING;
}

/* ---- interrupts ---- */

void seq_isr_trigger(uint32_t at) {
  isr_record_t r = {ISR_TRIGGER, hal_lasers_get(), 0, at, step_position()};
  (void)ring_push(&g_seq.isr_queue, &r); /* at most one trigger per shot: the queue cannot be full of them */
}

void seq_isr_exposure(uint32_t at, bool level) {
  if (!level) return;
  isr_record_t r = {ISR_EXPOSURE_RISE, 0, 0, at, 0};
  (void)ring_push(&g_seq.isr_queue, &r);
}

/* ---- state machine ---- */

static void current_shot(uint8_t* mask, uint32_t* lead, uint32_t* exposure) {
  if (g_seq.in_program) {
    *mask = g_seq.program.shots[g_seq.shot].laser_mask;
    *lead = g_seq.program.laser_lead_us;
    *exposure = g_seq.program.shots[g_seq.shot].exposure_us;
  } else {
    *mask = g_seq.single.laser_mask;
    *lead = g_seq.single.laser_lead_us;
    *exposure = g_seq.single.exposure_us;
  }
}

static void drain_isr_queue(void) {
  isr_record_t r;
  while (ring_pop(&g_seq.isr_queue, &r)) {
    if (g_seq.state != SEQ_EXPOSING) continue; /* stale: from an aborted shot */
    const uint64_t t = tb_extend(r.at);
    if (r.kind == ISR_TRIGGER && !g_seq.edge_seen && t == g_seq.edge_time) {
      g_seq.edge_seen = true;
      g_seq.edge_lasers = r.lasers;
      g_seq.edge_position = r.position;
    } else if (r.kind == ISR_EXPOSURE_RISE && !g_seq.exposure_seen && t >= g_seq.edge_time &&
               t <= g_seq.deadline) {
      g_seq.exposure_seen = true;
      g_seq.exposure_time = t;
    }
  }
}

static void arm_shot(uint64_t now) {
  uint8_t mask;
  uint32_t lead;
  uint32_t exposure;
  current_shot(&mask, &lead, &exposure);
  g_seq.edge_time = now + SEQ_ARM_MARGIN_US + lead;
  g_seq.deadline = g_seq.edge_time + exposure;
  g_seq.edge_seen = false;
  g_seq.exposure_seen = false;
  g_seq.exposure_time = 0;
  if (hal_lasers_schedule(mask, tb_to_counter(g_seq.edge_time - lead)) == -ENOSYS) hal_lasers_set(mask);
  hal_trigger_schedule(tb_to_counter(g_seq.edge_time), fw_config()->trigger_pulse_us);
  g_seq.state = SEQ_EXPOSING;
}

static void finish_program(void) {
  g_seq.state = SEQ_IDLE;
  hal_lasers_set(0);
  g_seq.status_due = PROTO_CAUSE_PROGRAM_DONE;
}

static void send_trigger_event(void) {
  proto_msg_t msg;
  proto_msg_init(&msg, PROTO_TRIGGER_EVENT, 0);
  proto_trigger_event_t* e = &msg.body.trigger_event;
  e->trigger_seq = g_seq.trigger_count++;
  e->time_us = g_seq.edge_time;
  e->exposure_seen_us = g_seq.exposure_seen ? g_seq.exposure_time : 0u;
  e->position = g_seq.edge_position;
  e->step_index = g_seq.in_program ? g_seq.step : 0xFFFFFFFFu;
  e->laser_mask = g_seq.edge_lasers;
  e->shot = g_seq.in_program ? g_seq.shot : 0u;
  e->flags = (uint8_t)((g_seq.in_program ? PROTO_TRIG_IN_PROGRAM : 0u) |
                       (g_seq.exposure_seen ? PROTO_TRIG_EXPOSURE_SEEN : 0u));
  (void)fw_send_event(&msg); /* room was reserved in ARMING */
}

static void after_exposure(void) {
  send_trigger_event();
  if (!g_seq.in_program) {
    hal_lasers_set(g_seq.idle_lasers);
    g_seq.state = SEQ_IDLE;
    return;
  }
  if (++g_seq.shot < g_seq.program.shot_count) {
    g_seq.state = SEQ_ARMING;
    return;
  }
  hal_lasers_set(0);
  g_seq.shot = 0;
  if (++g_seq.step >= g_seq.program.step_count) {
    finish_program();
    return;
  }
  g_seq.state = SEQ_MOVING;
  if (g_seq.program.steps_per_move == 0 || !fw_start_move(g_seq.program.steps_per_move, FW_MOVE_PROGRAM)) {
    seq_move_done();
  }
}

void seq_move_done(void) {
  if (g_seq.state != SEQ_MOVING) return;
  g_seq.deadline = tb_now() + g_seq.program.settle_us;
  g_seq.state = SEQ_SETTLING;
}

uint8_t seq_poll(void) {
  g_seq.status_due = SEQ_NO_STATUS;
  drain_isr_queue();
  const uint64_t now = tb_now();
  switch (g_seq.state) {
    case SEQ_SETTLING:
      if (now < g_seq.deadline) break;
      g_seq.state = SEQ_ARMING;
      if (fw_event_room()) arm_shot(now);
      break;
    case SEQ_ARMING:
      if (fw_event_room()) arm_shot(now);
      break;
    case SEQ_EXPOSING:
      if (now < g_seq.deadline) break;
      if (g_seq.edge_seen) {
        after_exposure();
      } else if (now >= g_seq.deadline + SEQ_TRIGGER_LOST_US) {
        fw_log(PROTO_LOG_ERROR, "trigger edge lost; program stopped");
        (void)seq_abort();
        g_seq.status_due = PROTO_CAUSE_ABORTED;
      }
      break;
    default: break;
  }
  return g_seq.status_due;
}

uint64_t seq_next_wakeup(void) {
  switch (g_seq.state) {
    case SEQ_SETTLING: return g_seq.deadline;
    case SEQ_EXPOSING: return g_seq.edge_seen ? g_seq.deadline : g_seq.deadline + SEQ_TRIGGER_LOST_US;
    case SEQ_ARMING: return tb_now() + SEQ_ARM_MARGIN_US; /* waiting for transmit room: poll */
    default: return UINT64_MAX;
  }
}
