// White-box tests of the firmware core's parts: ring buffers, the stepper profile, the timebase arithmetic.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <vector>

#include "ring.h"
#include "sim_port.h"
#include "stepper.h"
#include "timebase.h"

namespace rotoscan::firmware_test {
namespace {

TEST(FirmwareRing, RejectsACapacityThatIsNotAPowerOfTwo) {
  uint32_t storage[12];
  ring_t r;
  EXPECT_EQ(ring_init(&r, storage, 12, sizeof(uint32_t)), -EINVAL);
  EXPECT_EQ(ring_init(&r, storage, 0, sizeof(uint32_t)), -EINVAL);
  EXPECT_EQ(ring_init(&r, nullptr, 8, sizeof(uint32_t)), -EINVAL);
  EXPECT_EQ(ring_init(&r, storage, 8, sizeof(uint32_t)), 0);
}

TEST(FirmwareRing, KeepsOrderAcrossWrapAndReportsFullAndEmpty) {
  uint32_t storage[8];
  ring_t r;
  ASSERT_EQ(ring_init(&r, storage, 8, sizeof(uint32_t)), 0);
  r.head = r.tail = 0xFFFFFFFCu;  // the free-running indices wrap during the test
  uint32_t next_in = 0;
  uint32_t next_out = 0;
  for (int round = 0; round < 50; ++round) {
    const int pushes = 1 + round % 8;
    for (int i = 0; i < pushes; ++i) {
      if (ring_count(&r) == 8) {
        EXPECT_FALSE(ring_push(&r, &next_in));
        break;
      }
      ASSERT_TRUE(ring_push(&r, &next_in));
      ++next_in;
    }
    EXPECT_EQ(ring_count(&r) + ring_space(&r), 8u);
    const int pops = 1 + (round * 5) % 7;
    for (int i = 0; i < pops; ++i) {
      uint32_t v;
      if (ring_count(&r) == 0) {
        EXPECT_FALSE(ring_pop(&r, &v));
        break;
      }
      ASSERT_TRUE(ring_pop(&r, &v));
      EXPECT_EQ(v, next_out++);
    }
  }
  EXPECT_GT(next_out, 100u);
}

TEST(FirmwareRing, ByteWritesAreAllOrNothing) {
  uint8_t storage[16];
  ring_t r;
  ASSERT_EQ(ring_init(&r, storage, 16, 1), 0);
  const uint8_t data[20] = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20};
  EXPECT_TRUE(ring_write_all(&r, data, 10));
  EXPECT_FALSE(ring_write_all(&r, data, 7));  // 6 free: nothing written
  EXPECT_EQ(ring_count(&r), 10u);
  EXPECT_EQ(ring_write_some(&r, data + 10, 10), 6u);
  uint8_t out[20];
  ASSERT_EQ(ring_read(&r, out, 20), 16u);
  for (int i = 0; i < 16; ++i) EXPECT_EQ(out[i], i + 1);
  EXPECT_EQ(ring_read(&r, out, 20), 0u);
}

TEST(FirmwareStepperPlan, RoundedEdgesStayWithinHalfATickOfTheExactProfile) {
  const step_profile_cfg_t cfg = {300, 12000, 50000};
  step_plan_t plan;
  step_plan_init(&plan, &cfg, 20000);
  // ramp = floor((12000^2 - 300^2) / (2 * 50000)) = 1439 steps
  EXPECT_EQ(plan.ramp, 1439u);
  double exact = 0;
  uint64_t rounded = 0;
  uint32_t interval;
  uint32_t count = 0;
  double worst = 0;
  while (step_plan_next(&plan, &interval)) {
    const double v0 = 300, a = 50000;
    const uint32_t i = count;
    const uint32_t k = i < plan.ramp ? i : (i >= 20000 - plan.ramp ? 20000 - 1 - i : plan.ramp);
    const double d = (i < plan.ramp || i >= 20000 - plan.ramp)
                         ? 2e6 / (std::sqrt(v0 * v0 + 2 * a * k) + std::sqrt(v0 * v0 + 2 * a * (k + 1)))
                         : 1e6 / std::sqrt(v0 * v0 + 2 * a * plan.ramp);
    exact += d;
    rounded += interval;
    worst = std::max(worst, std::abs(static_cast<double>(rounded) - exact));
    ++count;
  }
  EXPECT_EQ(count, 20000u);
  EXPECT_LT(worst, 0.75);  // 0.5 from rounding, the rest single-precision arithmetic
}

TEST(FirmwareStepperPlan, IsSymmetricAndNeverFasterThanTheCeiling) {
  const step_profile_cfg_t cfg = {100, 3000, 10000};
  step_plan_t plan;
  step_plan_init(&plan, &cfg, 1001);
  for (uint32_t i = 0; i < 1001; ++i) {
    EXPECT_FLOAT_EQ(step_plan_exact_us(&plan, i), step_plan_exact_us(&plan, 1000 - i)) << i;
    EXPECT_GE(step_plan_exact_us(&plan, i), 1e6f / 3000.0f * 0.9999f) << i;
  }
}

TEST(FirmwareTimebase, ExtendsStampsOnEitherSideOfTheWrap) {
  sim_reset_with_counter(0xFFFFFF00u);  // tb_init ran in fw_init: device time 0 = counter 0xFFFFFF00
  sim_advance_us(0x200);                // counter now 0x100, past the wrap
  EXPECT_EQ(tb_now(), 0x200u);
  EXPECT_EQ(tb_extend(0xFFFFFFF0u), 0xF0u);  // a stamp from before the wrap
  EXPECT_EQ(tb_extend(0x80u), 0x180u);       // after it
  EXPECT_EQ(tb_extend(0x300u), 0x400u);      // a time scheduled ahead
  EXPECT_EQ(tb_to_counter(0x400u), 0x300u);
  EXPECT_EQ(tb_counter_diff(0x10u, 0xFFFFFFF0u), 0x20);
  EXPECT_EQ(tb_counter_diff(0xFFFFFFF0u, 0x10u), -0x20);
}

}  // namespace
}  // namespace rotoscan::firmware_test
