// The extractor's AVX2 kernels, dispatched at run time (kernels.h: used when the CPU has AVX2 and
// internal::AllowVectorExtensions allows it). Each computes exactly what its SSE2 / portable namesake
// does (kernels_sse2.simd.hpp, kernels_scalar.simd.hpp), 32 pixels, 8 floats or 4 doubles per
// instruction. Compiled with per-function target attributes, so the rest of the library keeps the
// baseline instruction set.
#include "kernels.h"

#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
#include <immintrin.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>

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

// 4 bytes as 4 doubles.
__attribute__((target("avx2"))) inline __m256d Bytes4Avx2(const uint8_t* p) {
  int32_t v;
  std::memcpy(&v, p, sizeof(v));
  return _mm256_cvtepi32_pd(_mm_cvtepu8_epi32(_mm_cvtsi32_si128(v)));
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

// smooth.cc's steep_fit for 4 points (kernels.h: SteepFitsAvx2). Each lane runs the scalar fit's loops, x from
// -h up, with the same operations on the same numbers (double, no fused multiply-add); a neighbour outside its
// point's window (or, in the second fit, not explained by the first) adds +0, which leaves a sum as it is (none
// is ever -0: each starts at +0, and a sum is -0 only when both terms are). Then the scalar fit's solve (order
// 1: the slope where the window's rows allow it), its outlier test with q = 0 as the scalar straight fit has
// it, and for the lanes with an outlier the second fit without them.
namespace {
struct SteepSums {
  __m256d s0, s1, s2, t0, t1;
};
// The neighbours j = i + x of the lanes' points that lie in their windows [lo, hi].
__attribute__((target("avx2"))) inline __m256d InWindow(__m128i j, __m128i lo, __m128i hi) {
  const __m128i out = _mm_or_si128(_mm_cmpgt_epi32(lo, j), _mm_cmpgt_epi32(j, hi));
  return _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm_xor_si128(out, _mm_set1_epi32(-1))));
}
// Not explained by the fit (a, b): not (|raw[j] - (a + x (b + x 0))| <= limit), a NaN included.
__attribute__((target("avx2"))) inline __m256d Unexplained(__m256d raw_j, double xd, __m256d a, __m256d b,
                                                           __m256d limit) {
  const __m256d abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffff));
  const __m256d fitted =
      _mm256_add_pd(a, _mm256_mul_pd(_mm256_set1_pd(xd), _mm256_add_pd(b, _mm256_set1_pd(xd * 0.0))));
  return _mm256_cmp_pd(_mm256_and_pd(abs_mask, _mm256_sub_pd(raw_j, fitted)), limit, _CMP_NLE_UQ);
}
// The fit's a (relative to ri) and b from its sums, as smooth.cc's fit solves them for order 0 or 1.
__attribute__((target("avx2"))) inline void SolveSteep(const SteepSums& u, bool slope, __m256d* a, __m256d* b) {
  const __m256d det = _mm256_sub_pd(_mm256_mul_pd(u.s0, u.s2), _mm256_mul_pd(u.s1, u.s1));
  const __m256d level = _mm256_mul_pd(_mm256_mul_pd(_mm256_set1_pd(1e-9), u.s0), u.s2);
  const __m256d sloped = slope ? _mm256_cmp_pd(det, level, _CMP_GT_OQ) : _mm256_setzero_pd();
  const __m256d a_line = _mm256_div_pd(_mm256_sub_pd(_mm256_mul_pd(u.s2, u.t0), _mm256_mul_pd(u.s1, u.t1)), det);
  const __m256d b_line = _mm256_div_pd(_mm256_sub_pd(_mm256_mul_pd(u.s0, u.t1), _mm256_mul_pd(u.s1, u.t0)), det);
  *a = _mm256_blendv_pd(_mm256_div_pd(u.t0, u.s0), a_line, sloped);
  *b = _mm256_blendv_pd(_mm256_setzero_pd(), b_line, sloped);
}

// The sums of the lanes' fits over their windows, less (where the fit (a, b) and limit are given) the
// neighbours that fit does not explain: the point itself always stays.
// The lanes' neighbours raw[i + x]: one load where the 4 points are consecutive (most: a steep line's rows).
__attribute__((target("avx2"))) inline __m256d Neighbours(const float* raw, __m128i vi, const int* i4, bool consecutive,
                                                         int x) {
  if (consecutive) return _mm256_cvtps_pd(_mm_loadu_ps(raw + i4[0] + x));
  return _mm256_cvtps_pd(_mm_i32gather_ps(raw, _mm_add_epi32(vi, _mm_set1_epi32(x)), 4));
}
__attribute__((target("avx2"))) inline SteepSums SteepFitSums(const float* raw, __m128i vi, const int* i4, bool consecutive,
                                                             __m256d ri, __m128i lo, __m128i hi, int h, bool drop,
                                                             __m256d a, __m256d b, __m256d limit) {
  const __m256d zero = _mm256_setzero_pd();
  SteepSums u{zero, zero, zero, zero, zero};
  for (int x = -h; x <= h; ++x) {
    const __m128i j = _mm_add_epi32(vi, _mm_set1_epi32(x));
    const __m256d raw_j = Neighbours(raw, vi, i4, consecutive, x);
    __m256d in = InWindow(j, lo, hi);
    if (drop && x != 0) in = _mm256_andnot_pd(Unexplained(raw_j, x, a, b, limit), in);
    if (_mm256_movemask_pd(in) == 0) continue;  // every lane would add +0
    const double xd = x;
    const double w = h + 1 - std::abs(xd);
    const double wx = w * xd, wxx = wx * xd;
    const __m256d y = _mm256_sub_pd(raw_j, ri);
    u.s0 = _mm256_add_pd(u.s0, _mm256_and_pd(in, _mm256_set1_pd(w)));
    u.s1 = _mm256_add_pd(u.s1, _mm256_and_pd(in, _mm256_set1_pd(wx)));
    u.s2 = _mm256_add_pd(u.s2, _mm256_and_pd(in, _mm256_set1_pd(wxx)));
    u.t0 = _mm256_add_pd(u.t0, _mm256_and_pd(in, _mm256_mul_pd(_mm256_set1_pd(w), y)));
    u.t1 = _mm256_add_pd(u.t1, _mm256_and_pd(in, _mm256_mul_pd(_mm256_set1_pd(wx), y)));
  }
  return u;
}
}  // namespace

