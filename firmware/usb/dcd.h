/*
 * dcd.h -- the device controller driver (dcd_): the only USB code that touches registers. It knows the DWC2
 * core (dcd_dwc2.c) and nothing of requests or descriptors; the chip-independent request handling (usbd.c)
 * sits on top, TinyUSB's split. Transfers are one buffer per endpoint, moved one packet at a time; a
 * zero-length transfer sends (IN) or accepts (OUT) a zero-length packet.
 *
 * Context: every function is called from the USB interrupt (dcd_irq and what it calls back), except
 * dcd_init / dcd_connect, called once from the main loop before the interrupt is enabled.
 */
#ifndef ROTOSCAN_FIRMWARE_DCD_H_
#define ROTOSCAN_FIRMWARE_DCD_H_

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define DCD_EP0_SIZE 64u
#define DCD_EP_COUNT 4u /* the F411's OTG_FS: endpoint 0 and three more in each direction */
#define DCD_DIR_IN 0x80u

/* FIFO plan, in 32-bit words out of DWC2_FIFO_WORDS (320). Receive: all OUT endpoints share it; RM0383 22.11
 * asks for 10 words for SETUP packets (3 back-to-back plus status), one word per OUT endpoint for the
 * transfer-complete entries, and room for two max-size packets (2 x (64 / 4 + 1)): 10 + 4 + 34 = 48; we
 * give it 128. Transmit: one per IN endpoint, at least one max-size packet (16 words). */
#define DCD_RX_FIFO_WORDS 128u
#define DCD_TX0_FIFO_WORDS 32u
#define DCD_TX1_FIFO_WORDS 64u

/* Resets the core into device mode with the FIFOs above, full speed, no VBUS sensing, the soft disconnect
 * still on. Returns 0, or -1 if the core does not come out of reset (the clock is not running). */
int dcd_init(void);
/* Connects (removes the soft disconnect): the host sees the pull-up and resets the bus. */
void dcd_connect(void);
/* Handles every pending interrupt of the core and returns; calls the usbd_ callbacks below. */
void dcd_irq(void);

/* Writes the address the host gave with SET_ADDRESS into DCFG.DAD. Must happen before the status stage. */
void dcd_set_address(uint8_t address);
/* Opens a bulk endpoint (ep: number | DCD_DIR_IN for IN), DATA0, NAKing until a transfer is queued. */
void dcd_ep_open_bulk(uint8_t ep, uint16_t max_packet);
/* Queues a transfer: IN sends `len` bytes of `buf` (0: one zero-length packet); OUT receives one packet of at
 * most `len` bytes into `buf`. `buf` must stay valid until usbd_on_xfer_done. False if one is running. */
bool dcd_ep_xfer(uint8_t ep, uint8_t* buf, uint16_t len);
/* Whether a transfer is queued on the endpoint. */
bool dcd_ep_busy(uint8_t ep);
/* Stalls an endpoint (endpoint 0: both directions, until the next SETUP), or clears a stall (resets the data
 * toggle to DATA0 as CLEAR_FEATURE(ENDPOINT_HALT) requires). */
void dcd_ep_stall(uint8_t ep);
void dcd_ep_clear_stall(uint8_t ep);
bool dcd_ep_stalled(uint8_t ep);

/* Callbacks into the request layer, from dcd_irq. */
void usbd_on_bus_reset(void);
void usbd_on_setup(const uint8_t setup[8]);
void usbd_on_xfer_done(uint8_t ep, uint16_t len);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_DCD_H_ */
