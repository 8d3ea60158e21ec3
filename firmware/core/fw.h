/*
 * fw.h -- the firmware core's entry points, called by a port (firmware/port/<board>/): fw_init once after the
 * board is up, fw_poll from the main loop forever, and the fw_isr_* functions from the interrupt handlers
 * that hal.h names. The core has no register access and no dynamic memory; all its state is static.
 */
#ifndef ROTOSCAN_FIRMWARE_FW_H_
#define ROTOSCAN_FIRMWARE_FW_H_

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#include "version.h" /* FW_VERSION_MAJOR, _MINOR, _PATCH */

/* Power-on: resets every module, device time 0 = now, queues a STATUS event with cause BOOT. Context: main.
 */
void fw_init(void);
/* One pass of the main loop: the link, the dispatcher, the stepper queue, the sequencer, the laser safety
 * timeout. Never blocks. Context: main. */
void fw_poll(void);
/* The device time (tb_now) by which fw_poll must run again even if no interrupt happens; never more than
 * TB_MAX_SLEEP_US ahead. A port may sleep until then (or until an interrupt). Context: main. */
uint64_t fw_next_wakeup_us(void);

/* Step timer interrupt: returns the delay to the next one in us, 0 to stop. Context: isr. */
uint32_t fw_isr_step(void);
/* Trigger compare interrupt: the rising edge happened at counter value `at`. Context: isr. */
void fw_isr_trigger(uint32_t at);
/* Exposure-line capture interrupt: the line went to `level` at counter value `at`. Context: isr. */
void fw_isr_exposure(uint32_t at, bool level);

/* Queues a LOG event from the port: `text` followed by " 0x" and the two values in hexadecimal (cut to the
 * LOG's length). For what only the port knows, e.g. the fault recorded before a reset. Context: main, after
 * fw_init. */
#define FW_REPORT_INFO 1u    /* PROTO_LOG_INFO */
#define FW_REPORT_WARNING 2u /* PROTO_LOG_WARNING */
#define FW_REPORT_ERROR 3u   /* PROTO_LOG_ERROR */
void fw_report(uint8_t level, const char* text, uint32_t a, uint32_t b);

/* USB OUT (or UART RX) data arrived: queues up to `len` bytes and returns how many it took (the rest must
 * be offered again later: flow control). Context: isr or main. */
size_t fw_usb_rx(const uint8_t* data, size_t len);
/* USB IN (or UART TX) can take up to `max` bytes: copies queued bytes to `out`, returns their count.
 * Context: isr or main (one of them, consistently). */
size_t fw_usb_tx(uint8_t* out, size_t max);
/* Bytes queued for fw_usb_tx. */
size_t fw_usb_tx_pending(void);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_FW_H_ */