__attribute__((target("avx2"))) void SteepFitsAvx2(const float* raw, const int* i4, int start, int end, int h, bool slope,
                                                   double outlier_px, double* fit_a) {
  const __m128i vi = _mm_loadu_si128(reinterpret_cast<const __m128i*>(i4));
  const __m128i lo = _mm_max_epi32(_mm_set1_epi32(start), _mm_sub_epi32(vi, _mm_set1_epi32(h)));
  const __m128i hi = _mm_min_epi32(_mm_set1_epi32(end), _mm_add_epi32(vi, _mm_set1_epi32(h)));
  const bool consecutive = i4[1] == i4[0] + 1 && i4[2] == i4[0] + 2 && i4[3] == i4[0] + 3;
  const __m256d ri = Neighbours(raw, vi, i4, consecutive, 0);
  const __m256d zero = _mm256_setzero_pd();
  __m256d a, b;
  SolveSteep(SteepFitSums(raw, vi, i4, consecutive, ri, lo, hi, h, false, zero, zero, zero), slope, &a, &b);
  a = _mm256_add_pd(a, ri);
  const __m256d limit =
      _mm256_mul_pd(_mm256_set1_pd(outlier_px), _mm256_sqrt_pd(_mm256_add_pd(_mm256_set1_pd(1.0), _mm256_mul_pd(b, b))));
  __m256d fails = zero;
  for (int x = -h; x <= h; ++x) {
    if (x == 0) continue;  // the point itself is always explained
    const __m128i j = _mm_add_epi32(vi, _mm_set1_epi32(x));
    const __m256d raw_j = Neighbours(raw, vi, i4, consecutive, x);
    fails = _mm256_or_pd(fails, _mm256_and_pd(InWindow(j, lo, hi), Unexplained(raw_j, x, a, b, limit)));
  }
  if (_mm256_movemask_pd(fails) != 0) {  // the second fit, without the neighbours the first does not explain
    __m256d a2, b2;
    SolveSteep(SteepFitSums(raw, vi, i4, consecutive, ri, lo, hi, h, true, a, b, limit), slope, &a2, &b2);
    a = _mm256_blendv_pd(a, _mm256_add_pd(a2, ri), fails);
  }
  _mm256_storeu_pd(fit_a, a);
}

namespace {
// One field of 4 consecutive points' terms.
__attribute__((target("avx2"))) inline __m256d Field(const PointTerms* t, double PointTerms::*m) {
  return _mm256_setr_pd(t[0].*m, t[1].*m, t[2].*m, t[3].*m);
}
// All ones in the lanes whose flags hold `bit`.
__attribute__((target("avx2"))) inline __m256d FlagMask(const uint8_t* flags, uint8_t bit) {
  return _mm256_castsi256_pd(_mm256_setr_epi64x((flags[0] & bit) ? -1 : 0, (flags[1] & bit) ? -1 : 0,
                                                (flags[2] & bit) ? -1 : 0, (flags[3] & bit) ? -1 : 0));
}
// q * factor in the lanes of mask, q elsewhere.
__attribute__((target("avx2"))) inline __m256d ScaleWhere(__m256d q, __m256d factor, __m256d mask) {
  return _mm256_blendv_pd(q, _mm256_mul_pd(q, factor), mask);
}
}  // namespace

