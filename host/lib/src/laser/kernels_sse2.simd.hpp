// The extractor's kernels at the x86-64 baseline (SSE2), one of the instruction-set paths that
// kernels.h selects from (kernels_scalar.simd.hpp is the portable one, kernels_avx2.cc and
// kernels_ssse3.cc the ones dispatched at run time). Each function here computes exactly what its namesake
// in kernels_scalar.simd.hpp does. Included only through kernels.h, where __SSE2__ is defined.
#pragma once

#include <emmintrin.h>
#include <xmmintrin.h>

#include <algorithm>
#include <array>
#include <cstdint>

#include "extract_steps.h"

namespace rotoscan::laser::detail::sse2 {

// The centre of mass of d - 0.15 peak over [first, last] (the run above that level). In integers: the
// weights scaled by kComScale, so the sums are exact and the ratio is the same as in real numbers.
inline double CenterOfMassOver(const uint8_t* d, int first, int last, int peak) {
  const int level = kComLevelNum * peak;
  int64_t sum_w = 0, sum_wx = 0;
  int i = first;
  // 8 pixels at a time in 16-bit lanes: w = max(0, 20 d - level) <= 5100 and the offset i - first, their
  // products summed in pairs by madd into 32-bit lanes. Over the first 1024 pixels a lane's sum stays
  // below 5100 * 1024^2 / 2 / 4 < 2^31; a longer run (never a laser line) finishes in the scalar loop.
  // The last group's lanes past `last` are cleared (the row is padded with kPad bytes after its end).
  const __m128i scale = _mm_set1_epi16(kComScale);
  const __m128i lv = _mm_set1_epi16(static_cast<int16_t>(level));
  const __m128i ones = _mm_set1_epi16(1);
  const __m128i lanes = _mm_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7);
  __m128i offset = lanes;
  const __m128i eight = _mm_set1_epi16(8);
  __m128i acc_w = _mm_setzero_si128(), acc_wx = _mm_setzero_si128();
  for (; i <= last && i + 8 - first <= 1024; i += 8) {
    const __m128i v = _mm_unpacklo_epi8(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(d + i)), _mm_setzero_si128());
    const __m128i in_run = _mm_cmpgt_epi16(_mm_set1_epi16(static_cast<int16_t>(std::min(8, last + 1 - i))), lanes);
    const __m128i w =
        _mm_and_si128(in_run, _mm_max_epi16(_mm_sub_epi16(_mm_mullo_epi16(v, scale), lv), _mm_setzero_si128()));
    acc_w = _mm_add_epi32(acc_w, _mm_madd_epi16(w, ones));
    acc_wx = _mm_add_epi32(acc_wx, _mm_madd_epi16(w, offset));
    offset = _mm_add_epi16(offset, eight);
  }
  alignas(16) int32_t lanes_w[4], lanes_wx[4];
  _mm_store_si128(reinterpret_cast<__m128i*>(lanes_w), acc_w);
  _mm_store_si128(reinterpret_cast<__m128i*>(lanes_wx), acc_wx);
  for (int k = 0; k < 4; ++k) {
    sum_w += lanes_w[k];
    sum_wx += int64_t{lanes_wx[k]} + int64_t{lanes_w[k]} * first;
  }
  for (; i <= last; ++i) {
    const int w = std::max(0, kComScale * d[i] - level);
    sum_w += w;
    sum_wx += int64_t{w} * i;
  }
  if (sum_w <= 0) return 0.5 * (first + last);  // a flat run exactly at the level
  return static_cast<double>(sum_wx) / static_cast<double>(sum_w);
}

// How many pixels from `at` on (ExtentRight) or from `at` back (ExtentLeft) in a row are >= min_value
// (1..255), reading 16 at a time. The row must be padded with kPad zero bytes on both sides, which stop
// the scans at the borders.
inline int ExtentRight(const uint8_t* d, int at, int min_value) {
  const __m128i m = _mm_set1_epi8(static_cast<char>(min_value));
  int n = 0;
  for (;;) {
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(d + at + n));
    const unsigned bits = static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(v, m), v)));
    const int ones = __builtin_ctz(~bits);  // bits has 16 bits: ~bits is never 0
    n += ones;
    if (ones < 16) return n;
  }
}
inline int ExtentLeft(const uint8_t* d, int at, int min_value) {
  const __m128i m = _mm_set1_epi8(static_cast<char>(min_value));
  int n = 0;
  for (;;) {
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(d + at - n - 15));
    const unsigned bits = static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(v, m), v)));
    const int ones = __builtin_clz(~(bits << 16));  // leading ones of the 16 bits, from pixel at - n down
    n += ones;
    if (ones < 16) return n;
  }
}

