/*
 * The 64-bit device timebase (tb_): microseconds since fw_init, extended in software from the port's 32-bit
 * 1 MHz counter (hal_timer_now), which wraps every 2^32 us = 71.6 min.
 *
 * tb_now() adds the counter's advance since the previous call (mod 2^32) to a 64-bit total, so it is exact
 * as long as the main loop calls it at least once per wrap period -- fw_poll calls it on every pass, and
 * fw_next_wakeup_us never asks for a sleep longer than TB_MAX_SLEEP_US. Interrupt handlers only take 32-bit
 * counter stamps; the main loop turns them into device time with tb_extend, which is exact for stamps within
 * 2^31 us (35 min) of now, before or after.
 */
#ifndef ROTOSCAN_FIRMWARE_TIMEBASE_H_
#define ROTOSCAN_FIRMWARE_TIMEBASE_H_

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define TB_MAX_SLEEP_US 1000000u

/* Device time 0 = the counter now. Context: main. */
void tb_init(void);
/* Device time now. Context: main. */
uint64_t tb_now(void);
/* Device time of a 32-bit counter stamp taken within 2^31 us of now. Context: main. */
uint64_t tb_extend(uint32_t stamp);
/* The 32-bit counter value at device time t (for scheduling compares). Context: main. */
uint32_t tb_to_counter(uint64_t t);
/* (int32_t)(a - b) without implementation-defined conversion: how far counter value a is after b. */
int32_t tb_counter_diff(uint32_t a, uint32_t b);

#ifdef __cplusplus
}
#endif

#endif /* ROTOSCAN_FIRMWARE_TIMEBASE_H_ */