// AlbedoBlurredRatio (point.cc), 4 pixels per turn: each lane's blur adds the 7 products in the scalar
// loop's order (sv from 0, the weights' sum as the scalar's whole window sums them), then the same division,
// clamps, truncation and table interpolation (the table's difference in float, as there): the same bits.
// No FMA (the target is avx2 alone): a fused multiply-add would round once where the scalar rounds twice.
__attribute__((target("avx2"))) void AlbedoBlurredRatioAvx2(const uint8_t* d, const uint8_t* b, int lo, int count,
                                                            double floor_dn, double* ratio) {
  const double* w = AlbedoBlurWeights();
  const float* table = AlbedoPowerTableValues();
  double sw = 0;
  for (int k = 0; k <= 2 * kAlbedoRadius; ++k) sw += w[k];
  __m256d weight[2 * kAlbedoRadius + 1];
  for (int k = 0; k <= 2 * kAlbedoRadius; ++k) weight[k] = _mm256_set1_pd(w[k]);
  const __m256d vsw = _mm256_set1_pd(sw), vfloor = _mm256_set1_pd(floor_dn), top = _mm256_set1_pd(256.0);
  const __m256d steps = _mm256_set1_pd(kAlbedoPowerSteps);
  for (int j = 0; j < count; j += 4) {
    const uint8_t* bi = b + lo + j - kAlbedoRadius;
    __m256d sv = _mm256_setzero_pd();
    for (int k = 0; k <= 2 * kAlbedoRadius; ++k) sv = _mm256_add_pd(sv, _mm256_mul_pd(weight[k], Bytes4Avx2(bi + k)));
    const __m256d x = _mm256_mul_pd(_mm256_min_pd(_mm256_max_pd(_mm256_div_pd(sv, vsw), vfloor), top), steps);
    const __m128i i = _mm256_cvttpd_epi32(x);
    const __m256d t = _mm256_sub_pd(x, _mm256_cvtepi32_pd(i));
    const __m128 v0 = _mm_i32gather_ps(table, i, 4), v1 = _mm_i32gather_ps(table + 1, i, 4);
    const __m256d inverse = _mm256_add_pd(_mm256_cvtps_pd(v0), _mm256_mul_pd(t, _mm256_cvtps_pd(_mm_sub_ps(v1, v0))));
    _mm256_storeu_pd(ratio + j, _mm256_mul_pd(Bytes4Avx2(d + lo + j), inverse));
  }
}