// The largest byte of a vector in all 16 lanes: a butterfly of maxima that never leaves the vector
// registers (MaxByte then _mm_set1_epi8 took the byte to a general register and back, ~8 cycles more on
// the path of every candidate, twice in FillPlateau: laser_bench).
inline __m128i MaxByteAll(__m128i v) {
  v = _mm_max_epu8(v, _mm_shuffle_epi32(v, 0x4e));  // swap the 64-bit halves
  v = _mm_max_epu8(v, _mm_shuffle_epi32(v, 0xb1));  // swap the 32-bit words within them
  v = _mm_max_epu8(v, _mm_or_si128(_mm_slli_epi32(v, 16), _mm_srli_epi32(v, 16)));  // 16-bit halves
  return _mm_max_epu8(v, _mm_or_si128(_mm_slli_epi16(v, 8), _mm_srli_epi16(v, 8)));  // bytes
}

// The highest value of d over [first, last] and the first pixel holding it. The row must be padded with
// kPad zero bytes after its end (the vector loads may run past `last`; those lanes are cleared).
inline PeakInRun FindPeak(const uint8_t* d, int first, int last) {
  const int length = last - first + 1;
  const __m128i lane = _mm_setr_epi8(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  auto load = [&](int k) {  // the 16 pixels from first + k, those past `last` zeroed
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(d + first + k));
    const int remaining = std::min(16, length - k);
    return _mm_and_si128(v, _mm_cmpgt_epi8(_mm_set1_epi8(static_cast<char>(remaining)), lane));
  };
  __m128i best = _mm_setzero_si128();
  for (int k = 0; k < length; k += 16) best = _mm_max_epu8(best, load(k));
  const __m128i target = MaxByteAll(best);
  PeakInRun peak;
  peak.value = _mm_cvtsi128_si32(target) & 0xff;
  for (int k = 0; k < length; k += 16) {
    const unsigned hits = static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(load(k), target)));
    if (hits != 0) {
      peak.position = first + k + __builtin_ctz(hits);
      break;
    }
  }
  return peak;
}

// The lanes k of a 16-byte vector with lo <= k <= hi (either may lie outside 0..15).
inline __m128i LaneRange(int lo, int hi) {
  const __m128i lane = _mm_setr_epi8(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const int l = std::clamp(lo, -1, 16) - 1, h = std::clamp(hi, -1, 16) + 1;
  return _mm_and_si128(_mm_cmpgt_epi8(lane, _mm_set1_epi8(static_cast<char>(l))),
                       _mm_cmpgt_epi8(_mm_set1_epi8(static_cast<char>(h)), lane));
}

// Calls f(p, mask) over [first, last] of a row of `cols` >= 16 pixels, 16 at a time: p is where 16 bytes
// can be read inside the row (the last block is moved back to end at the row's end, so the laser rows a
// and b, which have no padding, are never read past), mask the lanes in [first, last] not yet visited.
template <typename F>
inline void ForRange(int first, int last, int cols, F&& f) {
  for (int s = first; s <= last; s += 16) {
    const int p = std::min(s, cols - 16);
    f(p, LaneRange(s - p, std::min(last, s + 15) - p));
  }
}

// The largest byte of a vector.
inline int MaxByte(__m128i v) {
  v = _mm_max_epu8(v, _mm_srli_si128(v, 8));
  v = _mm_max_epu8(v, _mm_srli_si128(v, 4));
  v = _mm_max_epu8(v, _mm_srli_si128(v, 2));
  v = _mm_max_epu8(v, _mm_srli_si128(v, 1));
  return _mm_cvtsi128_si32(v) & 0xff;
}

// FillPlateau (kernels_scalar.simd.hpp), 16 pixels at a time.
inline PeakInRun FillPlateau(const uint8_t* a, const uint8_t* b, uint8_t* d, int first, int last, int cols,
                             int threshold) {
  if (cols < 16) return scalar::FillPlateau(a, b, d, first, last, cols, threshold);
  const __m128i all = _mm_set1_epi8(-1);
  __m128i plateau = _mm_setzero_si128();  // 255 - b = ~b over the saturated lanes
  __m128i any = _mm_setzero_si128();
  ForRange(first, last, cols, [&](int p, __m128i mask) {
    const __m128i va = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + p));
    const __m128i vb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + p));
    const __m128i saturated = _mm_and_si128(mask, _mm_cmpeq_epi8(va, all));
    plateau = _mm_max_epu8(plateau, _mm_andnot_si128(vb, saturated));
    any = _mm_or_si128(any, saturated);
  });
  if (_mm_movemask_epi8(any) == 0) return FindPeak(d, first, last);  // nothing saturated: nothing to fill
  const __m128i level = MaxByteAll(plateau);
  const __m128i headroom = _mm_set1_epi8(static_cast<char>(255 - threshold));
  // The peak from the filled vectors themselves while the run has at most kKept blocks: reading the row
  // back right after these stores, at other offsets, would wait for each store to land (no forwarding).
  constexpr int kKept = 4;
  __m128i kept[kKept];
  int kept_at[kKept];
  unsigned kept_lanes[kKept];
  int blocks = 0;
  __m128i best = _mm_setzero_si128();
  ForRange(first, last, cols, [&](int p, __m128i mask) {
    const __m128i va = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + p));
    const __m128i vb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + p));
    const __m128i fill = _mm_and_si128(_mm_and_si128(mask, _mm_cmpeq_epi8(va, all)),
                                       _mm_cmpeq_epi8(_mm_max_epu8(vb, headroom), headroom));
    __m128i* at = reinterpret_cast<__m128i*>(d + p);
    const __m128i filled = _mm_or_si128(_mm_andnot_si128(fill, _mm_loadu_si128(at)), _mm_and_si128(fill, level));
    _mm_storeu_si128(at, filled);
    const __m128i in_run = _mm_and_si128(mask, filled);  // the lanes not yet seen, in increasing order
    best = _mm_max_epu8(best, in_run);
    if (blocks < kKept) {
      kept[blocks] = in_run;
      kept_at[blocks] = p;
      kept_lanes[blocks] = static_cast<unsigned>(_mm_movemask_epi8(mask));
    }
    ++blocks;
  });
  if (blocks > kKept) return FindPeak(d, first, last);
  const __m128i target = MaxByteAll(best);
  PeakInRun peak;
  peak.value = _mm_cvtsi128_si32(target) & 0xff;
  for (int k = 0; k < blocks; ++k) {  // the first lane at the peak, blocks in increasing order
    const unsigned hits = kept_lanes[k] & static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(kept[k], target)));
    if (hits != 0) {
      peak.position = kept_at[k] + __builtin_ctz(hits);
      break;
    }
  }
  return peak;
}

