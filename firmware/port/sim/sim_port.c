/*
 * The simulated board: implements hal.h on virtual time and drives the firmware core (fw.h) the way the
 * STM32F411's interrupts and main loop would.
 *
 * Event loop. Hardware events pending at any moment: the step timer, the laser compare, the trigger compare
 * (rising, then falling edge), the end of a STEP pulse, and the camera's exposure line (rising, falling).
 * sim_advance_us repeatedly takes the earliest of them and the core's next wakeup (fw_next_wakeup_us), sets
 * the virtual time to it, runs the interrupts due then (in a fixed order: lasers, trigger, step, camera),
 * and runs the main loop once. So every interrupt happens at its exact tick and the main loop sees it at
 * once; what the main loop schedules is never late. Compares are given as 32-bit counter values, as on the
 * chip; one set in the past fires only after the counter wraps, as on the chip.
 */
#include "sim_port.h"

#include <string.h>

#include "fw.h"
#include "hal.h"
#include "rotoscan_protocol.h"

#define SIM_STEP_PULSE_US 2u
#define NEVER UINT64_MAX

static sim_edge_t g_edges[SIM_EDGE_CAPACITY];

static struct {
  uint64_t now;
  uint32_t counter_at_boot;
  size_t edge_count;
  size_t edges_dropped;
  uint8_t pins[SIM_PIN_COUNT];

  uint64_t step_at; /* next step interrupt */
  uint64_t step_fall_at;
  uint64_t laser_at;
  uint8_t laser_mask;
  uint64_t trigger_at;
  uint32_t trigger_counter; /* the compare value, reported to fw_isr_trigger */
  uint32_t trigger_pulse_us;
  uint64_t trigger_fall_at;
  uint64_t exposure_rise_at;
  uint64_t exposure_fall_at;
  bool exposure_capture;

  size_t usb_refused;
  bool camera_connected;
  uint32_t camera_delay_us;
  uint32_t camera_exposure_us;
} g_sim;

/* ---- pins and time ---- */

static uint32_t counter_now(void) {
  return (uint32_t)(g_sim.counter_at_boot + (uint32_t)g_sim.now);
}

/* Virtual time at which the counter next reads `at` (now if it reads it now). */
static uint64_t time_of_counter(uint32_t at) {
  return g_sim.now + (uint32_t)(at - counter_now());
}

static void set_pin(sim_pin_t pin, uint8_t level) {
  if (g_sim.pins[pin] == level) return;
  g_sim.pins[pin] = level;
  if (g_sim.edge_count < SIM_EDGE_CAPACITY) {
    g_edges[g_sim.edge_count].time_us = g_sim.now;
    g_edges[g_sim.edge_count].pin = (uint8_t)pin;
    g_edges[g_sim.edge_count].level = level;
    ++g_sim.edge_count;
  } else {
    ++g_sim.edges_dropped;
  }
}

/* ---- hal.h ---- */

uint32_t hal_timer_now(void) {
  return counter_now();
}

void hal_lasers_set(uint8_t mask) {
  g_sim.laser_at = NEVER;
  set_pin(SIM_PIN_LASER_LEFT, (mask & PROTO_LASER_LEFT) ? 1u : 0u);
  set_pin(SIM_PIN_LASER_RIGHT, (mask & PROTO_LASER_RIGHT) ? 1u : 0u);
}

uint8_t hal_lasers_get(void) {
  return (uint8_t)((g_sim.pins[SIM_PIN_LASER_LEFT] ? PROTO_LASER_LEFT : 0u) |
                   (g_sim.pins[SIM_PIN_LASER_RIGHT] ? PROTO_LASER_RIGHT : 0u));
}

int hal_lasers_schedule(uint8_t mask, uint32_t at) {
  g_sim.laser_at = time_of_counter(at);
  g_sim.laser_mask = mask;
  return 0;
}

void hal_trigger_schedule(uint32_t at, uint32_t pulse_us) {
  g_sim.trigger_at = time_of_counter(at);
  g_sim.trigger_counter = at;
  g_sim.trigger_pulse_us = pulse_us;
}