// ScorePoints (point.cc) of the points [0, n - n % 4), 4 per turn: the same operations in the same order
// as its loop, in double then float lanes, so the same bits (the divisions and square roots, ten per
// point, were its cost: 4 lanes per instruction here). Returns how many points it scored.
__attribute__((target("avx2"))) size_t ScorePointsAvx2(const PointTerms* t, const FrameScale& frame, LinePoint* p,
                                                       size_t n) {
  const __m256d one = _mm256_set1_pd(1.0), zero = _mm256_setzero_pd();
  const __m256d abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffff));
  const __m256d noise_dn = _mm256_set1_pd(frame.noise_dn);
  const __m256d per_snr = _mm256_set1_pd(frame.quality_per_snr), per_contrast = _mm256_set1_pd(frame.quality_per_contrast);
  const __m256d half_threshold = _mm256_set1_pd(0.5 * frame.threshold);
  const __m256d narrow = _mm256_set1_pd(frame.narrow_width), wide = _mm256_set1_pd(frame.wide_width);
  const __m128 onef = _mm_set1_ps(1.0f), halff = _mm_set1_ps(0.5f);
  const bool noisy = frame.noise_dn > 0;
  const size_t whole = n - n % 4;
  for (size_t i = 0; i < whole; i += 4) {
    const __m256d width = _mm256_div_pd(Field(t + i, &PointTerms::width_num), Field(t + i, &PointTerms::width_den));
    const __m256d peak = Field(t + i, &PointTerms::peak);
    const __m256d asymmetry = _mm256_sub_pd(Field(t + i, &PointTerms::column), Field(t + i, &PointTerms::extent_middle));
    const __m256d noise_term = _mm256_mul_pd(_mm256_div_pd(noise_dn, peak),
                                             _mm256_sqrt_pd(_mm256_mul_pd(width, _mm256_set1_pd(1.0 / 12.0))));
    const __m256d ml = _mm256_div_pd(Field(t + i, &PointTerms::left), Field(t + i, &PointTerms::left_n));
    const __m256d mr = _mm256_div_pd(Field(t + i, &PointTerms::right), Field(t + i, &PointTerms::right_n));
    // std::max(1.0, x) is x when 1.0 < x, else 1.0: _mm256_max_pd(x, 1.0) (the second operand otherwise).
    const __m256d texture_term =
        _mm256_div_pd(_mm256_mul_pd(_mm256_mul_pd(_mm256_set1_pd(0.25), width), _mm256_and_pd(abs_mask, _mm256_sub_pd(ml, mr))),
                      _mm256_max_pd(_mm256_add_pd(ml, mr), one));
    const __m256d sum = _mm256_add_pd(
        _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(noise_term, noise_term), _mm256_mul_pd(_mm256_set1_pd(kSpeckleTerm2), width)),
                      _mm256_mul_pd(asymmetry, asymmetry)),
        _mm256_mul_pd(texture_term, texture_term));
    const __m256d uncertainty = _mm256_mul_pd(_mm256_set1_pd(2.0), _mm256_sqrt_pd(sum));
    alignas(16) uint8_t flags[4];
    for (int k = 0; k < 4; ++k) flags[k] = p[i + static_cast<size_t>(k)].flags;
    // std::min(1.0, x) is x when x < 1.0, else 1.0: _mm256_min_pd(x, 1.0).
    __m256d quality = one;
    if (noisy) quality = _mm256_mul_pd(quality, _mm256_min_pd(_mm256_mul_pd(peak, per_snr), one));
    quality = _mm256_mul_pd(quality, _mm256_min_pd(_mm256_mul_pd(_mm256_sub_pd(peak, half_threshold), per_contrast), one));
    quality = ScaleWhere(quality, _mm256_set1_pd(0.6),
                          _mm256_or_pd(_mm256_cmp_pd(width, narrow, _CMP_LT_OQ), _mm256_cmp_pd(width, wide, _CMP_GT_OQ)));
    quality = ScaleWhere(quality, _mm256_set1_pd(0.5), FlagMask(flags, kFlagMultiplePeaks));
    quality = ScaleWhere(quality, _mm256_set1_pd(0.3), FlagMask(flags, kFlagClipped));
    quality = ScaleWhere(quality, _mm256_set1_pd(0.5), FlagMask(flags, kFlagStrongerRejected));
    quality = _mm256_div_pd(quality, _mm256_add_pd(one, _mm256_mul_pd(uncertainty, uncertainty)));
    // std::clamp(q, 0.0, 1.0): q < 0 ? 0 : (1 < q ? 1 : q), by compares (a max would turn -0.0 into 0.0).
    quality = _mm256_blendv_pd(quality, zero, _mm256_cmp_pd(quality, zero, _CMP_LT_OQ));
    quality = _mm256_blendv_pd(quality, one, _mm256_cmp_pd(one, quality, _CMP_LT_OQ));
    // The slope from the neighbouring rows' centres, in float as the loop computes it.
    alignas(16) float here[4], before[4], next[4];
    alignas(16) int32_t up[4], down[4];
    for (size_t k = 0; k < 4; ++k) {
      const size_t j = i + k;
      here[k] = p[j].column;
      before[k] = j > 0 ? p[j - 1].column : 0.0f;
      next[k] = j + 1 < n ? p[j + 1].column : 0.0f;
      up[k] = j > 0 && p[j - 1].row + 1 == p[j].row ? -1 : 0;
      down[k] = j + 1 < n && p[j + 1].row == p[j].row + 1 ? -1 : 0;
    }
    const __m128 h = _mm_load_ps(here), b = _mm_load_ps(before), x = _mm_load_ps(next);
    const __m128 u = _mm_castsi128_ps(_mm_load_si128(reinterpret_cast<const __m128i*>(up)));
    const __m128 d = _mm_castsi128_ps(_mm_load_si128(reinterpret_cast<const __m128i*>(down)));
    __m128 slope = _mm_and_ps(d, _mm_sub_ps(x, h));                               // down only
    slope = _mm_blendv_ps(slope, _mm_sub_ps(h, b), _mm_andnot_ps(d, u));          // up only
    slope = _mm_blendv_ps(slope, _mm_mul_ps(halff, _mm_sub_ps(x, b)), _mm_and_ps(u, d));  // both
    const __m128 grow = _mm_add_ps(onef, _mm_mul_ps(slope, slope));
    alignas(16) float width_f[4], quality_f[4], uncertainty_f[4];
    _mm_store_ps(width_f, _mm256_cvtpd_ps(width));
    _mm_store_ps(quality_f, _mm_div_ps(_mm256_cvtpd_ps(quality), grow));
    _mm_store_ps(uncertainty_f, _mm_mul_ps(_mm256_cvtpd_ps(uncertainty), _mm_sqrt_ps(grow)));
    const int lopsided = _mm256_movemask_pd(
        _mm256_cmp_pd(_mm256_and_pd(abs_mask, asymmetry), _mm256_mul_pd(_mm256_set1_pd(0.25), width), _CMP_GT_OQ));
    for (size_t k = 0; k < 4; ++k) {
      LinePoint& q = p[i + k];
      q.width = width_f[k];
      q.quality = quality_f[k];
      q.uncertainty_px = uncertainty_f[k];
      if ((lopsided >> k) & 1) q.flags = static_cast<uint8_t>(flags[k] | kFlagLopsided);
    }
  }
  return whole;
}

// Four pixels of a row from column c (`step` bytes a pixel) as 32-bit lanes, for the kernels below: read
// whole where columns up to readable_last may be read (a gray row), else one by one; where only n < 4 of
// them are the run's, the lanes from n on are 0 or, read whole, the row's next pixels (the callers mask
// them off).
__attribute__((target("avx2"), always_inline)) static inline __m128i FourPixels(const uint8_t* p, int c, int n,
                                                                                int step, int readable_last) {
  if (step == 1 && c + 3 <= readable_last) {
    int32_t v;
    __builtin_memcpy(&v, p + c, 4);
    return _mm_cvtepu8_epi32(_mm_cvtsi32_si128(v));
  }
  const uint8_t* q = p + static_cast<ptrdiff_t>(c) * step;
  if (n >= 4) return _mm_setr_epi32(q[0], q[step], q[2 * step], q[3 * step]);
  alignas(16) int32_t v4[4] = {0, 0, 0, 0};
  for (int j = 0; j < n; ++j) v4[j] = q[static_cast<ptrdiff_t>(j) * step];
  return _mm_load_si128(reinterpret_cast<const __m128i*>(v4));
}

