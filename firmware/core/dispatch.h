/*
 * The command dispatcher (disp_): decodes each frame from the host, answers every command exactly once
 * (ACK, NACK with a status code, or its data reply), and recognises retransmissions: a frame identical to one
 * of the last DISP_DUP_WINDOW commands (same seq, type and CRC) is not executed again, its cached answer is
 * sent again. Malformed frames (bad COBS, bad CRC, too long) and unknown or wrong-length commands get a
 * NACK, never a crash.
 */
#ifndef ROTOSCAN_FIRMWARE_DISPATCH_H_
#define ROTOSCAN_FIRMWARE_DISPATCH_H_

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define DISP_DUP_WINDOW 4u

void disp_init(void);
/* Handles the complete frames queued, as long as the transmit queue has room for an answer. Context: main. */
void disp_poll(void);
/* Retransmissions recognised (and answered from the cache) since power-on. */
uint32_t disp_duplicates(void);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_DISPATCH_H_ */
