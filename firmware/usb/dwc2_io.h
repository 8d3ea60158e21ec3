/*
 * dwc2_io.h -- how the DWC2 driver reaches the core's registers: offsets from the core's base through two
 * inline functions. On the MCU they are volatile accesses at OTG_FS's address (0x5000_0000); in a build with
 * DWC2_IO_EXTERN defined (the host tests, and later an emulator running the same driver) they are calls to
 * dwc2_io_read / dwc2_io_write, which the test links to its register-level model (tests/usb/dwc2_model.h).
 */
#ifndef ROTOSCAN_FIRMWARE_DWC2_IO_H_
#define ROTOSCAN_FIRMWARE_DWC2_IO_H_

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#ifdef DWC2_IO_EXTERN
uint32_t dwc2_io_read(uint32_t offset);
void dwc2_io_write(uint32_t offset, uint32_t value);
static inline uint32_t dwc2_rd(uint32_t offset) {
  return dwc2_io_read(offset);
}
static inline void dwc2_wr(uint32_t offset, uint32_t value) {
  dwc2_io_write(offset, value);
}
#else
#define DWC2_BASE 0x50000000u /* OTG_FS, RM0383 table 1 (asserted in stm32f411_regs.h) */
static inline uint32_t dwc2_rd(uint32_t offset) {
  return *(volatile uint32_t*)(uintptr_t)(DWC2_BASE + offset);
}
static inline void dwc2_wr(uint32_t offset, uint32_t value) {
  *(volatile uint32_t*)(uintptr_t)(DWC2_BASE + offset) = value;
}
#endif

static inline void dwc2_set(uint32_t offset, uint32_t bits) {
  dwc2_wr(offset, dwc2_rd(offset) | bits);
}
static inline void dwc2_clear(uint32_t offset, uint32_t bits) {
  dwc2_wr(offset, dwc2_rd(offset) & ~bits);
}

/* Waits for a register condition for at most `spins` reads (the driver never waits forever on hardware). */
static inline int dwc2_wait(uint32_t offset, uint32_t mask, uint32_t want, uint32_t spins) {
  while (spins-- > 0u) {
    if ((dwc2_rd(offset) & mask) == want) return 0;
  }
  return -1;
}

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_DWC2_IO_H_ */
