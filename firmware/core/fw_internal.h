/* Shared between the core's modules (not for ports). */
#ifndef ROTOSCAN_FIRMWARE_FW_INTERNAL_H_
#define ROTOSCAN_FIRMWARE_FW_INTERNAL_H_

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
/* Queues a STATUS frame. cause REPLY uses `reply_seq` as its header seq and is not an event. */
bool fw_send_status(uint8_t cause, uint16_t reply_seq);
/* Fills a STATUS payload (status_seq is assigned when it is sent). */
void fw_fill_status(proto_status_t* status, uint8_t cause);
/* Queues a LOG event. */
void fw_log(uint8_t level, const char* text);

/* Moves: the sequencer's program moves and MOVE commands share the stepper. */
enum fw_move_owner { FW_MOVE_NONE = 0, FW_MOVE_COMMAND, FW_MOVE_PROGRAM };
bool fw_start_move(int32_t steps, enum fw_move_owner owner);
enum fw_move_owner fw_move_owner(void);
/* Stops a running move (ABORT, safety); a command move reports MOVE_DONE with PROTO_MOVE_ABORTED. */
void fw_stop_move(void);

/* The last valid frame from the host restarts the laser safety timeout. */
void fw_host_seen(void);
bool fw_safety_tripped(void);
void fw_clear_safety(void);

uint32_t fw_rx_errors(void);
void fw_count_rx_error(void);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_FW_INTERNAL_H_ */
