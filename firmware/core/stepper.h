/*
 * Stepper motion (step_): a trapezoidal speed profile, computed in the main loop a few steps ahead into a
 * queue of intervals, and the step interrupt that only pops them. See stepper.c for the profile and the
 * interrupt's time budget.
 */
#ifndef ROTOSCAN_FIRMWARE_STEPPER_H_
#define ROTOSCAN_FIRMWARE_STEPPER_H_

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Intervals computed ahead of the interrupt. At 100 kHz (the fastest rate allowed) 64 intervals are 640 us
 * of main-loop slack. */
#define STEP_QUEUE_LEN 64u
/* When the queue runs dry mid-move the interrupt waits this long and tries again (counted as an underrun). */
#define STEP_UNDERRUN_RETRY_US 50u

typedef struct {
  uint32_t start_rate_hz;  /* speed at the first and the last step */
  uint32_t max_rate_hz;    /* cruise speed ceiling */
  uint32_t accel_hz_per_s; /* acceleration and deceleration */
} step_profile_cfg_t;

/*
 * A move of `steps` steps as a sequence of intervals d_0 .. d_{steps-1}: the i-th STEP edge comes
 * d_0 + ... + d_{i-1} after the first, and the move ends d_{steps-1} after the last edge.
 */
typedef struct {
  uint32_t steps;  /* N */
  uint32_t ramp;   /* m: steps of acceleration (and of deceleration), <= N / 2 */
  float v0_sq;     /* start_rate^2 */
  float two_a;     /* 2 * accel */
  float cruise_us; /* exact interval at cruise: 1e6 / v(m) */
  uint32_t next;   /* index of the next interval to produce */
  float carry_us;  /* rounding error carried to the next interval, in [-0.5, 0.5] */
} step_plan_t;

/* Plans a move. Context: main (floating point, a square root). */
void step_plan_init(step_plan_t* plan, const step_profile_cfg_t* cfg, uint32_t steps);
/* The exact (unrounded) interval i of the plan, in microseconds. */
float step_plan_exact_us(const step_plan_t* plan, uint32_t i);
/* The next interval, rounded to whole microseconds with the error carried forward so that the edge times
 * stay within 0.5 us of the exact profile; false when all have been produced. */
bool step_plan_next(step_plan_t* plan, uint32_t* interval_us);

/* ---- the stepper driver ---- */

/* Resets position to 0 and stops everything. Context: main. */
void step_init(void);
/* Starts a relative move (|steps| >= 1) with the profile; false if a move is running. Context: main. */
bool step_start_move(int32_t steps, const step_profile_cfg_t* cfg, bool invert_dir);
/* Keeps the interval queue full; returns true when a move finished since the last call. Context: main. */
bool step_poll(void);
/* True from step_start_move until step_poll reports the end (or step_abort). */
bool step_is_moving(void);
/* Stops at once; the position counts the steps actually made. Context: main. */
void step_abort(void);
/* Motor position in steps (the steps made since step_init, signed). Context: any. */
int32_t step_position(void);
/* Times the queue ran dry in the middle of a move since step_init. */
uint32_t step_underruns(void);

/* The step interrupt (called through fw_isr_step): makes one STEP pulse and returns the delay to the next
 * interrupt, or 0 when the move is over. Context: isr. */
uint32_t step_isr(void);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_STEPPER_H_ */