// AcrossRowSums (kernels_scalar.simd.hpp) over the columns [c, c_last], 4 at a time (the last block's lanes
// past c_last masked off), into 4-lane accumulators acc[0..5] of AcrossSums' six sums: each pixel's tests
// decide as the scalar loop's on the same numbers (IEEE double, no fused multiply-add), and its terms are
// whole numbers, so the lanes' sums and their total are the scalar loop's to the bit in any order. Columns
// up to readable_last may be read (a gray row's last block then takes 4 bytes at once; its lanes past c_last
// are masked off).
// The along test (fourteenth session): |along| > along_px where along = num / L is decided on |num| against
// along_px L (1 -+ kAlongMargin) for each lane, the division made only for a block with a lane within that
// margin of the edge (or NaN), where the rounded quotient might fall on the other side; the quotient's
// rounding is ~1e-16 relative. The across test divides always: decided the same way, once its quotient was
// no longer needed for the sums, it was ~2 % slower (seventeenth session, laser_bench BM_WebcamStep/2/0
// 21.7-22.0 against 22.1-22.4 µs, 3 rounds alternated: a branch there holds back the next block's loads).
constexpr double kAlongMargin = 1e-9;
__attribute__((target("avx2"), always_inline)) static inline void AcrossRowSumsInline(const uint8_t* pa, const uint8_t* pb,
                                                       int step, int c, int c_last, int readable_last, double dr,
                                                       double foot_c, double s, double length,
                                                       double t, double half, double level, int threshold,
                                                       double along_px, int c0, __m256d* acc) {
  const __m256d abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffff));
  const __m256d v_dr = _mm256_set1_pd(dr), v_sdr = _mm256_set1_pd(s * dr), v_s = _mm256_set1_pd(s);
  const __m256d v_foot = _mm256_set1_pd(foot_c), v_length = _mm256_set1_pd(length), v_t = _mm256_set1_pd(t);
  const __m256d v_half = _mm256_set1_pd(half), v_along = _mm256_set1_pd(along_px), v_level = _mm256_set1_pd(level);
  const __m256d v_along_in = _mm256_set1_pd(along_px * length * (1.0 - kAlongMargin));
  const __m256d v_along_out = _mm256_set1_pd(along_px * length * (1.0 + kAlongMargin));
  const __m256d one = _mm256_set1_pd(1.0);
  const __m128i lanes = _mm_setr_epi32(0, 1, 2, 3), full = _mm_set1_epi32(255);
  const __m128i headroom = _mm_set1_epi32(255 - threshold), v_c0 = _mm_set1_epi32(c0);
  for (; c <= c_last; c += 4) {
    const int n = c_last - c + 1;  // columns left: the lanes from n on are no pixel of the row's run
    const __m128i a = FourPixels(pa, c, n, step, readable_last), b = FourPixels(pb, c, n, step, readable_last);
    // LaserDifference: 255 where a saturates over b <= 255 - threshold, else max(a - b, 0).
    const __m128i saturated = _mm_andnot_si128(_mm_cmpgt_epi32(b, headroom), _mm_cmpeq_epi32(a, full));
    const __m128i d = _mm_blendv_epi8(_mm_max_epi32(_mm_sub_epi32(a, b), _mm_setzero_si128()), full, saturated);
    const __m128i ci = _mm_add_epi32(_mm_set1_epi32(c), lanes);
    const __m256d dc = _mm256_sub_pd(_mm256_cvtepi32_pd(ci), v_foot);
    const __m256d along_num = _mm256_add_pd(v_dr, _mm256_mul_pd(v_s, dc));
    const __m256d along_abs = _mm256_and_pd(along_num, abs_mask);
    __m256d along_beyond = _mm256_cmp_pd(along_abs, v_along_out, _CMP_GT_OQ);
    if (_mm256_movemask_pd(_mm256_or_pd(along_beyond, _mm256_cmp_pd(along_abs, v_along_in, _CMP_LT_OQ))) != 0xf) {
      const __m256d along = _mm256_div_pd(along_num, v_length);  // a lane near the edge: as the scalar loop
      along_beyond = _mm256_cmp_pd(_mm256_and_pd(along, abs_mask), v_along, _CMP_GT_OQ);
    }
    const __m256d across_num = _mm256_sub_pd(dc, v_sdr);
    const __m256d across = _mm256_div_pd(across_num, v_length);  // as the scalar loop
    const __m256d across_beyond = _mm256_cmp_pd(_mm256_and_pd(_mm256_sub_pd(across, v_t), abs_mask), v_half, _CMP_GT_OQ);
    const __m256d dd = _mm256_cvtepi32_pd(d);
    const __m256d w = _mm256_sub_pd(dd, v_level);
    // Kept: not (|along| > along_px), not (|across - t| > half), w > 0 (the scalar loop's tests).
    __m256d keep = _mm256_andnot_pd(_mm256_or_pd(along_beyond, across_beyond), _mm256_cmp_pd(w, _mm256_setzero_pd(), _CMP_GT_OQ));
    if (n < 4) keep = _mm256_and_pd(keep, _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm_cmplt_epi32(lanes, _mm_set1_epi32(n)))));
    const __m256d kd = _mm256_and_pd(keep, dd);
    const __m256d cr = _mm256_cvtepi32_pd(_mm_sub_epi32(ci, v_c0));  // the column from c0
    acc[0] = _mm256_add_pd(acc[0], _mm256_and_pd(keep, one));
    acc[1] = _mm256_add_pd(acc[1], kd);
    acc[2] = _mm256_add_pd(acc[2], _mm256_mul_pd(kd, cr));  // +-0 where not kept
    acc[3] = _mm256_add_pd(acc[3], _mm256_and_pd(keep, cr));
    acc[4] = _mm256_add_pd(acc[4], _mm256_mul_pd(kd, v_dr));
    acc[5] = _mm256_add_pd(acc[5], _mm256_and_pd(keep, v_dr));
  }
}

