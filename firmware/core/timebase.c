#include "timebase.h"

#include "hal.h"

static struct {
  uint32_t boot_counter; /* counter value at device time 0 */
  uint32_t last_counter; /* counter at the last tb_now */
  uint64_t last_time;    /* device time at the last tb_now */
} g_tb;

void tb_init(void) {
  g_tb.boot_counter = hal_timer_now();
  g_tb.last_counter = g_tb.boot_counter;
  g_tb.last_time = 0;
}

uint64_t tb_now(void) {
  const uint32_t counter = hal_timer_now();
  g_tb.last_time += (uint32_t)(counter - g_tb.last_counter); /* mod 2^32: survives the wrap */
  g_tb.last_counter = counter;
  return g_tb.last_time;
}

int32_t tb_counter_diff(uint32_t a, uint32_t b) {
  const uint32_t d = a - b;
  return d <= (uint32_t)INT32_MAX ? (int32_t)d : (int32_t)(d - 0x80000000u) + INT32_MIN;
}

uint64_t tb_extend(uint32_t stamp) {
  const uint64_t now = tb_now();
  const int32_t d = tb_counter_diff(stamp, g_tb.last_counter);
  if (d < 0 && (uint64_t)(-(int64_t)d) > now) return 0; /* before device time 0: clamp */
  return (uint64_t)((int64_t)now + d);
}

uint32_t tb_to_counter(uint64_t t) {
  return (uint32_t)(g_tb.boot_counter + (uint32_t)t);
}
