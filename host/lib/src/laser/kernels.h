// The extractor's instruction-set paths, OpenCV style: each kernel once per instruction set, in its own
// file, with a dispatcher that picks one.
//  * kernels_scalar.simd.hpp  portable C++: the whole path where the compiler does not target SSE2, and
//                             the tails (a row narrower than a vector) everywhere;
//  * kernels_sse2.simd.hpp    the x86-64 baseline, inlined into the row loop (the candidates' extent, peak
//                             and centre scans run per candidate, so a call each would cost);
//  * kernels_ssse3.cc         dispatched at run time: a color row's channel by byte shuffles;
//  * kernels_avx2.cc          dispatched at run time: the row pass, the smoothing's fits and screens,
//                             the points' scores.
// Which run-time paths are used: HaveSsse3(), HaveAvx2() (dispatch.cc), which the tests can turn off
// (internal::AllowVectorExtensions) to run each path; every path gives the same result bit for bit.
#pragma once

#include <cstdint>

#include "extract_steps.h"

#if defined(__x86_64__) || defined(__i386__)
#define ROTOSCAN_HAVE_SSSE3_PATH 1
#endif

#include "kernels_scalar.simd.hpp"
#if defined(__SSE2__)
#include "kernels_sse2.simd.hpp"
#endif