// The accumulators' lanes added into *sums (whole numbers: exact in any order).
__attribute__((target("avx2"))) static void AddAcrossSums(const __m256d* acc, AcrossSums* sums) {
  double* out[6] = {&sums->n, &sums->d, &sums->dc, &sums->c, &sums->ddr, &sums->dr};
  for (int k = 0; k < 6; ++k) {
    alignas(32) double v[4];
    _mm256_store_pd(v, acc[k]);
    *out[k] += (v[0] + v[1]) + (v[2] + v[3]);
  }
}

__attribute__((target("avx2"))) void AcrossRowSumsAvx2(const uint8_t* pa, const uint8_t* pb, int step, int c,
                                                       int c_last, double dr, double foot_c, double s, double length,
                                                       double t, double half, double level, int threshold,
                                                       double along_px, int c0, AcrossSums* sums) {
  __m256d acc[6];
  for (__m256d& x : acc) x = _mm256_setzero_pd();
  AcrossRowSumsInline(pa, pb, step, c, c_last, c_last, dr, foot_c, s, length, t, half, level, threshold, along_px, c0,
                      acc);
  AddAcrossSums(acc, sums);
}

// ends.cc's CentreAcross, one pass over its window (rows [r_first, r_last] of the frames, `channels` bytes a
// pixel, the laser's byte first at on0 / off0): each row's run of columns as ends.cc bounds it (the same
// operations; ceil and floor are exact however they are done), then AcrossRowSumsInline. Here rather than
// in ends.cc so that the bounds' roundings are single instructions and the constants are set once a window.
__attribute__((target("avx2"))) void AcrossWindowSumsAvx2(const uint8_t* on0, size_t on_stride, const uint8_t* off0,
                                                          size_t off_stride, int channels, int cols, int r_first,
                                                          int r_last, int r0, double a, double s, double length,
                                                          double foot_c, double t, double half, double level,
                                                          int threshold, double along_px, int c0, AcrossSums* sums) {
  // The run's along bounds by 1 / s (a column more either side: a column moves along by |s| / L >= 0.7 px
  // on these steep lines, far above the rounding of 1 / s; every pixel of the run is tested itself).
  const double inv_s = 1.0 / s;
  __m256d acc[6];
  for (__m256d& x : acc) x = _mm256_setzero_pd();
  for (int r = r_first; r <= r_last; ++r) {
    const double line = a + s * r;
    const double dr0 = r - r0;
    const double along_a = foot_c + (-dr0 - along_px * length) * inv_s;
    const double along_b = foot_c + (-dr0 + along_px * length) * inv_s;
    const int c_first = std::max({0, static_cast<int>(std::ceil(line + (t - half) * length - 1.0)),
                                  static_cast<int>(std::floor(std::min(along_a, along_b))) - 1});
    const int c_last = std::min({cols - 1, static_cast<int>(std::floor(line + (t + half) * length + 1.0)),
                                 static_cast<int>(std::ceil(std::max(along_a, along_b))) + 1});
    AcrossRowSumsInline(on0 + static_cast<size_t>(r) * on_stride, off0 + static_cast<size_t>(r) * off_stride, channels,
                        c_first, c_last, cols - 1, dr0, foot_c, s, length, t, half, level, threshold, along_px, c0, acc);
  }
  AddAcrossSums(acc, sums);
}

