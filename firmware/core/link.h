/*
 * The link layer (usb_): byte queues between the USB (or UART) interrupt and the main loop, COBS deframing
 * of incoming bytes and whole-frame queuing of outgoing ones. A frame is queued for transmission whole or
 * not at all, so the host never sees half a frame from the device.
 */
#ifndef ROTOSCAN_FIRMWARE_LINK_H_
#define ROTOSCAN_FIRMWARE_LINK_H_

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "rotoscan_protocol.h"

#ifdef __cplusplus
extern "C" {
#endif

#define USB_RX_QUEUE 512u  /* bytes; a power of two */
#define USB_TX_QUEUE 2048u /* bytes; a power of two: about 45 TRIGGER_EVENTs */

void usb_init(void);
size_t usb_rx_isr(const uint8_t* data, size_t len);
size_t usb_tx_take(uint8_t* out, size_t max);
size_t usb_tx_pending(void);

/* Main loop: the next complete stuffed frame (without its 0x00) in *frame and *len, valid until the next
 * call. Returns 1 for a frame, 0 when no complete frame is queued, -EMSGSIZE for a frame too long for any
 * message (dropped). Context: main. */
int usb_next_frame(const uint8_t** frame, size_t* len);
/* Whether `bytes` more bytes fit the transmit queue now. Context: main. */
bool usb_tx_room(size_t bytes);
/* Queues a whole wire frame; false (nothing queued) if it does not fit. Context: main. */
bool usb_send_wire(const uint8_t* wire, size_t len);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_LINK_H_ */
