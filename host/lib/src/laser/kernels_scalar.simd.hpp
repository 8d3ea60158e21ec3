// The extractor's kernels in portable C++, one of the instruction-set paths that kernels.h selects from:
// the whole path where the compiler does not target SSE2, and the tails (rows narrower than a vector)
// everywhere. Each function defines what its namesakes in kernels_sse2.simd.hpp and kernels_avx2.cc
// compute. Included only through kernels.h.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "extract_steps.h"

namespace rotoscan::laser::detail::scalar {

// The centre of mass of d - 0.15 peak over [first, last] (the run above that level). In integers: the
// weights scaled by kComScale, so the sums are exact and the ratio is the same as in real numbers.
inline double CenterOfMassOver(const uint8_t* d, int first, int last, int peak) {
  const int level = kComLevelNum * peak;
  int64_t sum_w = 0, sum_wx = 0;
  for (int i = first; i <= last; ++i) {
    const int w = std::max(0, kComScale * d[i] - level);
    sum_w += w;
    sum_wx += int64_t{w} * i;
  }
  if (sum_w <= 0) return 0.5 * (first + last);  // a flat run exactly at the level
  return static_cast<double>(sum_wx) / static_cast<double>(sum_w);
}

// How many pixels from `at` on (ExtentRight) or from `at` back (ExtentLeft) in a row are >= min_value
// (1..255). The row must be padded with kPad zero bytes on both sides, which stop the scans at the
// borders.
inline int ExtentRight(const uint8_t* d, int at, int min_value) {
  int n = 0;
  while (d[at + n] >= min_value) ++n;
  return n;
}
inline int ExtentLeft(const uint8_t* d, int at, int min_value) {
  int n = 0;
  while (d[at - n] >= min_value) ++n;
  return n;
}

// The highest value of d over [first, last] and the first pixel holding it.
inline PeakInRun FindPeak(const uint8_t* d, int first, int last) {
  PeakInRun peak{d[first], first};
  for (int i = first + 1; i <= last; ++i) {
    if (d[i] > peak.value) peak = {d[i], i};
  }
  return peak;
}

// Step 3's notch filling (candidates.cc) over the run [first, last] of a row of `cols` pixels: the
// saturated laser-on pixels (a == 255) over an off pixel with headroom (b <= 255 - threshold) take the
// run's plateau, the highest 255 - b among the saturated ones. Returns the run's peak afterwards.
inline PeakInRun FillPlateau(const uint8_t* a, const uint8_t* b, uint8_t* d, int first, int last, int /*cols*/,
                             int threshold) {
  int plateau = 0;
  for (int i = first; i <= last; ++i) {
    if (a[i] == 255) plateau = std::max(plateau, 255 - b[i]);
  }
  for (int i = first; i <= last; ++i) {
    if (a[i] == 255 && b[i] <= 255 - threshold) d[i] = static_cast<uint8_t>(plateau);
  }
  return FindPeak(d, first, last);
}

// Step 5's notch test (point.cc) over [first, last]: the highest difference max(a - b, 0), and the lowest
// one among the saturated laser-on pixels (255 when there is none).
inline NotchScan ScanNotch(const uint8_t* a, const uint8_t* b, int first, int last, int /*cols*/) {
  NotchScan scan;
  for (int i = first; i <= last; ++i) {
    const int x = a[i] > b[i] ? a[i] - b[i] : 0;
    scan.best_difference = std::max(scan.best_difference, x);
    if (a[i] == 255) scan.worst_saturated = std::min(scan.worst_saturated, x);
  }
  return scan;
}

// The lowest and highest b[i] over [first, last] (255 and 0 when last < first); reads nothing outside it.
inline ByteRange MinMaxRange(const uint8_t* b, int first, int last) {
  ByteRange range;
  for (int i = first; i <= last; ++i) {
    range.low = std::min(range.low, int{b[i]});
    range.high = std::max(range.high, int{b[i]});
  }
  return range;
}

// The sum of b[i] over [first, last] (0 when last < first) in a row of `cols` pixels.
inline int SumRange(const uint8_t* b, int first, int last, int /*cols*/) {
  int sum = 0;
  for (int i = first; i <= last; ++i) sum += b[i];
  return sum;
}

// The sums of b over [first, middle - 1] and [middle + 1, last] of a row of `cols` pixels (either empty
// when its end is before its start).
inline SidesSum SumsAround(const uint8_t* b, int first, int middle, int last, int cols) {
  return {SumRange(b, first, middle - 1, cols), SumRange(b, middle + 1, last, cols)};
}

// Step 1 of the row pass (row_pass.cc) from pixel *next to the row's end, in 16-pixel groups: d = the
// saturating difference a - b, 255 where a is saturated over a b with headroom (b <= 255 - threshold),
// and per group the bits of d >= threshold, pushed as (start, mask) at starts/masks[count...] when not
// zero. Returns the new count; *next = cols.
inline int RowGroups(const uint8_t* a, const uint8_t* b, uint8_t* d, int cols, int threshold, int* starts,
                     uint64_t* masks, int count, int* next) {
  int i0 = *next;
  for (; i0 < cols; i0 += 16) {
    uint64_t mask = 0;
    for (int k = 0; k < 16 && i0 + k < cols; ++k) {
      const uint8_t x = a[i0 + k], y = b[i0 + k];
      d[i0 + k] = static_cast<uint8_t>(LaserDifference(x, y, threshold));
      mask |= static_cast<uint64_t>(d[i0 + k] >= threshold) << k;
    }
    starts[count] = i0;
    masks[count] = mask;
    count += mask != 0;
  }
  *next = i0;
  return count;
}

// The along-line smoothing's outlier screen (SmoothAlongLine, smooth.cc): for each point k in [k0, k1) of
// a stretch, bit k - k0 of `bits` (zeroed by the caller) is set when some neighbour x in [-h, h], x != 0,
// may lie further than `limit` from the point's first fit af[k] + x bf[k], i.e. |rel[k + x] - af[k] - x
// bf[k]| > limit; NaN entries of rel (outside the stretch) are skipped. All columns relative to the
// stretch's first one. The vector paths take points in groups of 4 (SSE2) or 8 (AVX2): the last group
// computes on up to 7 entries past k1 of af and bf and reads rel up to k1 + h + 6, and may set bits past
// k1 - k0, which the caller ignores. In float, so the caller's limit carries a margin for the rounding and
// each flagged point is decided exactly: the screen's only job is to let the common case (no outlier)
// through with 2 h vector operations per 8 points instead of 2 h scalar tests per point.
inline void ScreenWindows(const float* rel, const float* af, const float* bf, int k0, int k1, int h, float limit,
                          uint64_t* bits) {
  for (int k = k0; k < k1; ++k) {
    bool flagged = false;
    for (int x = 1; x <= h && !flagged; ++x) {
      const float xb = static_cast<float>(x) * bf[k];
      flagged = std::abs(rel[k + x] - (af[k] + xb)) > limit || std::abs(rel[k - x] - (af[k] - xb)) > limit;
    }
    bits[(k - k0) >> 6] |= static_cast<uint64_t>(flagged) << ((k - k0) & 63);
  }
}

// The neighbours x in [-h, h], x != 0, of point i that the fit a + x b leaves further than outlier_px
// from raw[i + x], as bits x + h: in double and in the order of the scalar test std::abs(raw[i + x] -
// (a + x * b)) > outlier_px, so every path sets the same bits. Needs 2h + 1 <= 64, raw readable up to
// i + h + 3 and window_x[k] = k - h for k < 2h + 4.
inline uint64_t OutlierBits(const float* raw, int i, int h, double a, double b, double outlier_px,
                            const double* /*window_x*/) {
  uint64_t bits = 0;
  for (int x = -h; x <= h; ++x) bits |= static_cast<uint64_t>(std::abs(raw[i + x] - (a + x * b)) > outlier_px) << (x + h);
  return bits & (((uint64_t{1} << (2 * h + 1)) - 1) & ~(uint64_t{1} << h));
}


// ends.cc's centre across the line (CentreAcross), one row's share: over the row's columns [c_first, c_last]
// (pa, pb: the frames' row at the laser's channel, a pixel every `step` bytes), the pixels within along_px
// along the line and `half` across it from t, the line column = foot_c + s (row - r0) through the row r0
// + dr, whose weight w = d - level is positive, added to *sums (AcrossSums, extract_steps.h: whole numbers,
// so the same bits in any order; AcrossCentre makes the centre from them).
inline void AcrossRowSums(const uint8_t* pa, const uint8_t* pb, int step, int c_first, int c_last, double dr,
                          double foot_c, double s, double length, double t, double half, double level, int threshold,
                          double along_px, int c0, AcrossSums* sums) {
  for (int c = c_first; c <= c_last; ++c) {
    const double dc = c - foot_c;
    const double along = (dr + s * dc) / length;
    const double across = (dc - s * dr) / length;
    if (std::abs(along) > along_px || std::abs(across - t) > half) continue;
    const int d = LaserDifference(pa[c * step], pb[c * step], threshold);
    if (d - level <= 0) continue;
    const double dd = d, cc = c - c0;
    sums->n += 1;
    sums->d += dd;
    sums->dc += dd * cc;
    sums->c += cc;
    sums->ddr += dd * dr;
    sums->dr += dr;
  }
}

// steep.cc's pixel sums (MeasureRun), one column: over its rows [r_first, r_last] (pa, pb: the frames' pixel
// of the column in row 0, rows a_stride / b_stride bytes apart), the pixels whose difference reaches min_d,
// each into the bin of its along coordinate ((u0 + r per_row) bins_per_px, clamped to [0, last_bin]): its 8
// sums d, d c, d r, d r^2, 1, c, r, r^2 (c = cc, r relative to base_row) at moments[8 b .. 8 b + 8).
inline void SteepColumn(const uint8_t* pa, const uint8_t* pb, size_t a_stride, size_t b_stride, int r_first,
                        int r_last, int threshold, int min_d, double u0, double per_row, double bins_per_px,
                        double last_bin, double cc, int base_row, double* moments) {
  for (int r = r_first; r <= r_last; ++r) {
    const int d = LaserDifference(pa[static_cast<size_t>(r) * a_stride], pb[static_cast<size_t>(r) * b_stride], threshold);
    if (d < min_d) continue;
    const double u = (u0 + r * per_row) * bins_per_px;
    const size_t b = static_cast<size_t>(std::clamp(u, 0.0, last_bin));
    const double dd = d, rr = r - base_row;
    double* m = moments + 8 * b;
    m[0] += dd;
    m[1] += dd * cc;
    m[2] += dd * rr;
    m[3] += dd * rr * rr;
    m[4] += 1;
    m[5] += cc;
    m[6] += rr;
    m[7] += rr * rr;
  }
}

}  // namespace rotoscan::laser::detail::scalar