void hal_trigger_cancel(void) {
  g_sim.trigger_at = NEVER;
  g_sim.trigger_fall_at = NEVER;
  set_pin(SIM_PIN_TRIGGER, 0);
}

int hal_exposure_capture_enable(void) {
  g_sim.exposure_capture = true;
  return 0;
}

void hal_motor_enable(bool enable) {
  set_pin(SIM_PIN_MOTOR_ENABLE, enable ? 1u : 0u);
}
void hal_step_dir(bool high) {
  set_pin(SIM_PIN_DIR, high ? 1u : 0u);
}
void hal_step_timer_start(uint32_t delay_us) {
  g_sim.step_at = g_sim.now + delay_us;
}
void hal_step_timer_stop(void) {
  g_sim.step_at = NEVER;
}

void hal_step_pulse(void) {
  set_pin(SIM_PIN_STEP, 1);
  g_sim.step_fall_at = g_sim.now + SIM_STEP_PULSE_US;
}

int hal_usb_tx_kick(void) {
  return -ENOSYS;
}

int hal_uid(uint8_t out[12]) {
  static const uint8_t kUid[12] = {'R', 'O', 'T', 'O', 'S', 'C', 'A', 'N', 'S', 'I', 'M', '1'};
  memcpy(out, kUid, sizeof(kUid));
  return 0;
}

bool hal_is_simulated(void) {
  return true;
}

int hal_diag(hal_diag_t* out) {
  /* The simulation counts no CPU cycles and cannot fault: GET_DIAG says so (both flags clear). */
  memset(out, 0, sizeof(*out));
  return 0;
}

/* ---- the event loop ---- */

static uint64_t min_u64(uint64_t a, uint64_t b) {
  return a < b ? a : b;
}

static uint64_t next_hardware_event(void) {
  uint64_t t = g_sim.step_at;
  t = min_u64(t, g_sim.step_fall_at);
  t = min_u64(t, g_sim.laser_at);
  t = min_u64(t, g_sim.trigger_at);
  t = min_u64(t, g_sim.trigger_fall_at);
  t = min_u64(t, g_sim.exposure_rise_at);
  t = min_u64(t, g_sim.exposure_fall_at);
  return t;
}

/* Runs every interrupt due at the current time. */
static void run_due_interrupts(void) {
  const uint64_t now = g_sim.now;
  if (g_sim.step_fall_at <= now) {
    g_sim.step_fall_at = NEVER;
    set_pin(SIM_PIN_STEP, 0);
  }
  if (g_sim.laser_at <= now) {
    const uint8_t mask = g_sim.laser_mask;
    g_sim.laser_at = NEVER;
    set_pin(SIM_PIN_LASER_LEFT, (mask & PROTO_LASER_LEFT) ? 1u : 0u);
    set_pin(SIM_PIN_LASER_RIGHT, (mask & PROTO_LASER_RIGHT) ? 1u : 0u);
  }
  if (g_sim.trigger_fall_at <= now) {
    g_sim.trigger_fall_at = NEVER;
    set_pin(SIM_PIN_TRIGGER, 0);
  }
  if (g_sim.trigger_at <= now) {
    g_sim.trigger_at = NEVER;
    set_pin(SIM_PIN_TRIGGER, 1);
    g_sim.trigger_fall_at = now + g_sim.trigger_pulse_us;
    const bool camera_idle = g_sim.exposure_rise_at == NEVER && g_sim.pins[SIM_PIN_EXPOSURE] == 0;
    if (g_sim.camera_connected && camera_idle) {
      g_sim.exposure_rise_at = now + g_sim.camera_delay_us;
    }
    fw_isr_trigger(g_sim.trigger_counter);
  }
  if (g_sim.step_at <= now) {
    const uint64_t scheduled = g_sim.step_at;
    g_sim.step_at = NEVER;
    const uint32_t next = fw_isr_step();
    /* Auto-reload: the next interrupt counts from this one's scheduled time, not from its latency. */
    if (next != 0 && g_sim.step_at == NEVER) g_sim.step_at = scheduled + next;
  }
  if (g_sim.exposure_rise_at <= now) {
    g_sim.exposure_rise_at = NEVER;
    set_pin(SIM_PIN_EXPOSURE, 1);
    g_sim.exposure_fall_at = now + g_sim.camera_exposure_us;
    if (g_sim.exposure_capture) fw_isr_exposure(counter_now(), true);
  }
  if (g_sim.exposure_fall_at <= now) {
    g_sim.exposure_fall_at = NEVER;
    set_pin(SIM_PIN_EXPOSURE, 0);
    if (g_sim.exposure_capture) fw_isr_exposure(counter_now(), false);
  }
}