// ScanNotch (kernels_scalar.simd.hpp), 16 pixels at a time.
inline NotchScan ScanNotch(const uint8_t* a, const uint8_t* b, int first, int last, int cols) {
  if (cols < 16) return scalar::ScanNotch(a, b, first, last, cols);
  const __m128i all = _mm_set1_epi8(-1);
  __m128i best = _mm_setzero_si128(), worst = all;
  ForRange(first, last, cols, [&](int p, __m128i mask) {
    const __m128i va = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + p));
    const __m128i x = _mm_subs_epu8(va, _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + p)));
    best = _mm_max_epu8(best, _mm_and_si128(mask, x));
    const __m128i saturated = _mm_and_si128(mask, _mm_cmpeq_epi8(va, all));
    worst = _mm_min_epu8(worst, _mm_or_si128(x, _mm_andnot_si128(saturated, all)));
  });
  NotchScan scan;
  scan.best_difference = MaxByte(best);
  scan.worst_saturated = 255 - MaxByte(_mm_xor_si128(worst, all));  // min(x) = 255 - max(255 - x)
  return scan;
}

// MinMaxRange (kernels_scalar.simd.hpp), 16 pixels at a time: the stretch's whole blocks from `first`,
// then one block ending at `last` (overlapping the one before: a minimum and a maximum do not mind), so
// that nothing outside [first, last] is read (b is a frame's row, without padding).
inline ByteRange MinMaxRange(const uint8_t* b, int first, int last) {
  if (last - first + 1 < 16) return scalar::MinMaxRange(b, first, last);
  __m128i low = _mm_set1_epi8(-1), high = _mm_setzero_si128();
  auto take = [&](int at) {
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + at));
    low = _mm_min_epu8(low, v);
    high = _mm_max_epu8(high, v);
  };
  int i = first;
  for (; i + 16 <= last + 1; i += 16) take(i);
  if (i <= last) take(last - 15);
  const __m128i all = _mm_set1_epi8(-1);
  ByteRange range;
  range.high = MaxByte(high);
  range.low = 255 - MaxByte(_mm_xor_si128(low, all));  // min(x) = 255 - max(255 - x)
  return range;
}

