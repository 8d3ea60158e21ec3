/*
 * Stepper motion: trapezoidal profile precomputed in the main loop, popped by a dumb step interrupt.
 *
 * Profile. With start speed v0 (steps/s), acceleration a (steps/s^2) and ceiling vmax, the speed after k
 * steps of constant acceleration is v(k) = sqrt(v0^2 + 2 a k). The time to go from step k to step k+1 is
 *     t(k+1) - t(k) = (v(k+1) - v(k)) / a = 2 / (v(k) + v(k+1)),
 * the second form being free of the cancellation the first one suffers at high k (and exact, not the usual
 * 1/v approximation). The ramp length is m = min(floor((vmax^2 - v0^2) / (2a)), N / 2) steps; intervals
 * 0..m-1 accelerate, intervals N-m..N-1 mirror them (decelerate), and those between cruise at 1 / v(m)
 * (<= vmax, and = v0 when v0 = vmax). Intervals are rounded to the 1 us timer tick with the rounding error
 * carried into the next interval, so every edge stays within 0.5 us of the exact profile over any move.
 *
 * Interrupt budget (STM32F411 at 96 MHz; DESIGN.md allows 5 us = 480 cycles per step interrupt): the ISR
 * pops one 32-bit interval from a single-producer single-consumer queue (a load, a compare, a copy, a store),
 * pulses STEP through hal_step_pulse (one BSRR write; the timer's one-pulse mode or the next interrupt ends
 * it), updates the position (one add) and returns the interval for the timer's auto-reload: about 40
 * instructions, no division, no floating point, no loop. All arithmetic (two sqrtf and a division per step,
 * about 60 cycles on the M4F's FPU) runs in the main loop, which keeps up to STEP_QUEUE_LEN intervals ahead.
 * At the 100 kHz ceiling the interrupt takes well under 10 % of the CPU.
 */
#include "stepper.h"

#include <math.h>

#include "hal.h"
#include "ring.h"

/* ---- profile ---- */

static float speed_at(const step_plan_t* p, uint32_t k) {
  return sqrtf(p->v0_sq + p->two_a * (float)k);
}

void step_plan_init(step_plan_t* plan, const step_profile_cfg_t* cfg, uint32_t steps) {
  const float v0 = (float)cfg->start_rate_hz;
  const float vmax = (float)(cfg->max_rate_hz > cfg->start_rate_hz ? cfg->max_rate_hz : cfg->start_rate_hz);
  const float a = (float)cfg->accel_hz_per_s;
  plan->steps = steps;
  plan->v0_sq = v0 * v0;
  plan->two_a = 2.0f * a;
  const float ramp_full = (vmax * vmax - v0 * v0) / (2.0f * a);
  const uint32_t ramp = ramp_full >= (float)(steps / 2u) ? steps / 2u : (uint32_t)ramp_full;
  plan->ramp = ramp;
  plan->cruise_us = 1e6f / speed_at(plan, ramp);
  plan->next = 0;
  plan->carry_us = 0.0f;
}

float step_plan_exact_us(const step_plan_t* plan, uint32_t i) {
  uint32_t k;
  if (i < plan->ramp) {
    k = i;
  } else if (i >= plan->steps - plan->ramp) {
    k = plan->steps - 1u - i; /* deceleration mirrors acceleration */
  } else {
    return plan->cruise_us;
  }
  return 2e6f / (speed_at(plan, k) + speed_at(plan, k + 1u));
}

bool step_plan_next(step_plan_t* plan, uint32_t* interval_us) {
  if (plan->next >= plan->steps) return false;
  const float want = step_plan_exact_us(plan, plan->next) + plan->carry_us;
  uint32_t whole = (uint32_t)(want + 0.5f);
  if (whole < 1u) whole = 1u;
  plan->carry_us = want - (float)whole;
  *interval_us = whole;
  ++plan->next;
  return true;
}

/* ---- driver ---- */

static struct {
  uint32_t queue_storage[STEP_QUEUE_LEN];
  ring_t queue; /* main -> isr: intervals */
  step_plan_t plan;
  bool moving;                 /* main's view */
  volatile bool all_queued;    /* main -> isr: the plan's last interval is in the queue */
  volatile bool done;          /* isr -> main: the move ended */
  volatile int32_t position;   /* isr: steps made */
  volatile int32_t direction;  /* +1 or -1 for the running move */
  volatile uint32_t underruns; /* isr */
} g_step;

void step_init(void) {
  hal_step_timer_stop();
  (void)ring_init(&g_step.queue, g_step.queue_storage, STEP_QUEUE_LEN, sizeof(uint32_t));
  g_step.moving = false;
  g_step.all_queued = false;
  g_step.done = false;
  g_step.position = 0;
  g_step.direction = 1;
  g_step.underruns = 0;
}

static void fill_queue(void) {
  uint32_t interval;
  while (!g_step.all_queued && ring_space(&g_step.queue) > 0) {
    if (!step_plan_next(&g_step.plan, &interval)) {
      g_step.all_queued = true;
      break;
    }
    (void)ring_push(&g_step.queue, &interval);
    if (g_step.plan.next >= g_step.plan.steps) g_step.all_queued = true;
  }
}

bool step_start_move(int32_t steps, const step_profile_cfg_t* cfg, bool invert_dir) {
  if (g_step.moving || steps == 0) return false;
  const bool forward = steps > 0;
  const uint32_t count = forward ? (uint32_t)steps : (uint32_t)(-(int64_t)steps);
  ring_clear(&g_step.queue);
  step_plan_init(&g_step.plan, cfg, count);
  g_step.all_queued = false;
  g_step.done = false;
  g_step.direction = forward ? 1 : -1;
  g_step.moving = true;
  fill_queue();
  hal_step_dir(forward != invert_dir);
  hal_step_timer_start(HAL_DIR_SETUP_US); /* the first edge once DIR has settled */
  return true;
}

bool step_poll(void) {
  if (!g_step.moving) return false;
  if (g_step.done) {
    g_step.moving = false;
    return true;
  }
  fill_queue();
  return false;
}

bool step_is_moving(void) {
  return g_step.moving;
}

void step_abort(void) {
  hal_step_timer_stop();
  ring_clear(&g_step.queue);
  g_step.moving = false;
  g_step.all_queued = false;
  g_step.done = false;
}

int32_t step_position(void) {
  return g_step.position;
}
uint32_t step_underruns(void) {
  return g_step.underruns;
}

uint32_t step_isr(void) {
  uint32_t interval;
  if (!ring_pop(&g_step.queue, &interval)) {
    if (g_step.all_queued) {
      g_step.done = true;
      return 0; /* the last interval has run out: the move is over */
    }
    g_step.underruns = g_step.underruns + 1u;
    return STEP_UNDERRUN_RETRY_US;
  }
  hal_step_pulse();
  g_step.position = g_step.position + g_step.direction;
  return interval;
}