void sim_poll(void) {
  fw_poll();
}

void sim_advance_us(uint64_t us) {
  const uint64_t target = g_sim.now + us;
  fw_poll();
  for (;;) {
    /* Device time and virtual time are the same clock: fw_init ran at virtual time 0. */
    const uint64_t wake = fw_next_wakeup_us();
    const uint64_t next = min_u64(next_hardware_event(), wake > g_sim.now ? wake : g_sim.now + 1u);
    if (next > target) break;
    g_sim.now = next;
    run_due_interrupts();
    fw_poll();
  }
  g_sim.now = target;
  run_due_interrupts();
  fw_poll();
}

uint64_t sim_now_us(void) {
  return g_sim.now;
}
uint32_t sim_timer_counter(void) {
  return counter_now();
}

/* ---- reset, USB, log ---- */

void sim_reset_with_counter(uint32_t counter_at_boot) {
  memset(&g_sim, 0, sizeof(g_sim));
  g_sim.counter_at_boot = counter_at_boot;
  g_sim.step_at = NEVER;
  g_sim.step_fall_at = NEVER;
  g_sim.laser_at = NEVER;
  g_sim.trigger_at = NEVER;
  g_sim.trigger_fall_at = NEVER;
  g_sim.exposure_rise_at = NEVER;
  g_sim.exposure_fall_at = NEVER;
  g_sim.camera_connected = true;
  g_sim.camera_delay_us = 10;
  g_sim.camera_exposure_us = 500;
  fw_init();
  g_sim.edge_count = 0; /* power-on levels are not edges */
  g_sim.edges_dropped = 0;
}

void sim_reset(void) {
  sim_reset_with_counter(0);
}

void sim_usb_receive(const uint8_t* data, size_t len) {
  if (data == NULL) return;
  size_t done = 0;
  while (done < len) {
    size_t n = fw_usb_rx(data + done, len - done);
    if (n == 0) {
      fw_poll(); /* the endpoint NAKs until the main loop has made room */
      n = fw_usb_rx(data + done, len - done);
      if (n == 0) { /* the device cannot take more until the host reads: the rest is refused */
        g_sim.usb_refused += len - done;
        return;
      }
    }
    done += n;
  }
  fw_poll();
}

size_t sim_usb_transmit(uint8_t* out, size_t max) {
  if (out == NULL) return 0;
  const size_t n = fw_usb_tx(out, max);
  if (n > 0) fw_poll(); /* room freed: the main loop may answer waiting commands */
  return n;
}

size_t sim_usb_refused(void) {
  return g_sim.usb_refused;
}

size_t sim_edge_count(void) {
  return g_sim.edge_count;
}
const sim_edge_t* sim_edges(void) {
  return g_edges;
}
size_t sim_edges_dropped(void) {
  return g_sim.edges_dropped;
}
void sim_edges_clear(void) {
  g_sim.edge_count = 0;
  g_sim.edges_dropped = 0;
}

int sim_pin_level(sim_pin_t pin) {
  if ((int)pin < 0 || pin >= SIM_PIN_COUNT) return -1;
  return g_sim.pins[pin];
}

void sim_set_camera(bool connected, uint32_t delay_us, uint32_t exposure_us) {
  g_sim.camera_connected = connected;
  g_sim.camera_delay_us = delay_us;
  g_sim.camera_exposure_us = exposure_us;
}