// SumRange (kernels_scalar.simd.hpp), 16 pixels at a time.
inline int SumRange(const uint8_t* b, int first, int last, int cols) {
  if (cols < 16) return scalar::SumRange(b, first, last, cols);
  __m128i sum = _mm_setzero_si128();
  ForRange(first, last, cols, [&](int p, __m128i mask) {
    const __m128i vb = _mm_and_si128(mask, _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + p)));
    sum = _mm_add_epi64(sum, _mm_sad_epu8(vb, _mm_setzero_si128()));
  });
  return _mm_cvtsi128_si32(sum) + _mm_cvtsi128_si32(_mm_srli_si128(sum, 8));
}

// SumsAround (kernels_scalar.simd.hpp), 16 pixels at a time, both sums from one pass where middle lies
// in [first, last].
inline SidesSum SumsAround(const uint8_t* b, int first, int middle, int last, int cols) {
  if (cols < 16 || middle < first || middle > last) return scalar::SumsAround(b, first, middle, last, cols);
  __m128i left = _mm_setzero_si128(), right = _mm_setzero_si128();
  ForRange(first, last, cols, [&](int p, __m128i mask) {
    const __m128i vb = _mm_and_si128(mask, _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + p)));
    left = _mm_add_epi64(left, _mm_sad_epu8(_mm_and_si128(vb, LaneRange(-1, middle - 1 - p)), _mm_setzero_si128()));
    right = _mm_add_epi64(right, _mm_sad_epu8(_mm_and_si128(vb, LaneRange(middle + 1 - p, 16)), _mm_setzero_si128()));
  });
  SidesSum sums;
  sums.left = _mm_cvtsi128_si32(left) + _mm_cvtsi128_si32(_mm_srli_si128(left, 8));
  sums.right = _mm_cvtsi128_si32(right) + _mm_cvtsi128_si32(_mm_srli_si128(right, 8));
  return sums;
}

// Step 1 of the row pass (row_pass.cc) from pixel *next on, 16 pixels per instruction: whole 64-pixel
// groups, then the rest in 16-pixel blocks, then one overlapping block whose already-seen bits are
// cleared. Pushes (start, mask) pairs at starts/masks[count...] and returns the new count; *next = cols
// unless the row is narrower than 16 pixels (the portable path does those).
inline int RowGroups(const uint8_t* a, const uint8_t* b, uint8_t* d, int cols, int threshold, int* starts,
                     uint64_t* masks, int count, int* next) {
  auto push = [&](int start, uint64_t mask) {
    starts[count] = start;
    masks[count] = mask;
    count += mask != 0;
  };
  int i0 = *next;
  const __m128i t = _mm_set1_epi8(static_cast<char>(threshold));
  const __m128i headroom = _mm_set1_epi8(static_cast<char>(255 - threshold));
  auto block = [&](int at) -> uint64_t {
    const __m128i va = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + at));
    const __m128i vb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + at));
    // A saturated laser-on pixel over an off pixel with headroom counts as 255 (row_pass.cc).
    const __m128i saturated = _mm_and_si128(_mm_cmpeq_epi8(va, _mm_set1_epi8(-1)),
                                            _mm_cmpeq_epi8(_mm_max_epu8(vb, headroom), headroom));
    const __m128i v = _mm_or_si128(_mm_subs_epu8(va, vb), saturated);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(d + at), v);
    return static_cast<uint32_t>(_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(v, t), v)));
  };
  for (; i0 + 64 <= cols; i0 += 64) {
    push(i0, block(i0) | block(i0 + 16) << 16 | block(i0 + 32) << 32 | block(i0 + 48) << 48);
  }
  if (i0 + 16 <= cols) {
    const int base = i0;
    uint64_t mask = 0;
    for (; i0 + 16 <= cols; i0 += 16) mask |= block(i0) << (i0 - base);
    push(base, mask);
  }
  if (i0 < cols && cols >= 16) {
    const int at = cols - 16;
    push(at, block(at) & ~((uint64_t{1} << (i0 - at)) - 1u));
    i0 = cols;
  }
  *next = i0;
  return count;
}

