// The extractor's AVX2 kernels, dispatched at run time (kernels.h: used when the CPU has AVX2 and
// internal::AllowVectorExtensions allows it). Each computes exactly what its SSE2 / portable namesake
// does (kernels_sse2.simd.hpp, kernels_scalar.simd.hpp), 32 pixels, 8 floats or 4 doubles per
// instruction. Compiled with per-function target attributes, so the rest of the library keeps the
// baseline instruction set.
#include "kernels.h"

#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
#include <immintrin.h>

#include <algorithm>
#include <cstdint>

namespace rotoscan::laser::detail {
namespace {
// 32 pixels of step 1 of the row pass (row_pass.cc): stores d, returns the bits of d >= t.
__attribute__((target("avx2"))) inline uint64_t HalfGroupAvx2(const uint8_t* a, const uint8_t* b, uint8_t* d,
                                                              __m256i t, __m256i headroom) {
  const __m256i va = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(a));
  const __m256i vb = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(b));
  // A saturated laser-on pixel over an off pixel with headroom counts as 255 (step 1).
  const __m256i saturated = _mm256_and_si256(_mm256_cmpeq_epi8(va, _mm256_set1_epi8(-1)),
                                             _mm256_cmpeq_epi8(_mm256_max_epu8(vb, headroom), headroom));
  const __m256i v = _mm256_or_si256(_mm256_subs_epu8(va, vb), saturated);
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(d), v);
  return static_cast<uint32_t>(_mm256_movemask_epi8(_mm256_cmpeq_epi8(_mm256_max_epu8(v, t), v)));
}

// OutlierBits (kernels_scalar.simd.hpp), 4 neighbours at a time.
__attribute__((target("avx2"))) inline uint64_t OutlierBitsAvx2(const float* raw, int i, int h, double a, double b,
                                                         double outlier_px, const double* window_x) {
  const __m256d abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffff));
  const __m256d va = _mm256_set1_pd(a), vb = _mm256_set1_pd(b), limit = _mm256_set1_pd(outlier_px);
  uint64_t bits = 0;
  for (int x0 = -h; x0 <= h; x0 += 4) {
    const __m256d fitted = _mm256_add_pd(va, _mm256_mul_pd(_mm256_loadu_pd(window_x + (x0 + h)), vb));
    const __m256d r = _mm256_and_pd(abs_mask, _mm256_sub_pd(_mm256_cvtps_pd(_mm_loadu_ps(raw + i + x0)), fitted));
    bits |= static_cast<uint64_t>(_mm256_movemask_pd(_mm256_cmp_pd(r, limit, _CMP_GT_OQ))) << (x0 + h);
  }
  return bits & (((uint64_t{1} << (2 * h + 1)) - 1) & ~(uint64_t{1} << h));
}
}  // namespace

// Step 1 of the row pass (row_pass.cc) over the row's whole 64-pixel groups, 32 pixels per
// instruction; returns the number of groups pushed and where it stopped.
__attribute__((target("avx2"))) int RowGroupsAvx2(const uint8_t* a, const uint8_t* b, uint8_t* d, int cols,
                                                  int threshold, int* starts, uint64_t* masks, int* next) {
  const __m256i t = _mm256_set1_epi8(static_cast<char>(threshold));
  const __m256i headroom = _mm256_set1_epi8(static_cast<char>(255 - threshold));
  int count = 0;
  int i0 = 0;
  for (; i0 + 64 <= cols; i0 += 64) {
    const uint64_t mask = HalfGroupAvx2(a + i0, b + i0, d + i0, t, headroom) |
                          HalfGroupAvx2(a + i0 + 32, b + i0 + 32, d + i0 + 32, t, headroom) << 32;
    starts[count] = i0;
    masks[count] = mask;
    count += mask != 0;
  }
  *next = i0;
  return count;
}

// The along-line smoothing's outlier screen (smooth.cc), 8 points at a time: ScreenWindows.
__attribute__((target("avx2"))) void ScreenWindowsAvx2(const float* rel, const float* af, const float* bf, int k0,
                                                       int k1, int h, float limit, uint64_t* bits) {
  const __m256 abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
  const __m256 lim = _mm256_set1_ps(limit);
  for (int k = k0; k < k1; k += 8) {
    const __m256 a = _mm256_loadu_ps(af + k), b = _mm256_loadu_ps(bf + k);
    __m256 worst = _mm256_setzero_ps();
    for (int x = 1; x <= h; ++x) {
      const __m256 xb = _mm256_mul_ps(_mm256_set1_ps(static_cast<float>(x)), b);
      const __m256 right = _mm256_sub_ps(_mm256_loadu_ps(rel + k + x), _mm256_add_ps(a, xb));
      const __m256 left = _mm256_sub_ps(_mm256_loadu_ps(rel + k - x), _mm256_sub_ps(a, xb));
      worst = _mm256_max_ps(_mm256_and_ps(abs_mask, right), worst);  // a NaN residual leaves worst as is
      worst = _mm256_max_ps(_mm256_and_ps(abs_mask, left), worst);
    }
    const uint64_t m = static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps(worst, lim, _CMP_GT_OQ)));
    bits[(k - k0) >> 6] |= m << ((k - k0) & 63);
  }
}

