/*
 * status.h -- STATUS frames (status_ layer, above the sequencer): the snapshot of the device that GET_STATUS
 * answers with and that BOOT, SAFETY, ABORTED and PROGRAM_DONE events carry.
 */
#ifndef ROTOSCAN_FIRMWARE_STATUS_H_
#define ROTOSCAN_FIRMWARE_STATUS_H_

#include <stdbool.h>
#include <stdint.h>

#include "rotoscan_protocol.h"

#ifdef __cplusplus
extern "C" {
#endif

void status_init(void);
/* Fills a STATUS payload (status_seq is assigned when it is sent). */
void fw_fill_status(proto_status_t* status, uint8_t cause);
/* Queues a STATUS frame. cause REPLY uses `reply_seq` as its header seq and is not an event. */
bool fw_send_status(uint8_t cause, uint16_t reply_seq);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_STATUS_H_ */