// The noise estimate's histogram (noise.cc) of one stretch [from, end) of single-channel rows a and b,
// 16 pixels at a time: bins of a - b clamped to [-near, near - 1] plus near, counted into four
// interleaved histograms by pixel index & 3; a pixel whose b is under min_off goes to bin kNoiseDumpBin
// instead (not sampled), and 16 pixels of which none is sampled are passed over without reading a (the
// dump bin's count is never read). Returns where it stopped (noise.cc's per-pixel loop does the rest, and
// every other layout).
inline int NoiseStretch(const uint8_t* a, const uint8_t* b, int from, int end, int near, int min_off,
                        NoiseHistograms* partial) {
  int c = from;
  alignas(16) uint16_t at[16];
  const __m128i zero = _mm_setzero_si128(), offset = _mm_set1_epi16(static_cast<int16_t>(near));
  const __m128i lo = _mm_set1_epi16(static_cast<int16_t>(-near)), hi = _mm_set1_epi16(static_cast<int16_t>(near - 1));
  const __m128i below = _mm_set1_epi16(static_cast<int16_t>(min_off)), dump = _mm_set1_epi16(kNoiseDumpBin);
  const __m128i lowest = _mm_set1_epi8(static_cast<char>(min_off));  // min_off is 0 or kNoiseMinOffDn
  auto bin = [&](__m128i x, __m128i y) {
    const __m128i value = _mm_add_epi16(_mm_min_epi16(_mm_max_epi16(_mm_sub_epi16(x, y), lo), hi), offset);
    const __m128i skip = _mm_cmplt_epi16(y, below);
    return _mm_or_si128(_mm_and_si128(skip, dump), _mm_andnot_si128(skip, value));
  };
  for (; c + 16 <= end; c += 16) {
    const __m128i vb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + c));
    // b >= min_off anywhere (unsigned bytes: max(b, min_off) == b)?
    if (_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(vb, lowest), vb)) == 0) continue;
    const __m128i va = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + c));
    _mm_store_si128(reinterpret_cast<__m128i*>(at), bin(_mm_unpacklo_epi8(va, zero), _mm_unpacklo_epi8(vb, zero)));
    _mm_store_si128(reinterpret_cast<__m128i*>(at + 8), bin(_mm_unpackhi_epi8(va, zero), _mm_unpackhi_epi8(vb, zero)));
    for (int q = 0; q < 16; q += 4) {
      ++(*partial)[0][at[q]];
      ++(*partial)[1][at[q + 1]];
      ++(*partial)[2][at[q + 2]];
      ++(*partial)[3][at[q + 3]];
    }
  }
  return c;
}

// The along-line smoothing's outlier screen (smooth.cc), 4 points at a time: see ScreenWindows in
// kernels_scalar.simd.hpp for the contract.
inline void ScreenWindows(const float* rel, const float* af, const float* bf, int k0, int k1, int h, float limit,
                          uint64_t* bits) {
  const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
  const __m128 lim = _mm_set1_ps(limit);
  for (int k = k0; k < k1; k += 4) {
    const __m128 a = _mm_loadu_ps(af + k), b = _mm_loadu_ps(bf + k);
    __m128 worst = _mm_setzero_ps();
    for (int x = 1; x <= h; ++x) {
      const __m128 xb = _mm_mul_ps(_mm_set1_ps(static_cast<float>(x)), b);
      const __m128 right = _mm_sub_ps(_mm_loadu_ps(rel + k + x), _mm_add_ps(a, xb));
      const __m128 left = _mm_sub_ps(_mm_loadu_ps(rel + k - x), _mm_sub_ps(a, xb));
      worst = _mm_max_ps(_mm_and_ps(abs_mask, right), worst);  // a NaN residual leaves worst as is
      worst = _mm_max_ps(_mm_and_ps(abs_mask, left), worst);
    }
    const uint64_t m = static_cast<uint32_t>(_mm_movemask_ps(_mm_cmpgt_ps(worst, lim)));
    bits[(k - k0) >> 6] |= m << ((k - k0) & 63);
  }
}

// The smoothing's exact outlier test of one point, 2 neighbours at a time: see OutlierBits in
// kernels_scalar.simd.hpp.
inline uint64_t OutlierBits(const float* raw, int i, int h, double a, double b, double outlier_px,
                            const double* window_x) {
  uint64_t bits = 0;
  const __m128d abs_mask = _mm_castsi128_pd(_mm_set1_epi64x(0x7fffffffffffffff));
  const __m128d va = _mm_set1_pd(a), vb = _mm_set1_pd(b), limit = _mm_set1_pd(outlier_px);
  for (int x0 = -h; x0 <= h; x0 += 2) {
    const __m128d fitted = _mm_add_pd(va, _mm_mul_pd(_mm_loadu_pd(window_x + (x0 + h)), vb));
    // Two floats by an unaligned 64-bit load (_mm_load_sd would be a misaligned double).
    const __m128d y = _mm_cvtps_pd(_mm_castsi128_ps(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(raw + i + x0))));
    const __m128d r = _mm_and_pd(abs_mask, _mm_sub_pd(y, fitted));
    bits |= static_cast<uint64_t>(_mm_movemask_pd(_mm_cmpgt_pd(r, limit))) << (x0 + h);
  }
  return bits & (((uint64_t{1} << (2 * h + 1)) - 1) & ~(uint64_t{1} << h));
}

}  // namespace rotoscan::laser::detail::sse2
