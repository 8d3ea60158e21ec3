/*
 * motion.h -- who owns the stepper (motion_ layer, above state): the sequencer's program moves and MOVE
 * commands share it. A command move reports MOVE_DONE itself; the end of a program move is returned by
 * motion_poll for the caller (fw.c) to hand to the sequencer, which sits above this layer (see state.h).
 */
#ifndef ROTOSCAN_FIRMWARE_MOTION_H_
#define ROTOSCAN_FIRMWARE_MOTION_H_

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

enum fw_move_owner { FW_MOVE_NONE = 0, FW_MOVE_COMMAND, FW_MOVE_PROGRAM };

void motion_init(void);
bool fw_start_move(int32_t steps, enum fw_move_owner owner);
enum fw_move_owner fw_move_owner(void);
/* Stops a running move (ABORT, safety); a command move reports MOVE_DONE with PROTO_MOVE_ABORTED. */
void fw_stop_move(void);
/* Keeps the stepper fed and sends a pending MOVE_DONE; returns the owner of a move that ended since the last
 * call (FW_MOVE_NONE if none). Context: main. */
enum fw_move_owner motion_poll(void);
/* A MOVE_DONE waits for transmit room. */
bool motion_report_pending(void);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_MOTION_H_ */
