/*
 * state.h -- the core's shared state and outgoing events (state_ layer, below everything that acts):
 * configuration, motor enable, the event stream (frame counter, LOG lines, drop count), receive errors, and
 * when the host was last heard. It calls only the link, the timebase and the port.
 *
 * The core's modules call each other one way only, each using only those listed before it:
 *     ring, timebase, link, stepper  <-  state  <-  motion  <-  sequencer  <-  status  <-  dispatch  <-  fw
 * (the test firmware.core_layers checks the includes). A lower module that has news for an upper one
 * returns it (motion_poll, seq_poll) instead of calling up.
 */
#ifndef ROTOSCAN_FIRMWARE_STATE_H_
#define ROTOSCAN_FIRMWARE_STATE_H_

#include <stdbool.h>
#include <stdint.h>

#include "rotoscan_protocol.h"
#include "stepper.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Default configuration after power-on (SET_CONFIG changes it). */
#define FW_DEFAULT_START_RATE_HZ 200u
#define FW_DEFAULT_MAX_RATE_HZ 2000u
#define FW_DEFAULT_ACCEL_HZ_PER_S 8000u
#define FW_DEFAULT_TRIGGER_PULSE_US 100u
#define FW_DEFAULT_LASER_TIMEOUT_MS 2000u

/* Power-on state: default configuration, motor disabled, counters zero, host seen now. */
void state_init(void);

const proto_config_t* fw_config(void);
step_profile_cfg_t fw_profile(void);
/* Replaces the configuration; the caller has validated it. */
void fw_set_config(const proto_config_t* config);

bool fw_motor_enabled(void);
void fw_set_motor_enabled(bool enabled);

/* Stamps an event with the device's frame counter and queues it; false (and counted as dropped) when the
 * transmit queue is full. */
bool fw_send_event(proto_msg_t* msg);
/* Room in the transmit queue for one more event of any type. */
bool fw_event_room(void);
uint32_t fw_events_dropped(void);
/* Queues a LOG event. */
void fw_log(uint8_t level, const char* text);

/* The last valid frame from the host restarts the laser safety timeout. */
void fw_host_seen(void);
uint64_t fw_host_seen_at(void);
bool fw_safety_tripped(void);
void fw_set_safety_tripped(bool tripped);

uint32_t fw_rx_errors(void);
void fw_count_rx_error(void);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_STATE_H_ */
