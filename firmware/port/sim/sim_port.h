/*
 * sim_port.h -- the firmware built for the host: the real firmware core and protocol on a simulated board
 * with virtual time and a log of pin edges. Tests and the mocked-USB device drive it through this API.
 *
 * Model of the board:
 *  - Time is virtual, in microseconds since power-on (sim_now_us). Nothing happens between calls; time only
 *    moves in sim_advance_us, which runs every timer interrupt (step pulses, trigger and laser compares, the
 *    camera's exposure line) and the firmware's main loop at the exact virtual times they are due.
 *  - The 32-bit hardware timer (TIM2 on the board) reads (counter_at_boot + now) mod 2^32, so that a test
 *    can put its wrap a few milliseconds after power-on (sim_reset_with_counter).
 *  - USB: sim_usb_receive is the bulk OUT endpoint (bytes the host wrote), sim_usb_transmit the bulk IN
 *    endpoint (bytes the device queued). Frames may be split or merged arbitrarily on both sides. Receiving
 *    runs the main loop as needed to make room (as USB flow control would), but does not advance time.
 *  - The camera: a trigger rising edge makes the camera's exposure-active line (an input of the board) rise
 *    delay_us later and fall exposure_us after that, unless the camera is disconnected.
 *  - Every level change of an output pin (and of the exposure input) is logged with its time.
 *
 * Not thread-safe: call it from one thread at a time. No function here allocates memory.
 */
#ifndef ROTOSCAN_FIRMWARE_SIM_PORT_H_
#define ROTOSCAN_FIRMWARE_SIM_PORT_H_

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Power-on: fresh device state, time 0, empty USB buffers and edge log, default camera. */
void sim_reset(void);
/* Same, with the 32-bit hardware timer reading `counter_at_boot` at time 0 (to test its wrap). */
void sim_reset_with_counter(uint32_t counter_at_boot);

/* Bytes the host wrote to the bulk OUT endpoint. */
void sim_usb_receive(const uint8_t* data, size_t len);
/* Bytes sim_usb_receive could not hand to the device since the last reset (its receive queue was full and
 * the host had not read the answers waiting: a real endpoint would NAK them). */
size_t sim_usb_refused(void);
/* Copies up to `max` bytes the device queued for the bulk IN endpoint into `out`; returns the count. */
size_t sim_usb_transmit(uint8_t* out, size_t max);

/* Runs virtual time forward by `us` (timers, interrupts, the main loop), ending exactly at now + us. */
void sim_advance_us(uint64_t us);
/* Runs the main loop once at the current time. */
void sim_poll(void);
/* Virtual time since power-on. */
uint64_t sim_now_us(void);
/* The raw 32-bit hardware timer now. */
uint32_t sim_timer_counter(void);

/* The pins whose edges are logged. */
typedef enum {
  SIM_PIN_LASER_LEFT = 0,
  SIM_PIN_LASER_RIGHT = 1,
  SIM_PIN_TRIGGER = 2,      /* camera trigger output, active high */
  SIM_PIN_STEP = 3,         /* stepper driver STEP, a pulse per step (rising edge = the step) */
  SIM_PIN_DIR = 4,          /* stepper driver DIR, high = positive steps (unless inverted by config) */
  SIM_PIN_MOTOR_ENABLE = 5, /* stepper driver enable, active high */
  SIM_PIN_EXPOSURE = 6,     /* input: the camera's exposure-active line */
  SIM_PIN_COUNT = 7
} sim_pin_t;

typedef struct {
  uint64_t time_us; /* virtual time of the edge */
  uint8_t pin;      /* sim_pin_t */
  uint8_t level;    /* the new level, 0 or 1 */
} sim_edge_t;

/* The edge log since the last reset or clear, oldest first. It holds SIM_EDGE_CAPACITY edges; later edges
 * are counted in sim_edges_dropped() but not stored. */
#define SIM_EDGE_CAPACITY (1u << 20)
size_t sim_edge_count(void);
const sim_edge_t* sim_edges(void);
size_t sim_edges_dropped(void);
void sim_edges_clear(void);
/* Current level of a pin (0 or 1); -1 for a bad pin. */
int sim_pin_level(sim_pin_t pin);

/* The camera model (default: connected, delay 10 us, exposure 500 us). */
void sim_set_camera(bool connected, uint32_t delay_us, uint32_t exposure_us);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_SIM_PORT_H_ */