namespace rotoscan::laser::detail {

// The baseline kernels (see each one's portable definition in kernels_scalar.simd.hpp).
#if defined(__SSE2__)
using sse2::CenterOfMassOver;
using sse2::ExtentLeft;
using sse2::ExtentRight;
using sse2::FillPlateau;
using sse2::FindPeak;
using sse2::MinMaxRange;
using sse2::OutlierBits;
using sse2::ScanNotch;
using sse2::ScreenWindows;
using sse2::SumRange;
using sse2::SumsAround;
#else
using scalar::CenterOfMassOver;
using scalar::ExtentLeft;
using scalar::ExtentRight;
using scalar::FillPlateau;
using scalar::FindPeak;
using scalar::MinMaxRange;
using scalar::OutlierBits;
using scalar::ScanNotch;
using scalar::ScreenWindows;
using scalar::SumRange;
using scalar::SumsAround;
#endif

// OutlierBits of every point k in [k0, k1) of a stretch that the screen flagged (bit k - k0 of
// `flagged`), with the point's first fit a[k] + x b[k], into outliers[k]. `raw` from the stretch start.
inline void FlaggedOutliers(const float* raw, const double* a, const double* b, int k0, int k1, int h,
                            double outlier_px, const uint64_t* flagged, const double* window_x, uint64_t* outliers) {
  for (int w = 0; w <= (k1 - k0 - 1) / 64; ++w) {
    for (uint64_t f = flagged[w]; f != 0; f &= f - 1) {
      const int k = k0 + 64 * w + __builtin_ctzll(f);
      if (k < k1) outliers[k] = OutlierBits(raw, k, h, a[k], b[k], outlier_px, window_x);
    }
  }
}

// gaps.cc's window rows (FillLineGaps, fourteenth session): a pixel of column c of the row is within
// kGapAlongPx along when x = (c - c0) s + dr is, for certain, within along_in (and its sign tells which half),
// and beyond it when x is beyond along_out; its across is y / length, y = c - cc, whose box the edges tell
// (|y| up to edge0_in: the centre box; edge0_out to edge1_in: none; edge1_out to edge2_in: a side box, y's
// sign which; from edge2_out: none); a kept pixel for the centre of mass has weight d - noise_dn > 0 and |y|
// not beyond com_out.
struct GapRow {
  double c0, s, length, along_in, along_out, normal_min;
  double edge0_in, edge0_out, edge1_in, edge1_out, edge2_in, edge2_out, com_out, noise_dn;
};
// A window row: its laser channel's bytes (row start), the curve's column cc in it, its row less the gap row's
// (dr), its columns.
struct GapSpan {
  const uint8_t* a;
  const uint8_t* b;
  double cc;
  int dr, c_first, c_last;
};
struct GapPixel {
  double across, weight;
};
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
// Whether the CPU has the extension and the tests allow it (dispatch.cc).
bool HaveSsse3();
bool HaveAvx2();

// kernels_ssse3.cc: dst[i] = src[i * channels + channel] for i < pixels, channels 3 or 4.
__attribute__((target("ssse3"))) void ChannelRowSsse3(const uint8_t* src, int pixels, int channels, int channel, uint8_t* dst);

// kernels_avx2.cc (declared with the definitions' target attribute, as GCC needs). Step 1 of the row pass over the row's whole 64-pixel groups (see RowGroups):
// returns the number of groups pushed, and in *next where it stopped.
__attribute__((target("avx2"))) int RowGroupsAvx2(const uint8_t* a, const uint8_t* b, uint8_t* d, int cols, int threshold, int* starts,
                  uint64_t* masks, int* next);
// ScreenWindows, 8 points at a time.
__attribute__((target("avx2"))) void ScreenWindowsAvx2(const float* rel, const float* af, const float* bf, int k0, int k1, int h, float limit,
                       uint64_t* bits);
// FlaggedOutliers, 4 neighbours at a time.
__attribute__((target("avx2"))) void FlaggedOutliersAvx2(const float* raw, const double* a, const double* b, int k0, int k1, int h,
                         double outlier_px, const uint64_t* flagged, const double* window_x, uint64_t* outliers);
// SmoothAlongLine's first fits (order 0 or 1) of the points k in [k0, k1) whose window is whole (k0 >= h,
// k1 <= len - h, k1 - k0 a multiple of 4), 4 points per turn: the same operations in the same order as
// its scalar loop (smooth.cc: range_sums, then the whole-window solve), so the same bits. Returns the
// largest |b|.
__attribute__((target("avx2"))) double WholeWindowFitsAvx2(const double* py, const double* pjy, const double* pjjy, int k0, int k1, int h,
                           bool slope, double inv_s0, double inv_s2, double origin, double* fit_a, double* fit_b,
                           float* af, float* bf);
// SmoothAlongLine's fit of a point of a stretch joined across steep steps (smooth.cc, steep_fit; order 0 or 1:
// slope), for the 4 points i4[0..3] of the stretch [start, end], each over its window [max(start, i - h),
// min(end, i + h)] of raw (readable from -h to the stretch's end + h), and again without the neighbours more
// than outlier_px across the line from the first fit where there are such: each point's smoothed column (the
// fit's a) into fit_a[0..3], bit for bit as the scalar fits.
__attribute__((target("avx2"))) void SteepFitsAvx2(const float* raw, const int* i4, int start, int end, int h, bool slope,
                                                   double outlier_px, double* fit_a);
// AlbedoBlurredRatio (point.cc) of the pixels [lo, lo + count), count a multiple of 4, whose blur lies inside
// the row (lo >= kAlbedoRadius, lo + count - 1 + kAlbedoRadius < the row's width), 4 at a time, bit for bit
// as AlbedoBlurredRatioAt: into ratio[0, count).
__attribute__((target("avx2"))) void AlbedoBlurredRatioAvx2(const uint8_t* d, const uint8_t* b, int lo, int count,
                                                            double floor_dn, double* ratio);
// ScorePoints (point.cc) of the points [0, n - n % 4), 4 at a time, bit for bit; returns how many.
__attribute__((target("avx2"))) size_t ScorePointsAvx2(const PointTerms* terms, const FrameScale& frame, LinePoint* points,
                                                       size_t n);
// AcrossRowSums (kernels_scalar.simd.hpp: ends.cc's centre across the line, one row), 4 pixels at a time, the
// same sums (whole numbers) added to *sums.
__attribute__((target("avx2"))) void AcrossRowSumsAvx2(const uint8_t* pa, const uint8_t* pb, int step, int c,
                                                       int c_last, double dr, double foot_c, double s, double length,
                                                       double t, double half, double level, int threshold,
                                                       double along_px, int c0, AcrossSums* sums);
// ends.cc's CentreAcross, one pass over its window (rows [r_first, r_last]; on0, off0 the laser's byte of row
// 0, rows on_stride / off_stride bytes apart, `channels` bytes a pixel): each row's run of columns bounded as
// ends.cc bounds it, then AcrossRowSumsAvx2's sums added to *sums; the same as ends.cc's scalar loop.
__attribute__((target("avx2"))) void AcrossWindowSumsAvx2(const uint8_t* on0, size_t on_stride, const uint8_t* off0,
                                                          size_t off_stride, int channels, int cols, int r_first,
                                                          int r_last, int r0, double a, double s, double length,
                                                          double foot_c, double t, double half, double level,
                                                          int threshold, double along_px, int c0, AcrossSums* sums);
// The pixels of a window's rows (`step` bytes a pixel; columns up to readable_last may be read), 4 at a time:
// the differences of the pixels within kGapAlongPx added to sums[half * 3 + box] (half 0: along < 0) and
// counted in counts[], the kept ones appended to near[*near_count...] (room for each row's columns and 4
// more), all in row and column order. False, with nothing added or counted, where a pixel's test is left
// undecided (within the margins of an edge, or NaN): gaps.cc's scalar loop takes the window then. Bit for
// bit as that loop.
__attribute__((target("avx2"))) bool GapWindowAvx2(const GapSpan* spans, size_t span_count, int step,
                                                   int readable_last, const GapRow& g, int64_t* sums,
                                                   int64_t* counts, GapPixel* near, size_t* near_count);
// steep.cc's MeasureRun over its columns (their crossing rows, along coordinates and nearest fits, from
// c_first), each column's rows bounded as there, then SteepColumnAvx2; bit for bit. A steep fit as it reads
// it (steep.cc's SteepFit): its half width in rows, the along
// coordinate's change per row, the weights' lowest difference.
struct SteepColumnFit {
  double half_rows, per_row;
  int min_d;
};
__attribute__((target("avx2"))) void SteepColumnsAvx2(const uint8_t* on0, size_t on_stride, const uint8_t* off0,
                                                     size_t off_stride, int channels, int rows, int c_first,
                                                     int c_last, const double* crossing, const double* along,
                                                     const uint32_t* nearest, const SteepColumnFit* fits,
                                                     int threshold, double shift, double bins_per_px,
                                                     double last_bin, int base_row, double* moments);
// SteepColumn (kernels_scalar.simd.hpp: steep.cc's pixel sums, one column) with vectors, bit for bit, where
// rows and columns are under 2^20.
__attribute__((target("avx2"))) void SteepColumnAvx2(const uint8_t* pa, const uint8_t* pb, size_t a_stride,
                                                    size_t b_stride, int r_first, int r_last, int threshold,
                                                    int min_d, double u0, double per_row, double bins_per_px,
                                                    double last_bin, double cc, int base_row, double* moments);
#endif

}  // namespace rotoscan::laser::detail
