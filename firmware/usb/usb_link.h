/*
 * usb_link.h -- the board's USB function: the descriptors (pid.codes VID 0x1209, test PID 0x0001, the values
 * host/lib/include/rotoscan/device/usb_ids.h expects), one vendor-class interface with bulk OUT 0x01 and bulk
 * IN 0x81 (64 bytes), and the byte pump between those endpoints and the firmware core's link queues
 * (fw_usb_rx / fw_usb_tx, core/fw.h). Built on usbd.h, so it never touches a register.
 */
#ifndef ROTOSCAN_FIRMWARE_USB_LINK_H_
#define ROTOSCAN_FIRMWARE_USB_LINK_H_

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define USB_LINK_VID 0x1209u
#define USB_LINK_PID 0x0001u
#define USB_LINK_EP_OUT 0x01u
#define USB_LINK_EP_IN 0x81u
#define USB_LINK_PACKET 64u
/* Vendor request (device-to-host, recipient device): the firmware version, 3 bytes major, minor, patch. */
#define USB_LINK_REQ_VERSION 0x01u

/* Installs the function into usbd; `uid` (12 bytes, the chip's unique id) becomes the serial number string
 * (24 hexadecimal digits). Context: main, before dcd_init. */
void usb_link_init(const uint8_t uid[12]);
/* Moves bytes now: refills the bulk IN endpoint from fw_usb_tx and offers bytes held back from a full receive
 * queue to fw_usb_rx again. Context: the USB interrupt (a port pends it from hal_usb_tx_kick). */
void usb_link_service(void);
/* Whether usb_link_service has work (bytes held back, or transmit bytes and the IN endpoint idle). */
bool usb_link_wants_service(void);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_USB_LINK_H_ */