// GapWindowRowAvx2 (kernels.h): the tests on the numerators as gaps.cc's loop makes them, on the same numbers
// (IEEE double, no fused multiply-add); a lane left undecided returns false before anything is added. The
// signed difference a - b (gaps.cc's SignedDifference: 255 - b for a saturated a is a - b), its sums per key
// in 64-bit lanes (whole numbers: exact in any order, as the scalar loop's double sums of them are).
__attribute__((target("avx2"))) bool GapWindowAvx2(const GapSpan* spans, size_t span_count, int step,
                                                   int readable_last, const GapRow& g, int64_t* sums,
                                                   int64_t* counts, GapPixel* near, size_t* near_count) {
  const __m256d abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffff));
  const __m256d zero = _mm256_setzero_pd();
  const __m256d v_c0 = _mm256_set1_pd(g.c0), v_s = _mm256_set1_pd(g.s), v_length = _mm256_set1_pd(g.length);
  const __m256d along_in = _mm256_set1_pd(g.along_in), along_out = _mm256_set1_pd(g.along_out);
  const __m256d normal_min = _mm256_set1_pd(g.normal_min);
  const __m256d e0_in = _mm256_set1_pd(g.edge0_in), e0_out = _mm256_set1_pd(g.edge0_out);
  const __m256d e1_in = _mm256_set1_pd(g.edge1_in), e1_out = _mm256_set1_pd(g.edge1_out);
  const __m256d e2_in = _mm256_set1_pd(g.edge2_in), e2_out = _mm256_set1_pd(g.edge2_out);
  const __m256d com_out = _mm256_set1_pd(g.com_out), noise = _mm256_set1_pd(g.noise_dn);
  const __m128i lanes = _mm_setr_epi32(0, 1, 2, 3);
  __m256i sum[6], count[6];
  for (int k = 0; k < 6; ++k) sum[k] = count[k] = _mm256_setzero_si256();
  size_t kept = *near_count;
  for (size_t j = 0; j < span_count; ++j) {
  const uint8_t* const a = spans[j].a;
  const uint8_t* const b = spans[j].b;
  const int c_last = spans[j].c_last;
  const __m256d v_dr = _mm256_set1_pd(static_cast<double>(spans[j].dr)), v_cc = _mm256_set1_pd(spans[j].cc);
  for (int c = spans[j].c_first; c <= c_last; c += 4) {
    const int n = c_last - c + 1;  // columns left: lanes from n on are masked off
    const __m128i va = FourPixels(a, c, n, step, readable_last), vb = FourPixels(b, c, n, step, readable_last);
    const __m256d valid =
        n >= 4 ? _mm256_castsi256_pd(_mm256_set1_epi64x(-1))
               : _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm_cmplt_epi32(lanes, _mm_set1_epi32(n))));
    const __m256d cd = _mm256_cvtepi32_pd(_mm_add_epi32(_mm_set1_epi32(c), lanes));
    const __m256d x = _mm256_add_pd(_mm256_mul_pd(_mm256_sub_pd(cd, v_c0), v_s), v_dr);
    const __m256d ax = _mm256_and_pd(x, abs_mask);
    const __m256d in = _mm256_and_pd(_mm256_cmp_pd(ax, along_in, _CMP_LT_OQ),
                                     _mm256_or_pd(_mm256_cmp_pd(ax, normal_min, _CMP_GE_OQ),
                                                  _mm256_cmp_pd(ax, zero, _CMP_EQ_OQ)));
    const __m256d out = _mm256_cmp_pd(ax, along_out, _CMP_GT_OQ);
    if (_mm256_movemask_pd(_mm256_andnot_pd(_mm256_or_pd(in, out), valid)) != 0) return false;
    const __m256d near_lanes = _mm256_and_pd(in, valid);
    if (_mm256_movemask_pd(near_lanes) == 0) continue;
    const __m256d y = _mm256_sub_pd(cd, v_cc);
    const __m256d ay = _mm256_and_pd(y, abs_mask);
    const __m256d box0 = _mm256_cmp_pd(ay, e0_in, _CMP_LE_OQ);
    const __m256d none = _mm256_or_pd(_mm256_and_pd(_mm256_cmp_pd(ay, e0_out, _CMP_GE_OQ), _mm256_cmp_pd(ay, e1_in, _CMP_LE_OQ)),
                                      _mm256_cmp_pd(ay, e2_out, _CMP_GE_OQ));
    const __m256d side = _mm256_and_pd(_mm256_cmp_pd(ay, e1_out, _CMP_GE_OQ), _mm256_cmp_pd(ay, e2_in, _CMP_LE_OQ));
    if (_mm256_movemask_pd(_mm256_andnot_pd(_mm256_or_pd(_mm256_or_pd(box0, none), side), near_lanes)) != 0) return false;
    const __m128i d = _mm_sub_epi32(va, vb);
    const __m256d w = _mm256_sub_pd(_mm256_cvtepi32_pd(d), noise);
    const __m256d push = _mm256_andnot_pd(_mm256_cmp_pd(ay, com_out, _CMP_GT_OQ),
                                          _mm256_and_pd(near_lanes, _mm256_cmp_pd(w, zero, _CMP_GT_OQ)));
    if (const int pm = _mm256_movemask_pd(push)) {
      alignas(32) double across[4], weight[4];
      _mm256_store_pd(across, _mm256_div_pd(y, v_length));
      _mm256_store_pd(weight, w);
      for (int k = 0; k < 4; ++k)
        if ((pm >> k) & 1) near[kept++] = {across[k], weight[k]};
    }
    const __m256i d64 = _mm256_cvtepi32_epi64(d);
    const __m256i before = _mm256_castpd_si256(_mm256_and_pd(near_lanes, _mm256_cmp_pd(x, zero, _CMP_LT_OQ)));
    const __m256i after = _mm256_castpd_si256(_mm256_andnot_pd(_mm256_cmp_pd(x, zero, _CMP_LT_OQ), near_lanes));
    const __m256i negative = _mm256_castpd_si256(_mm256_cmp_pd(y, zero, _CMP_LT_OQ));
    const __m256i box[3] = {_mm256_castpd_si256(box0), _mm256_and_si256(_mm256_castpd_si256(side), negative),
                            _mm256_andnot_si256(negative, _mm256_castpd_si256(side))};
    for (int k = 0; k < 3; ++k) {
      const __m256i mb = _mm256_and_si256(box[k], before), ma = _mm256_and_si256(box[k], after);
      sum[k] = _mm256_add_epi64(sum[k], _mm256_and_si256(d64, mb));
      count[k] = _mm256_sub_epi64(count[k], mb);
      sum[k + 3] = _mm256_add_epi64(sum[k + 3], _mm256_and_si256(d64, ma));
      count[k + 3] = _mm256_sub_epi64(count[k + 3], ma);
    }
  }
  }
  for (int k = 0; k < 6; ++k) {
    alignas(32) int64_t s4[4], c4[4];
    _mm256_store_si256(reinterpret_cast<__m256i*>(s4), sum[k]);
    _mm256_store_si256(reinterpret_cast<__m256i*>(c4), count[k]);
    sums[k] += s4[0] + s4[1] + s4[2] + s4[3];
    counts[k] += c4[0] + c4[1] + c4[2] + c4[3];
  }
  *near_count = kept;
  return true;
}

