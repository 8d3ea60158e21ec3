/*
 * usbd.h -- the chip-independent half of the USB device stack (usbd_): endpoint 0's standard requests,
 * descriptors, configuration, and the hand-off of vendor requests and of the other endpoints' transfers to the
 * function (usb_link.c for the board). It reaches the hardware only through dcd.h.
 *
 * Endpoint 0 answers GET_DESCRIPTOR (device, configuration, string), SET_ADDRESS, SET_CONFIGURATION,
 * GET_CONFIGURATION, GET_STATUS, CLEAR_FEATURE / SET_FEATURE (ENDPOINT_HALT), GET_INTERFACE /
 * SET_INTERFACE (alternate setting 0 only) and the vendor requests the function accepts. Everything else --
 * the device-qualifier and BOS descriptors a full-speed USB 2.0 device does not have, unknown requests,
 * wrong directions, lengths or indices -- gets a STALL (USB 2.0 9.2.7, "request error"), never a hang.
 */
#ifndef ROTOSCAN_FIRMWARE_USBD_H_
#define ROTOSCAN_FIRMWARE_USBD_H_

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define USBD_MAX_STRING_CHARS 31u /* a string descriptor fits one 64-byte packet */

typedef struct {
  /* bmRequestType, bRequest, wValue, wIndex, wLength as received (little endian decoded). */
  uint8_t bm_request_type;
  uint8_t b_request;
  uint16_t w_value;
  uint16_t w_index;
  uint16_t w_length;
} usbd_setup_t;

typedef struct {
  const uint8_t* device; /* 18 bytes */
  const uint8_t* config; /* the whole configuration (wTotalLength at bytes 2-3) */
  const char* const* strings; /* index 1..string_count (ASCII); [0] unused */
  uint8_t string_count;
  /* The interface's endpoints, opened by SET_CONFIGURATION 1. */
  uint8_t ep_in;
  uint8_t ep_out;
  uint16_t ep_size;
  /* SET_CONFIGURATION: true = configured (endpoints open), false = back to the address state or reset. */
  void (*on_configured)(bool configured);
  /* A transfer on ep_in or ep_out ended. */
  void (*on_xfer_done)(uint8_t ep, uint16_t len);
  /* A vendor request (device-to-host with wLength > 0, or no data stage): fill `reply` with up to `room`
   * bytes and return their count, 0 for no data, or -1 to STALL it. May be NULL (every vendor request
   * stalls). */
  int (*on_vendor_request)(const usbd_setup_t* setup, uint8_t* reply, size_t room);
} usbd_function_t;

/* Installs the function's descriptors and callbacks; resets the state. Context: main, before dcd_init. */
void usbd_init(const usbd_function_t* function);
/* 0 until SET_CONFIGURATION 1, then 1. */
uint8_t usbd_configuration(void);
/* The address the host assigned (0 before SET_ADDRESS). */
uint8_t usbd_address(void);
/* Counts of requests stalled since reset (for the tests and diagnostics). */
uint32_t usbd_stalls(void);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_USBD_H_ */
