// Which instruction-set paths the extractor runs (kernels.h): the CPU's, as far as the tests allow.
#include <atomic>

#include "kernels.h"
#include "rotoscan/laser/extract.h"

namespace rotoscan::laser {
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
namespace detail {
namespace {
std::atomic<bool> allow_avx2{true}, allow_ssse3{true};
}  // namespace

bool HaveSsse3() {
  static const bool have = __builtin_cpu_supports("ssse3");
  return have && allow_ssse3.load(std::memory_order_relaxed);
}
bool HaveAvx2() {
  static const bool have = __builtin_cpu_supports("avx2");
  return have && allow_avx2.load(std::memory_order_relaxed);
}
}  // namespace detail
#endif

namespace internal {
void AllowVectorExtensions(bool avx2, bool ssse3) {
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  detail::allow_avx2.store(avx2);
  detail::allow_ssse3.store(ssse3);
#else
  (void)avx2;
  (void)ssse3;
#endif
}
bool UseAvx2() {
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  return detail::HaveAvx2();
#else
  return false;
#endif
}
}  // namespace internal

}  // namespace rotoscan::laser