// SteepColumn (kernels_scalar.simd.hpp) with each bin's 8 sums added to as two vectors: the same additions
// in the same order. Each term is a whole number under 2^53 (the caller sees to it: rows and columns under
// 2^20), so exact here and in the scalar loop: d r^2 may be formed as d (r^2) rather than (d r) r, and
// (1, c, r, r^2) row by row by adding (0, 0, 1, 2 r + 1); the same terms, hence the same bits.
__attribute__((target("avx2"), always_inline)) static inline void SteepColumnInline(
    const uint8_t* pa, const uint8_t* pb, size_t a_stride, size_t b_stride, int r_first, int r_last, int threshold,
    int min_d, double u0, double per_row, double bins_per_px, double last_bin, double cc, int base_row,
    double* moments) {
  const double rr0 = r_first - base_row;
  __m256d ones = _mm256_setr_pd(1.0, cc, rr0, rr0 * rr0);  // (1, c, r, r^2) of row r
  __m256d step = _mm256_setr_pd(0.0, 0.0, 1.0, 2.0 * rr0 + 1.0);
  const __m256d step_step = _mm256_setr_pd(0.0, 0.0, 0.0, 2.0);
  const __m128d low = _mm_setzero_pd(), high = _mm_set_sd(last_bin);
  for (int r = r_first; r <= r_last; ++r) {
    const int d = LaserDifference(pa[static_cast<size_t>(r) * a_stride], pb[static_cast<size_t>(r) * b_stride], threshold);
    if (d >= min_d) {
      // std::clamp(u, 0, last_bin) (u is never NaN: the crossing row is a number), then the bin.
      const __m128d u = _mm_set_sd((u0 + r * per_row) * bins_per_px);
      const int64_t b = _mm_cvttsd_si64(_mm_min_sd(_mm_max_sd(u, low), high));
      double* m = moments + 8 * b;
      _mm256_storeu_pd(m, _mm256_add_pd(_mm256_loadu_pd(m), _mm256_mul_pd(_mm256_set1_pd(d), ones)));
      _mm256_storeu_pd(m + 4, _mm256_add_pd(_mm256_loadu_pd(m + 4), ones));
    }
    ones = _mm256_add_pd(ones, step);
    step = _mm256_add_pd(step, step_step);
  }
}
__attribute__((target("avx2"))) void SteepColumnAvx2(const uint8_t* pa, const uint8_t* pb, size_t a_stride,
                                                    size_t b_stride, int r_first, int r_last, int threshold,
                                                    int min_d, double u0, double per_row, double bins_per_px,
                                                    double last_bin, double cc, int base_row, double* moments) {
  SteepColumnInline(pa, pb, a_stride, b_stride, r_first, r_last, threshold, min_d, u0, per_row, bins_per_px, last_bin,
                    cc, base_row, moments);
}

// steep.cc's MeasureRun, its columns [c_first, c_last] (crossing, along, nearest: per column from c_first;
// on0 / off0: the laser's byte of row 0 and column 0): each column's run of rows bounded as there (the same
// operations; ceil and floor are exact however they are done), then its sums as SteepColumnAvx2's. Here so
// that the bounds' roundings are single instructions.
__attribute__((target("avx2"))) void SteepColumnsAvx2(const uint8_t* on0, size_t on_stride, const uint8_t* off0,
                                                     size_t off_stride, int channels, int rows, int c_first,
                                                     int c_last, const double* crossing, const double* along,
                                                     const uint32_t* nearest, const SteepColumnFit* fits,
                                                     int threshold, double shift, double bins_per_px,
                                                     double last_bin, int base_row, double* moments) {
  for (int c = c_first; c <= c_last; ++c) {
    const size_t at = static_cast<size_t>(c - c_first);
    if (std::isnan(crossing[at])) continue;
    const SteepColumnFit& f = fits[nearest[at]];
    const int r_first = std::max(0, static_cast<int>(std::ceil(crossing[at] - f.half_rows)));
    const int r_last = std::min(rows - 1, static_cast<int>(std::floor(crossing[at] + f.half_rows)));
    const double cc = c - c_first;
    const double u0 = along[at] - crossing[at] * f.per_row + shift;
    SteepColumnInline(on0 + static_cast<ptrdiff_t>(c) * channels, off0 + static_cast<ptrdiff_t>(c) * channels,
                      on_stride, off_stride, r_first, r_last, threshold, f.min_d, u0, f.per_row, bins_per_px,
                      last_bin, cc, base_row, moments);
  }
}

}  // namespace rotoscan::laser::detail
#endif  // ROTOSCAN_HAVE_SSSE3_PATH