// FlaggedOutliers (kernels.h) with OutlierBitsAvx2.
__attribute__((target("avx2"))) void FlaggedOutliersAvx2(const float* raw, const double* a, const double* b, int k0,
                                                         int k1, int h, double outlier_px, const uint64_t* flagged,
                                                         const double* window_x, uint64_t* outliers) {
  for (int w = 0; w <= (k1 - k0 - 1) / 64; ++w) {
    for (uint64_t f = flagged[w]; f != 0; f &= f - 1) {
      const int k = k0 + 64 * w + __builtin_ctzll(f);
      if (k < k1) outliers[k] = OutlierBitsAvx2(raw, k, h, a[k], b[k], outlier_px, window_x);
    }
  }
}

// SmoothAlongLine's first fits (order 0 or 1) of the points k in [k0, k1) whose window is whole (k0 >= h,
// k1 <= len - h, k1 - k0 a multiple of 4), 4 points per turn: the same operations in the same order as its
// scalar loop (range_sums, then the whole-window solve), so the same bits. Returns the largest |b|.
__attribute__((target("avx2"))) double WholeWindowFitsAvx2(const double* py, const double* pjy, const double* pjjy,
                                                           int k0, int k1, int h, bool slope, double inv_s0,
                                                           double inv_s2, double origin, double* fit_a,
                                                           double* fit_b, float* af, float* bf) {
  const __m256d hp = _mm256_set1_pd(h + 1), two = _mm256_set1_pd(2.0), s0 = _mm256_set1_pd(inv_s0);
  const __m256d s2 = _mm256_set1_pd(inv_s2), o = _mm256_set1_pd(origin);
  const __m256d abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffff));
  __m256d kd = _mm256_setr_pd(k0, k0 + 1, k0 + 2, k0 + 3);
  const __m256d four = _mm256_set1_pd(4.0);
  __m256d max_b = _mm256_setzero_pd();
  for (int k = k0; k < k1; k += 4, kd = _mm256_add_pd(kd, four)) {
    const __m256d y_k = _mm256_loadu_pd(py + k), jy_k = _mm256_loadu_pd(pjy + k), jjy_k = _mm256_loadu_pd(pjjy + k);
    const __m256d ly = _mm256_sub_pd(y_k, _mm256_loadu_pd(py + k - h));
    const __m256d ljy = _mm256_sub_pd(jy_k, _mm256_loadu_pd(pjy + k - h));
    const __m256d ljjy = _mm256_sub_pd(jjy_k, _mm256_loadu_pd(pjjy + k - h));
    const __m256d ry = _mm256_sub_pd(_mm256_loadu_pd(py + k + h + 1), y_k);
    const __m256d rjy = _mm256_sub_pd(_mm256_loadu_pd(pjy + k + h + 1), jy_k);
    const __m256d rjjy = _mm256_sub_pd(_mm256_loadu_pd(pjjy + k + h + 1), jjy_k);
    const __m256d two_k = _mm256_mul_pd(two, kd), kk = _mm256_mul_pd(kd, kd);
    const __m256d lxy = _mm256_sub_pd(ljy, _mm256_mul_pd(kd, ly));
    const __m256d lxxy = _mm256_add_pd(_mm256_sub_pd(ljjy, _mm256_mul_pd(two_k, ljy)), _mm256_mul_pd(kk, ly));
    const __m256d rxy = _mm256_sub_pd(rjy, _mm256_mul_pd(kd, ry));
    const __m256d rxxy = _mm256_add_pd(_mm256_sub_pd(rjjy, _mm256_mul_pd(two_k, rjy)), _mm256_mul_pd(kk, ry));
    const __m256d t0 = _mm256_sub_pd(_mm256_add_pd(_mm256_mul_pd(hp, _mm256_add_pd(ly, ry)), lxy), rxy);
    const __m256d fa = _mm256_mul_pd(t0, s0);
    __m256d fb = _mm256_setzero_pd();
    if (slope) {
      const __m256d t1 = _mm256_sub_pd(_mm256_add_pd(_mm256_mul_pd(hp, _mm256_add_pd(lxy, rxy)), lxxy), rxxy);
      fb = _mm256_mul_pd(t1, s2);
    }
    _mm256_storeu_pd(fit_a + k, _mm256_add_pd(fa, o));
    _mm256_storeu_pd(fit_b + k, fb);
    _mm_storeu_ps(af + k, _mm256_cvtpd_ps(fa));
    _mm_storeu_ps(bf + k, _mm256_cvtpd_ps(fb));
    max_b = _mm256_max_pd(max_b, _mm256_and_pd(fb, abs_mask));
  }
  alignas(32) double lanes[4];
  _mm256_store_pd(lanes, max_b);
  return std::max(std::max(lanes[0], lanes[1]), std::max(lanes[2], lanes[3]));
}

}  // namespace rotoscan::laser::detail
#endif  // ROTOSCAN_HAVE_SSSE3_PATH
