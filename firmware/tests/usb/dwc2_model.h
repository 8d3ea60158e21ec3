/*
 * dwc2_model.h -- a register-level model of the Synopsys DWC2 USB core in device mode, as the STM32F411's
 * OTG_FS has it (RM0383 chapter 22), for running the firmware's USB driver off the chip: the host tests do,
 * and an emulator running the real image (issue 18) can map the same model behind OTG_FS's address window.
 *
 * Two sides. The bus side (dwc2_model_read / dwc2_model_write, offsets from the core's base) is what the
 * driver sees: registers with their write-1-to-clear and self-clearing bits, the receive FIFO as GRXSTSP
 * entries each followed by its data words, one transmit FIFO per IN endpoint sized from DIEPTXFx, the
 * interrupt tree (GINTSTS <- DAINT <- DIEPINTx / DOEPINTx) and dwc2_model_irq, the core's interrupt line.
 * The USB side (dwc2_model_setup / _out / _in / _bus_reset) is one host transaction per call, answered as
 * the core would: ACK, NAK, STALL, or nothing (wrong address, not connected).
 *
 * The model also checks the driver: a use the core does not allow -- popping GRXSTSP before the previous
 * entry's words are read, reading past them, enabling an endpoint without programming its transfer size
 * first, overfilling a transmit FIFO, FIFOs beyond the 320 words, VBUS sensing on a board without VBUS --
 * is recorded (dwc2_model_error) and makes the transaction fail the way the hardware would misbehave.
 * Plain C with no dependency, so that any harness can use it.
 */
#ifndef ROTOSCAN_FIRMWARE_TESTS_DWC2_MODEL_H_
#define ROTOSCAN_FIRMWARE_TESTS_DWC2_MODEL_H_

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct dwc2_model dwc2_model_t;

enum dwc2_model_result {
  DWC2_MODEL_ACK = 0,
  DWC2_MODEL_NAK = 1,
  DWC2_MODEL_STALL = 2,
  DWC2_MODEL_NO_ANSWER = 3 /* no device at that address, or not connected: the host times out */
};

dwc2_model_t* dwc2_model_create(void);
void dwc2_model_destroy(dwc2_model_t* m);

/* Bus side: a 32-bit read or write at `offset` from the core's base (0 .. 0x1FFFF). */
uint32_t dwc2_model_read(dwc2_model_t* m, uint32_t offset);
void dwc2_model_write(dwc2_model_t* m, uint32_t offset, uint32_t value);
/* The core's interrupt line (OTG_FS global interrupt). */
bool dwc2_model_irq(const dwc2_model_t* m);

/* USB side. Whether the device pulls D+ up (connected, transceiver on, VBUS sensing set for this board). */
bool dwc2_model_connected(const dwc2_model_t* m);
/* The host resets the bus (USBRST, then ENUMDNE at full speed); the device answers at address 0 again. */
void dwc2_model_bus_reset(dwc2_model_t* m);
/* A SETUP transaction to endpoint 0 at `address`: always ACKed by a connected device at that address. */
int dwc2_model_setup(dwc2_model_t* m, uint8_t address, const uint8_t packet[8]);
/* An OUT transaction of `len` bytes (<= the endpoint's max packet). */
int dwc2_model_out(dwc2_model_t* m, uint8_t address, uint8_t ep, const uint8_t* data, size_t len);
/* An IN transaction: on ACK, *len bytes (0 for a zero-length packet) were copied to `buf` (room `max`). */
int dwc2_model_in(dwc2_model_t* m, uint8_t address, uint8_t ep, uint8_t* buf, size_t max, size_t* len);

/* The first misuse of the core by the driver, or NULL. */
const char* dwc2_model_error(const dwc2_model_t* m);
/* The address the core answers at now. */
uint8_t dwc2_model_address(const dwc2_model_t* m);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_TESTS_DWC2_MODEL_H_ */
