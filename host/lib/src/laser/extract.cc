// Laser line extraction: design notes.
//
// The detection threshold T = max(min_contrast_dn, min_snr * noise) comes first, the noise from a sparse
// sample of the frame (EstimateNoise). Then one pass per row, row-major, no allocation per row (the row
// buffer lives in the extractor), the rows a few ahead prefetched so that memory and work overlap:
//  1. d[i] = max(on[i] - off[i], 0) on the laser channel (differential imaging, paper §3.1), 16 pixels
//     per SSE2 instruction, and the bit mask of d >= T per 64-pixel group, groups without a bit dropped.
//     A pixel saturated in the laser-on frame over an off pixel with headroom (off <= 255 - T) counts as
//     255 whatever its difference: on real webcam frames the on frame saturates over a bright texel and
//     the difference dips inside the line (DESIGN.md, the real row `146 145 53 164 44`), which split
//     the line into pieces that failed the width test, so that a weak candidate 8-16 px away won
//     (issue 15). A run holding such pixels then gives them all its plateau (the highest true difference
//     among them) before it is measured (step 3), so the notch is filled and the plateau stays flat.
//  2. No bit in the row: no laser (the common case for rows above and below the object: it costs only
//     step 1, which runs at the memory-bandwidth bound, laser_bench BM_RowPassOnly).
//  3. Otherwise the candidates are the runs of set bits. For each run: its peak p, the half-maximum extent
//     [a, b] around the peak (vector scans), the width at half maximum (edges interpolated linearly), and
//     whether the laser-off frame is saturated under it (a specular highlight that hides the laser).
//     Runs within kMergeGapPx of the previous candidate's half-maximum extent join it (a dark speckle
//     grain or a noise dip inside one line).
//  4. Candidates narrower than min_width (glints, hot pixels) or wider than max_width (ambient blobs) are
//     dropped. Of the others the highest peak wins; a rival within multiple_peak_ratio of it flags the row
//     (kFlagMultiplePeaks), and then the one nearer the previous row's point wins (lines are continuous).
//     The winner is never much weaker (below multiple_peak_ratio) than a rejected candidate unless that
//     one was too narrow (a hot pixel, a glint's core: kFlagStrongerRejected); a much stronger one that
//     was too wide or hidden under a saturated off pixel may be the laser, so the row gets no point
//     (stats.stronger_rejected) rather than a stray one (RealFramesTest.NeverAWeakCandidate...).
//  5. The sub-pixel centre of the winner, by the chosen estimator.
//
// Uncertainty (LinePoint::uncertainty_px, about two standard errors). The centre of mass of a profile of
// width W (px at half maximum) and peak P over noise sigma_n moves by sigma_n / P * sqrt(W / 12) from the
// noise; a multiplicative speckle field of contrast C and grain g px moves it by about C sqrt(g W / 12),
// which for the speckle of our presets and of real webcams (C ~ 0.3, g ~ 1-3 px) is ~0.08 sqrt(W)
// (kSpeckleTerm2); and a lopsided profile (texture across the line, a glint's lobe, an edge) shows as the
// distance between the centre of mass and the middle of the half-maximum extent, which enters whole.
// u = 2 sqrt(noise^2 + speckle^2 + asymmetry^2). The quality is divided by 1 + u^2, so that the points
// of lowest quality are those with the largest expected errors (RenderedLineTest.WebcamQuality...). The
// along-line smoothing moves a point by at most u, and not at all where saturation begins or ends
// between neighbouring rows or where the profile is lopsided (its asymmetry over a quarter of W): there
// the row's own estimate stays (issue 15: on a real bust the smoothing had moved a fifth of the rows by
// 1-2 px from their own centres).
//
// Estimators and the saturated plateau. Real lines are 7-16 px wide and flat-topped (the on-frame clips
// at 255), so any estimator that reads only the brightest pixel and its two neighbours is biased toward
// the first pixel of the plateau. Here:
//  * kCenterOfMass weighs (d - 0.15 p) over the run above 0.15 p around [a, b]: both edges enter
//  symmetrically, the weights vanish at
//    the half-maximum crossings so the estimate is continuous as the line moves, and a plateau is just a
//    flat weight. This is Horus's estimator without its bias (Horus uses the raw intensity over a fixed
//    window around the first maximum, so background and window clipping pull the centre).
//  * kParabolic / kGaussian collapse the plateau [pa, pb] of pixels equal to p to its midpoint and fit
//    the 3-point parabola (of d, or of ln d) through the two neighbours of the plateau. Exact for a narrow
//    Gaussian; for a wide line they see only the plateau edges.
//  * kZeroCrossing finds the zero of the FIR derivative g[i] = d[i+k] - d[i-k] with k = round(width / 2),
//    i.e. the point where the two flanks balance, interpolated linearly.
//
// Choice of the default, by measurement (host/tests/laser/extract_test.cc, EstimatorComparison, prints
// the table): 400 rows per case, pixel-integrated profiles, 1.4 DN noise per frame, 8-bit quantisation,
// random sub-pixel centres; RMS error in px:
//        case                          com    parabolic  gaussian  zero-crossing
//        Gaussian sigma 1.2, 150 DN    0.022  0.032      0.024     0.024
//        flat-top ~12 px, saturated    0.017  3.58       3.58      0.016
//        wide weak (60 DN, sigma 3.5)  0.073  0.85       0.84      0.118
// The 3-point fits fail on the saturated plateau (noise on the off frame leaves a single "brightest"
// pixel anywhere on the flat top) and on wide lines (they only see the top). Zero-crossing and centre of
// mass are both good on plateaus; the centre of mass is clearly better on weak wide lines and as good
// elsewhere, so it is the default.
//
// Along-line smoothing (ExtractOptions::smooth_*, on by default). Laser speckle is a multiplicative
// field correlated over a few pixels in both directions; it tilts the profile of a row, and the centre of
// mass follows the tilt. Neighbouring rows see the same speckle grain, so the error is correlated along
// the line too, over about the speckle size: averaging +-2 rows does little, averaging over a window
// several times the grain does a lot. The surface, in contrast, is smooth along the line except at depth
// edges. So after the rows are extracted, each centre is replaced by a weighted (triangular) local
// least-squares polynomial through the centres of its +-h rows, evaluated at its own row: unbiased for a
// straight or slanted line, biased by ~q * h^2 / 6 for a curved one (q the line's second derivative,
// px/row^2). It never crosses a depth edge or a gap: a stretch ends where a row is missing or the column
// jumps by more than smooth_max_jump_px; and a second fit drops neighbours more than smooth_outlier_px
// from the first (a wrong peak inside a stretch). Peak, width, quality and flags stay those of the row.
// Measured on rendered bundles with the default speckle (rotoscan evaluate --lines; plane-300mm 4 steps,
// spot 6 steps, both lasers), RMS px:
//        smoothing                    plane   spot
//        off                          0.173   0.195
//        +-4 rows, straight line      0.134   0.167
//        +-8 rows, straight line      0.108   0.164
//        +-12 rows, straight line     0.092   0.184   <- default
//        +-16 rows, straight line     0.081   0.217
//        +-12 rows, parabola          0.124   0.161
//        +-16 rows, parabola          0.111   0.162
// The plane (the paper's Table 1 test, and the target <= 0.1 px) needs +-12 rows; on Spot the curvature
// bias of the straight line starts to show beyond +-8 rows while the parabola stays at 0.16: Spot's
// error floor is not speckle alone (its texture changes the albedo across the line, which differencing
// does not remove). +-12 rows straight is the default because it meets the target on the plane and is
// still better than no smoothing on Spot; smooth_order = 2 is the better choice for strongly curved
// objects. (The parabola rows were measured before a fix to the parabola's curvature term, which only
// the outlier test of the second fit reads; SmoothAlongLineTest.MatchesTheDefiningWeightedFit checks
// every order against a direct weighted least-squares fit.)
#include "rotoscan/laser/extract.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#if defined(__SSE2__)
#include <emmintrin.h>
#include <xmmintrin.h>
#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#include <tmmintrin.h>
#endif
#endif

#include "rotoscan/core/check.h"
#include "rotoscan/geometry/image_file.h"

namespace rotoscan::laser {
namespace {

// The centre of mass weighs d - 0.15 * peak over the run above that level. Measured on the
// synthetic cases of EstimatorComparison with levels 0.5, 0.35, 0.25, 0.2, 0.15 and 0.1: below 0.25 the
// wide weak line gains (more pixels average the noise, 0.092 -> 0.073 px) and nothing loses; 0.15 keeps a
// margin of 6 sigma over a 60 DN line's noise floor.
// The level 0.15 as the exact fraction kComLevelNum / kComScale.
constexpr int kComScale = 20;
constexpr int kComLevelNum = 3;

// Runs whose half-maximum extents are at most this far apart are one candidate (step 3).
constexpr int kMergeGapPx = 2;
// The speckle's share of a point's variance per pixel of line width, px^2 (Uncertainty, design notes).
constexpr double kSpeckleTerm2 = 0.08 * 0.08;
// Internal flag of a point whose profile is lopsided (its centre of mass more than a quarter of its
// width from the middle of its half-maximum extent): cleared before the points are returned.
constexpr uint8_t kFlagLopsided = 0x80;

struct Candidate {
  int peak_pos = 0;  // first pixel at the peak value
  int peak = 0;
  int first = 0;  // half-maximum extent, inclusive
  int last = 0;
  // The width at half maximum as the fraction width_num / width_den (width_den > 0): the candidates are
  // judged by it without a division (a division per candidate on the way to every row's decision was the
  // row's slowest step); only the winner's width is divided out.
  int width_num = 0, width_den = 1;
  int com_first = 0, com_last = 0;  // the centre of mass's run (kCenterOfMass only)
  bool off_saturated = false;
  bool WidthWithin(double min_width, double max_width) const {
    return width_num >= min_width * width_den && width_num <= max_width * width_den;
  }
  double Width() const { return static_cast<double>(width_num) / width_den; }
};

// The centre of mass of d - 0.15 peak over [first, last] (the run above that level). In integers: the
// weights scaled by kComScale, so the sums are exact and the ratio is the same as in real numbers.
inline double CenterOfMassOver(const uint8_t* d, int first, int last, int peak) {
  const int level = kComLevelNum * peak;
  int64_t sum_w = 0, sum_wx = 0;
  int i = first;
#if defined(__SSE2__)
  // 8 pixels at a time in 16-bit lanes: w = max(0, 20 d - level) <= 5100 and the offset i - first, their
  // products summed in pairs by madd into 32-bit lanes. Over the first 1024 pixels a lane's sum stays
  // below 5100 * 1024^2 / 2 / 4 < 2^31; a longer run (never a laser line) finishes in the scalar loop.
  const __m128i scale = _mm_set1_epi16(kComScale);
  const __m128i lv = _mm_set1_epi16(static_cast<int16_t>(level));
  const __m128i ones = _mm_set1_epi16(1);
  __m128i offset = _mm_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7);
  const __m128i eight = _mm_set1_epi16(8);
  __m128i acc_w = _mm_setzero_si128(), acc_wx = _mm_setzero_si128();
  for (; i + 8 <= last + 1 && i + 8 - first <= 1024; i += 8) {
    const __m128i v = _mm_unpacklo_epi8(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(d + i)), _mm_setzero_si128());
    const __m128i w = _mm_max_epi16(_mm_sub_epi16(_mm_mullo_epi16(v, scale), lv), _mm_setzero_si128());
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
#endif
  for (; i <= last; ++i) {
    const int w = std::max(0, kComScale * d[i] - level);
    sum_w += w;
    sum_wx += int64_t{w} * i;
  }
  if (sum_w <= 0) return 0.5 * (first + last);  // a flat run exactly at the level
  return static_cast<double>(sum_wx) / static_cast<double>(sum_w);
}

// Zero bytes before and after the row's difference buffer (LineExtractor::diff_).
constexpr int kPad = 16;

// How many pixels from `at` on (ExtentRight) or from `at` back (ExtentLeft) in a row are >= min_value
// (1..255), reading 16 at a time. The row must be padded with kPad zero bytes on both sides, which stop
// the scans at the borders.
inline int ExtentRight(const uint8_t* d, int at, int min_value) {
#if defined(__SSE2__)
  const __m128i m = _mm_set1_epi8(static_cast<char>(min_value));
  int n = 0;
  for (;;) {
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(d + at + n));
    const unsigned bits = static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(v, m), v)));
    const int ones = __builtin_ctz(~bits);  // bits has 16 bits: ~bits is never 0
    n += ones;
    if (ones < 16) return n;
  }
#else
  int n = 0;
  while (d[at + n] >= min_value) ++n;
  return n;
#endif
}
inline int ExtentLeft(const uint8_t* d, int at, int min_value) {
#if defined(__SSE2__)
  const __m128i m = _mm_set1_epi8(static_cast<char>(min_value));
  int n = 0;
  for (;;) {
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(d + at - n - 15));
    const unsigned bits = static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(v, m), v)));
    const int ones = __builtin_clz(~(bits << 16));  // leading ones of the 16 bits, from pixel at - n down
    n += ones;
    if (ones < 16) return n;
  }
#else
  int n = 0;
  while (d[at - n] >= min_value) ++n;
  return n;
#endif
}

// The highest value of d over [first, last] and the first pixel holding it. The row must be padded with
// kPad zero bytes after its end (the vector loads may run past `last`; those lanes are cleared).
struct PeakInRun {
  int value = 0;
  int position = 0;
};
inline PeakInRun FindPeak(const uint8_t* d, int first, int last) {
#if defined(__SSE2__)
  const int length = last - first + 1;
  const __m128i lane = _mm_setr_epi8(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  auto load = [&](int k) {  // the 16 pixels from first + k, those past `last` zeroed
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(d + first + k));
    const int remaining = std::min(16, length - k);
    return _mm_and_si128(v, _mm_cmpgt_epi8(_mm_set1_epi8(static_cast<char>(remaining)), lane));
  };
  __m128i best = _mm_setzero_si128();
  for (int k = 0; k < length; k += 16) best = _mm_max_epu8(best, load(k));
  best = _mm_max_epu8(best, _mm_srli_si128(best, 8));
  best = _mm_max_epu8(best, _mm_srli_si128(best, 4));
  best = _mm_max_epu8(best, _mm_srli_si128(best, 2));
  best = _mm_max_epu8(best, _mm_srli_si128(best, 1));
  PeakInRun peak;
  peak.value = _mm_cvtsi128_si32(best) & 0xff;
  const __m128i target = _mm_set1_epi8(static_cast<char>(peak.value));
  for (int k = 0; k < length; k += 16) {
    const unsigned hits = static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(load(k), target)));
    if (hits != 0) {
      peak.position = first + k + __builtin_ctz(hits);
      break;
    }
  }
  return peak;
#else
  PeakInRun peak{d[first], first};
  for (int i = first + 1; i <= last; ++i) {
    if (d[i] > peak.value) peak = {d[i], i};
  }
  return peak;
#endif
}

// Robust noise sigma of (on - off) from a sparse sample: 1.4826 * MAD, the median interpolated within
// the integer histogram bins so that sub-DN noise is not rounded to 0 or 1.
double EstimateNoise(const cv::Mat& on, const cv::Mat& off, int channel) {
  const int channels = on.channels();
  // 16 rows spread over the frame, in each 4 stretches of 64 pixels spread over the row (the whole row
  // when it is narrower than 256): ~4,000 samples at 1288x964, enough for a MAD to a few percent. The
  // frames are not in the cache yet, so the cost is the cache lines touched: contiguous stretches touch
  // 1 in 5 of the sampled rows' lines (every 4th pixel of whole rows touched them all and was ~13 % of a
  // frame's extraction, laser_bench). Noise fills few bins, so consecutive increments of one histogram
  // would wait on each other's store; four interleaved ones do not.
  const int row_step = std::max(1, on.rows / 16);
  constexpr int kStretch = 64;
  const int stretches = on.cols >= 4 * kStretch ? 4 : 1;
  const int stretch = stretches == 4 ? kStretch : on.cols;
  auto stretch_start = [&](int j) { return stretches == 4 ? (2 * j + 1) * on.cols / 8 - kStretch / 2 : 0; };
  // All the lines are requested first, so that their misses overlap instead of following one another.
  for (int r = row_step / 2; r < on.rows; r += row_step) {
    for (int j = 0; j < stretches; ++j) {
      const size_t from = static_cast<size_t>(stretch_start(j) * channels);
      const size_t to = static_cast<size_t>((stretch_start(j) + stretch) * channels);
      for (size_t k = from; k < to + 64; k += 64) {
        __builtin_prefetch(on.ptr<uint8_t>(r) + std::min(k, to - 1));
        __builtin_prefetch(off.ptr<uint8_t>(r) + std::min(k, to - 1));
      }
    }
  }
  auto interpolated_median = [](const uint32_t* hist, int bins, uint32_t count) {
    const double half = 0.5 * count;
    double cumulative = 0;
    for (int k = 0; k < bins; ++k) {
      if (cumulative + hist[k] >= half && hist[k] > 0) return k - 0.5 + (half - cumulative) / hist[k];
      cumulative += hist[k];
    }
    return static_cast<double>(bins - 1);
  };
  // The differences go into bins of x + near clamped to [-near, near - 1]. First with near = 64: 128 bins
  // to clear, add up and scan instead of 511 (the histogram's passes were most of the estimate's time).
  // The clamp moves only samples beyond +-64 DN; they stay on their side of the median, and of the MAD when
  // the MAD stays short of the clamped edges, so then the result is that of the full histogram. Otherwise
  // (noise of tens of DN) the sample is taken again with near = 256, i.e. without a clamp.
  std::array<std::array<uint32_t, 512>, 4> partial;
  std::array<uint32_t, 512> histogram;
  std::array<uint32_t, 513> deviation;
  for (const int near : {64, 256}) {
    const int bins = 2 * near;
    for (auto& h : partial) std::fill(h.begin(), h.begin() + bins, 0u);
    uint32_t total = 0;
    for (int r = row_step / 2; r < on.rows; r += row_step) {
      const uint8_t* a = on.ptr<uint8_t>(r);
      const uint8_t* b = off.ptr<uint8_t>(r);
      for (int j = 0; j < stretches; ++j) {
        const int from = stretch_start(j);
        int c = from, n = 0;
#if defined(__SSE2__)
        if (channels == 1) {  // the bins of 16 pixels at a time (16-bit lanes), then counted
          alignas(16) uint16_t at[16];
          const __m128i zero = _mm_setzero_si128(), offset = _mm_set1_epi16(static_cast<int16_t>(near));
          const __m128i lo = _mm_set1_epi16(static_cast<int16_t>(-near)), hi = _mm_set1_epi16(static_cast<int16_t>(near - 1));
          auto bin = [&](__m128i x, __m128i y) {
            return _mm_add_epi16(_mm_min_epi16(_mm_max_epi16(_mm_sub_epi16(x, y), lo), hi), offset);
          };
          for (; c + 16 <= from + stretch; c += 16) {
            const __m128i va = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + c));
            const __m128i vb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + c));
            _mm_store_si128(reinterpret_cast<__m128i*>(at), bin(_mm_unpacklo_epi8(va, zero), _mm_unpacklo_epi8(vb, zero)));
            _mm_store_si128(reinterpret_cast<__m128i*>(at + 8), bin(_mm_unpackhi_epi8(va, zero), _mm_unpackhi_epi8(vb, zero)));
            for (int q = 0; q < 16; q += 4) {
              ++partial[0][at[q]];
              ++partial[1][at[q + 1]];
              ++partial[2][at[q + 2]];
              ++partial[3][at[q + 3]];
            }
          }
          n = c - from;
        }
#endif
        for (; c < from + stretch; ++c, ++n) {
          const int k = c * channels + channel;
          const int x = std::clamp(int{a[k]} - int{b[k]}, -near, near - 1);
          ++partial[static_cast<size_t>(n & 3)][static_cast<size_t>(x + near)];
        }
        total += static_cast<uint32_t>(stretch);
      }
    }
    if (total < 16) return 0.0;
    for (int k = 0; k < bins; ++k) histogram[k] = partial[0][k] + partial[1][k] + partial[2][k] + partial[3][k];
    const double median = interpolated_median(histogram.data(), bins, total) - near;
    const int m = static_cast<int>(std::lround(median));
    // Deviations are integers: bin 0 holds |x - m| in [0, 0.5), bin j holds [j - 0.5, j + 0.5).
    std::fill(deviation.begin(), deviation.begin() + bins + 1, 0u);
    for (int k = 0; k < bins; ++k) deviation[static_cast<size_t>(std::abs(k - near - m))] += histogram[k];
    const double mad = std::max(0.0, interpolated_median(deviation.data(), bins + 1, total));
    // Exact when the median's bin and the MAD's lie inside the clamped edges (the edge bins hold
    // everything beyond them).
    const int edge = std::min(near + m, near - 1 - m);  // the clamped edges' deviation
    if (near == 256 || (m > -near && m < near - 1 && std::lround(mad) + 1 < edge)) return 1.4826 * mad;
  }
  return 0.0;  // not reached
}

// The along-line smoothing's outlier screen (SmoothAlongLine): for each point k in [k0, k1) of a stretch,
// bit k - k0 of `bits` (zeroed by the caller) is set when some neighbour x in [-h, h], x != 0, may lie
// further than `limit` from the point's first fit af[k] + x bf[k], i.e. |rel[k + x] - af[k] - x bf[k]|
// > limit; NaN entries of rel (outside the stretch) are skipped. All columns relative to the stretch's
// first one. Points are taken in groups of `lanes` (8 with
// AVX2, 4 with SSE2, 1 otherwise): the last group computes on up to 7 entries past k1 of af and bf and
// reads rel up to k1 + h + 6, and may set bits past k1 - k0, which the caller ignores. In float, so
// the caller's limit carries a margin for the rounding and each flagged point is decided exactly: the
// screen's only job is to let the common case (no outlier) through with 2 h vector operations per 8
// points instead of 2 h scalar tests per point.
void ScreenWindows(const float* rel, const float* af, const float* bf, int k0, int k1, int h, float limit,
                       uint64_t* bits) {
#if defined(__SSE2__)
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
#else
  for (int k = k0; k < k1; ++k) {
    bool flagged = false;
    for (int x = 1; x <= h && !flagged; ++x) {
      const float xb = static_cast<float>(x) * bf[k];
      flagged = std::abs(rel[k + x] - (af[k] + xb)) > limit || std::abs(rel[k - x] - (af[k] - xb)) > limit;
    }
    bits[(k - k0) >> 6] |= static_cast<uint64_t>(flagged) << ((k - k0) & 63);
  }
#endif
}

// The neighbours x in [-h, h], x != 0, of point i that the fit a + x b leaves further than outlier_px
// from raw[i + x], as bits x + h: in double and in the order of the scalar test std::abs(raw[i + x] -
// (a + x * b)) > outlier_px, so every path sets the same bits. Needs 2h + 1 <= 64, raw readable up to
// i + h + 3 and window_x[k] = k - h for k < 2h + 4.
uint64_t OutlierBits(const float* raw, int i, int h, double a, double b, double outlier_px, const double* window_x) {
  uint64_t bits = 0;
#if defined(__SSE2__)
  const __m128d abs_mask = _mm_castsi128_pd(_mm_set1_epi64x(0x7fffffffffffffff));
  const __m128d va = _mm_set1_pd(a), vb = _mm_set1_pd(b), limit = _mm_set1_pd(outlier_px);
  for (int x0 = -h; x0 <= h; x0 += 2) {
    const __m128d fitted = _mm_add_pd(va, _mm_mul_pd(_mm_loadu_pd(window_x + (x0 + h)), vb));
    // Two floats by an unaligned 64-bit load (_mm_load_sd would be a misaligned double).
    const __m128d y = _mm_cvtps_pd(_mm_castsi128_ps(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(raw + i + x0))));
    const __m128d r = _mm_and_pd(abs_mask, _mm_sub_pd(y, fitted));
    bits |= static_cast<uint64_t>(_mm_movemask_pd(_mm_cmpgt_pd(r, limit))) << (x0 + h);
  }
#else
  (void)window_x;
  for (int x = -h; x <= h; ++x) bits |= static_cast<uint64_t>(std::abs(raw[i + x] - (a + x * b)) > outlier_px) << (x + h);
#endif
  return bits & (((uint64_t{1} << (2 * h + 1)) - 1) & ~(uint64_t{1} << h));
}

// OutlierBits of every point k in [k0, k1) of a stretch that the screen flagged (bit k - k0 of
// `flagged`), with the point's first fit a[k] + x b[k], into outliers[k]. `raw` from the stretch start.
void FlaggedOutliers(const float* raw, const double* a, const double* b, int k0, int k1, int h, double outlier_px,
                     const uint64_t* flagged, const double* window_x, uint64_t* outliers) {
  for (int w = 0; w <= (k1 - k0 - 1) / 64; ++w) {
    for (uint64_t f = flagged[w]; f != 0; f &= f - 1) {
      const int k = k0 + 64 * w + __builtin_ctzll(f);
      if (k < k1) outliers[k] = OutlierBits(raw, k, h, a[k], b[k], outlier_px, window_x);
    }
  }
}

// Scratch of the along-line smoothing, per thread (SmoothAlongLine is a free function with a
// public signature; a thread-local buffer keeps it allocation-free from the second frame on).
struct SmoothScratch {
  std::vector<double> prefix;                     // prefix sums and first fits of a stretch
  std::vector<uint64_t> bits;                     // the screen's flags, then outlier bits per point
  std::vector<std::array<double, 3>> cumulative;  // running sums of w, w x, w x^2 over the window
};
SmoothScratch& smooth_scratch() {
  thread_local SmoothScratch scratch;
  return scratch;
}

}  // namespace

const char* EstimatorName(Estimator estimator) {
  switch (estimator) {
    case Estimator::kCenterOfMass: return "com";
    case Estimator::kParabolic: return "parabolic";
    case Estimator::kGaussian: return "gaussian";
    case Estimator::kZeroCrossing: return "zero-crossing";
  }
  return "unknown";
}

Result<Estimator> ParseEstimator(const std::string& name) {
  for (Estimator e :
       {Estimator::kCenterOfMass, Estimator::kParabolic, Estimator::kGaussian, Estimator::kZeroCrossing}) {
    if (name == EstimatorName(e)) return e;
  }
  return InvalidArgumentError("estimator '" + name + "': expected com, parabolic, gaussian or zero-crossing");
}

Result<Channel> ParseChannel(const std::string& name) {
  if (name == "red") return Channel::kRed;
  if (name == "green") return Channel::kGreen;
  if (name == "blue") return Channel::kBlue;
  return InvalidArgumentError("channel '" + name + "': expected red, green or blue");
}

Result<PixelLayout> ParsePixelLayout(const std::string& name) {
  static const std::pair<const char*, PixelLayout> kNames[] = {{"auto", PixelLayout::kAuto},
                                                               {"gray", PixelLayout::kGray},
                                                               {"bgr", PixelLayout::kBgr},
                                                               {"rgb", PixelLayout::kRgb},
                                                               {"bayer-rggb", PixelLayout::kBayerRggb},
                                                               {"bayer-grbg", PixelLayout::kBayerGrbg},
                                                               {"bayer-bggr", PixelLayout::kBayerBggr},
                                                               {"bayer-gbrg", PixelLayout::kBayerGbrg}};
  for (const auto& [n, layout] : kNames) {
    if (name == n) return layout;
  }
  return InvalidArgumentError("pixel layout '" + name +
                              "': expected auto, gray, bgr, rgb or bayer-rggb/grbg/bggr/gbrg");
}

Status ExtractOptions::Check() const {
  auto bad = [](const std::string& field, const std::string& why) {
    return InvalidArgumentError("extract options: " + field + " " + why);
  };
  if (!(min_contrast_dn >= 1.0 && min_contrast_dn <= 255.0))
    return bad("min_contrast_dn", "must be in [1, 255]");
  if (!(min_snr >= 0.0 && std::isfinite(min_snr))) return bad("min_snr", "must be >= 0");
  if (!std::isfinite(noise_dn)) return bad("noise_dn", "must be finite");
  if (!(min_width_px >= 0.0 && max_width_px > min_width_px && std::isfinite(max_width_px))) {
    return bad("min_width_px/max_width_px", "must satisfy 0 <= min < max");
  }
  if (!(multiple_peak_ratio > 0.0 && multiple_peak_ratio <= 1.0))
    return bad("multiple_peak_ratio", "must be in (0, 1]");
  if (off_saturation_dn < 1 || off_saturation_dn > 256)
    return bad("off_saturation_dn", "must be in [1, 256]");
  if (smooth_half_rows < 0 || smooth_half_rows > 64) return bad("smooth_half_rows", "must be in [0, 64]");
  if (smooth_order < 0 || smooth_order > 2) return bad("smooth_order", "must be 0, 1 or 2");
  if (!(smooth_max_jump_px > 0.0 && std::isfinite(smooth_max_jump_px)))
    return bad("smooth_max_jump_px", "must be > 0");
  if (!(smooth_outlier_px > 0.0 && std::isfinite(smooth_outlier_px)))
    return bad("smooth_outlier_px", "must be > 0");
  return Status::Ok();
}

double EstimateCentre(Estimator estimator, const uint8_t* d, int size, int first, int last, int peak) {
  ROTOSCAN_CHECK(first >= 0 && last < size && first <= last) << "run [" << first << ", " << last << "]";
  switch (estimator) {
    case Estimator::kCenterOfMass: {
      const int level = kComLevelNum * peak;
      while (first > 0 && kComScale * d[first - 1] > level) --first;
      while (last < size - 1 && kComScale * d[last + 1] > level) ++last;
      return CenterOfMassOver(d, first, last, peak);
    }
    case Estimator::kParabolic:
    case Estimator::kGaussian: {
      int pa = first;
      while (pa <= last && d[pa] != peak) ++pa;
      if (pa > last) return -1.0;
      int pb = pa;
      while (pb + 1 <= last && d[pb + 1] == peak) ++pb;
      const double mid = 0.5 * (pa + pb);
      if (pa == 0 || pb == size - 1) return mid;
      double l = d[pa - 1], c = peak, r = d[pb + 1];
      if (estimator == Estimator::kGaussian) {
        l = std::log(std::max(l, 0.5));
        c = std::log(std::max(c, 0.5));
        r = std::log(std::max(r, 0.5));
      }
      const double denominator = l - 2 * c + r;
      if (denominator >= 0) return mid;
      const double delta = 0.5 * (l - r) / denominator;
      return mid + std::clamp(delta, -0.5, 0.5);
    }
    case Estimator::kZeroCrossing: {
      const int k = std::max(1, static_cast<int>(std::lround(0.5 * (last - first + 1))));
      auto g = [&](int i) {
        const int hi = std::min(i + k, size - 1);
        const int lo = std::max(i - k, 0);
        return int{d[hi]} - int{d[lo]};
      };
      // g is positive on the rising flank and negative on the falling one; find the crossing nearest
      // the middle of the run.
      const double mid = 0.5 * (first + last);
      double best = -1.0;
      for (int i = first - 1; i <= last; ++i) {
        if (i < 0 || i + 1 >= size) continue;
        const int gi = g(i);
        if (gi <= 0) continue;
        int j = i + 1;
        while (j <= last + 1 && j < size && g(j) == 0) ++j;
        if (j >= size || g(j) >= 0) continue;
        const double x = (j == i + 1) ? i + static_cast<double>(gi) / (gi - g(j)) : 0.5 * (i + j);
        if (best < 0 || std::abs(x - mid) < std::abs(best - mid)) best = x;
      }
      return best;
    }
  }
  return -1.0;
}

LineExtractor::LineExtractor(const ExtractOptions& options) : options_(options) {
  const Status status = options_.Check();
  ROTOSCAN_CHECK(status.ok()) << status.ToString();
}

Status LineExtractor::Extract(const cv::Mat& on, const cv::Mat& off, Line* line) {
  ROTOSCAN_CHECK(line != nullptr);
  if (on.empty() || off.empty()) return InvalidArgumentError("empty image (laser-on or laser-off frame)");
  if (on.size() != off.size()) {
    return InvalidArgumentError("image sizes differ: laser-on " + std::to_string(on.cols) + "x" +
                                std::to_string(on.rows) + ", laser-off " + std::to_string(off.cols) + "x" +
                                std::to_string(off.rows));
  }
  if (on.type() != off.type()) return InvalidArgumentError("laser-on and laser-off images differ in type");
  if (on.depth() != CV_8U) return InvalidArgumentError("only 8-bit images are supported");
  const int channels = on.channels();
  PixelLayout layout = options_.layout;
  if (layout == PixelLayout::kAuto) {
    if (channels == 1) {
      layout = PixelLayout::kGray;
    } else if (channels == 3 || channels == 4) {
      layout = PixelLayout::kBgr;
    } else {
      return InvalidArgumentError("unsupported channel count " + std::to_string(channels));
    }
  }
  const bool bayer = layout == PixelLayout::kBayerRggb || layout == PixelLayout::kBayerGrbg ||
                     layout == PixelLayout::kBayerBggr || layout == PixelLayout::kBayerGbrg;
  if ((layout == PixelLayout::kGray || bayer) && channels != 1) {
    return InvalidArgumentError("a gray or Bayer layout needs single-channel images, got " +
                                std::to_string(channels) + " channels");
  }
  if ((layout == PixelLayout::kBgr || layout == PixelLayout::kRgb) && channels != 3 && channels != 4) {
    return InvalidArgumentError("a color layout needs 3 or 4 channels, got " + std::to_string(channels));
  }
  if (layout == PixelLayout::kGray) return ExtractFromChannel(on, off, line);

  const cv::Mat* on_color = &on;
  const cv::Mat* off_color = &off;
  if (bayer) {
    // OpenCV names Bayer patterns by the second row's start; RGGB raw is COLOR_BayerBG2BGR.
    int code = cv::COLOR_BayerBG2BGR;
    if (layout == PixelLayout::kBayerGrbg) code = cv::COLOR_BayerGB2BGR;
    if (layout == PixelLayout::kBayerBggr) code = cv::COLOR_BayerRG2BGR;
    if (layout == PixelLayout::kBayerGbrg) code = cv::COLOR_BayerGR2BGR;
    cv::cvtColor(on, on_bgr_, code);
    cv::cvtColor(off, off_bgr_, code);
    on_color = &on_bgr_;
    off_color = &off_bgr_;
    layout = PixelLayout::kBgr;
  }
  int index = 2;  // red in BGR
  if (options_.channel == Channel::kGreen) index = 1;
  if (options_.channel == Channel::kBlue) index = 0;
  if (layout == PixelLayout::kRgb) index = 2 - index;
  return ExtractRows(*on_color, *off_color, index, line);
}

Status LineExtractor::ExtractFromChannel(const cv::Mat& on_channel, const cv::Mat& off_channel, Line* line) {
  ROTOSCAN_CHECK(line != nullptr);
  if (on_channel.empty() || on_channel.size() != off_channel.size() || on_channel.type() != CV_8UC1 ||
      off_channel.type() != CV_8UC1) {
    return InvalidArgumentError("laser channel images must be non-empty, single-channel 8-bit, same size");
  }
  return ExtractRows(on_channel, off_channel, 0, line);
}

// Color input (3 or 4 interleaved channels): on x86 with SSSE3 each row's laser channel is pulled out
// with byte shuffles into a row buffer (ChannelRowSsse3: 16 pixels from 3 or 4 loads, 3 or 4 shuffles),
// so the frames are read once and nothing else is written. Elsewhere the frames are read in bands of
// kBandRows rows that OpenCV's vectorised cv::split deinterleaves into small buffers in the L2 cache
// (cv::extractChannel goes through the generic, scalar mixChannels: 3x slower). laser_bench
// BM_ExtractBgr: split bands 673 µs, shuffles see README.
constexpr int kBandRows = 32;
// The row pass asks for the row this many rows ahead: the hardware prefetcher alone left the per-row
// work waiting on memory (laser_bench, smoothed, measured on a busy machine: no prefetch ~220 µs per frame,
// 2-4 rows ahead ~170 µs, 1 or 8 rows ~180-190 µs).
constexpr int kPrefetchRows = 3;

#if defined(__x86_64__) || defined(__i386__)
#define ROTOSCAN_HAVE_SSSE3_PATH 1
namespace {
// dst[i] = src[i * channels + channel] for i < pixels, channels 3 or 4.
__attribute__((target("ssse3"))) void ChannelRowSsse3(const uint8_t* src, int pixels, int channels, int channel,
                                                       uint8_t* dst) {
  // Shuffle k takes from the k-th 16 source bytes the lanes of pixels 0..15 that lie there.
  alignas(16) uint8_t masks[4][16];
  for (int k = 0; k < 4; ++k) {  // all four (the fourth is unused for 3 channels)
    for (int lane = 0; lane < 16; ++lane) {
      const int at = lane * channels + channel - 16 * k;
      masks[k][lane] = at >= 0 && at < 16 ? static_cast<uint8_t>(at) : 0x80;
    }
  }
  const __m128i m0 = _mm_load_si128(reinterpret_cast<const __m128i*>(masks[0]));
  const __m128i m1 = _mm_load_si128(reinterpret_cast<const __m128i*>(masks[1]));
  const __m128i m2 = _mm_load_si128(reinterpret_cast<const __m128i*>(masks[2]));
  const __m128i m3 = _mm_load_si128(reinterpret_cast<const __m128i*>(masks[3]));
  const int bytes = 16 * channels;
  int i = 0;
  for (; i + 16 <= pixels; i += 16, src += bytes) {
    const __m128i* v = reinterpret_cast<const __m128i*>(src);
    __m128i out = _mm_or_si128(_mm_shuffle_epi8(_mm_loadu_si128(v), m0),
                               _mm_or_si128(_mm_shuffle_epi8(_mm_loadu_si128(v + 1), m1),
                                            _mm_shuffle_epi8(_mm_loadu_si128(v + 2), m2)));
    if (channels == 4) out = _mm_or_si128(out, _mm_shuffle_epi8(_mm_loadu_si128(v + 3), m3));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(dst + i), out);
  }
  for (int k = 0; i < pixels; ++i, ++k) dst[i] = src[k * channels + channel];
}

// Step 1 of the row pass (see ExtractRows) over the row's whole 64-pixel groups, 32 pixels per
// instruction; returns the number of groups pushed and where it stopped.
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

// The along-line smoothing's outlier screen (SmoothAlongLine), 8 points at a time: ScreenWindows.
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

// OutlierBits, 4 neighbours at a time.
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
// FlaggedOutliers with OutlierBitsAvx2.
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

std::atomic<bool> allow_avx2{true}, allow_ssse3{true};

bool HaveSsse3() {
  static const bool have = __builtin_cpu_supports("ssse3");
  return have && allow_ssse3.load(std::memory_order_relaxed);
}
bool HaveAvx2() {
  static const bool have = __builtin_cpu_supports("avx2");
  return have && allow_avx2.load(std::memory_order_relaxed);
}
}  // namespace
#endif

namespace internal {
void AllowVectorExtensions(bool avx2, bool ssse3) {
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  allow_avx2.store(avx2);
  allow_ssse3.store(ssse3);
#else
  (void)avx2;
  (void)ssse3;
#endif
}
bool UseAvx2() {
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  return HaveAvx2();
#else
  return false;
#endif
}
}  // namespace internal

Status LineExtractor::ExtractRows(const cv::Mat& on, const cv::Mat& off, int channel, Line* line) {
  const ExtractOptions& o = options_;
  const int rows = on.rows;
  const int cols = on.cols;
  const int channels = on.channels();
  bool shuffled = false;  // color rows through ChannelRowSsse3
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  shuffled = channels > 1 && HaveSsse3();
  if (shuffled) {
    on_row_.resize(static_cast<size_t>(cols));
    off_row_.resize(static_cast<size_t>(cols));
  }
#endif
  const bool banded = channels > 1 && !shuffled;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  const bool avx2 = HaveAvx2();  // the row pass 32 pixels at a time
#endif
  line->points.clear();
  line->stats = LineStats{};
  LineStats& stats = line->stats;
  stats.rows = rows;
  stats.noise_dn = o.noise_dn > 0 ? o.noise_dn : EstimateNoise(on, off, channel);
  const double threshold_real = std::max(o.min_contrast_dn, o.min_snr * stats.noise_dn);
  const int threshold = static_cast<int>(std::ceil(std::min(threshold_real, 255.0)));
  stats.threshold_dn = threshold;
  // The row's difference with kPad zero bytes on either side, so that the extent scans below can read
  // whole vectors at the borders and stop there.
  diff_.assign(static_cast<size_t>(cols) + 2 * kPad, 0);
  block_starts_.resize(static_cast<size_t>(cols) / 16 + 3);
  block_masks_.resize(static_cast<size_t>(cols) / 16 + 3);
  uint8_t* d = diff_.data() + kPad;

  // The quality's factors (step 5), per frame.
  const double quality_per_snr = stats.noise_dn > 0 ? 1.0 / (stats.noise_dn * std::max(1.0, 4 * o.min_snr)) : 0.0;
  const double quality_per_contrast = 1.0 / std::max(1.0, 2.0 * threshold);
  const double narrow_width = 1.5 * o.min_width_px, wide_width = o.max_width_px / 1.5;

  // Both frames' row kPrefetchRows ahead of row r, read from memory while row r is worked on.
  auto prefetch_ahead = [&](int r) {
    if (r + kPrefetchRows >= rows) return;
    const char* pa = reinterpret_cast<const char*>(on.ptr<uint8_t>(r + kPrefetchRows));
    const char* pb = reinterpret_cast<const char*>(off.ptr<uint8_t>(r + kPrefetchRows));
    for (int k = 0; k < cols * channels; k += 64) {
      __builtin_prefetch(pa + k);
      __builtin_prefetch(pb + k);
    }
  };

  const bool centre_of_mass = o.estimator == Estimator::kCenterOfMass;
  std::array<Candidate, 32> candidates;
  double previous_column = -1.0;
  int previous_row = -10;
  for (int r = 0; r < rows; ++r) {
    const uint8_t* a;
    const uint8_t* b;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
    if (shuffled) {
      prefetch_ahead(r);
      ChannelRowSsse3(on.ptr<uint8_t>(r), cols, channels, channel, on_row_.data());
      ChannelRowSsse3(off.ptr<uint8_t>(r), cols, channels, channel, off_row_.data());
      a = on_row_.data();
      b = off_row_.data();
    } else
#endif
    if (banded) {
      if (r % kBandRows == 0) {
        const cv::Range band(r, std::min(rows, r + kBandRows));
        cv::split(on.rowRange(band), on_planes_);
        cv::split(off.rowRange(band), off_planes_);
      }
      a = on_planes_[static_cast<size_t>(channel)].ptr<uint8_t>(r % kBandRows);
      b = off_planes_[static_cast<size_t>(channel)].ptr<uint8_t>(r % kBandRows);
    } else {
      a = on.ptr<uint8_t>(r);
      b = off.ptr<uint8_t>(r);
      prefetch_ahead(r);
    }
    // Step 1: saturating difference, and the 64-pixel groups that hold a pixel >= threshold, compacted
    // into (start, bit mask) pairs without a branch. Nothing else is read per pixel, so a row without
    // the laser costs two loads and five vector instructions per 16 pixels and one compaction per 64 (the
    // loop runs at the memory-bandwidth bound, laser_bench BM_RowPassOnly). A width that is not a
    // multiple of 16 ends with one overlapping block whose already-seen bits are cleared.
    int block_count = 0;
    {
      int* starts = block_starts_.data();
      uint64_t* masks = block_masks_.data();
      auto push = [&](int start, uint64_t mask) {
        starts[block_count] = start;
        masks[block_count] = mask;
        block_count += mask != 0;
      };
      int i0 = 0;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
      if (avx2) block_count = RowGroupsAvx2(a, b, d, cols, threshold, starts, masks, &i0);
#endif
#if defined(__SSE2__)
      const __m128i t = _mm_set1_epi8(static_cast<char>(threshold));
      const __m128i headroom = _mm_set1_epi8(static_cast<char>(255 - threshold));
      auto block = [&](int at) -> uint64_t {
        const __m128i va = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + at));
        const __m128i vb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + at));
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
#endif
      for (; i0 < cols; i0 += 16) {  // portable path (and images narrower than 16 pixels)
        uint64_t mask = 0;
        for (int k = 0; k < 16 && i0 + k < cols; ++k) {
          const uint8_t x = a[i0 + k], y = b[i0 + k];
          d[i0 + k] = static_cast<uint8_t>(x == 255 && y <= 255 - threshold ? 255 : x > y ? x - y : 0);
          mask |= static_cast<uint64_t>(d[i0 + k] >= threshold) << k;
        }
        push(i0, mask);
      }
    }
    if (block_count == 0) {  // step 2: no pixel reaches the threshold
      ++stats.low_contrast;
      continue;
    }
    // Step 3: candidates = runs of d >= threshold, found from the set bits of the blocks alone.
    int count = 0;
    auto add_run = [&](int run_first, int run_last) __attribute__((always_inline)) {
      if (count >= static_cast<int>(candidates.size())) return;
      Candidate& c = candidates[static_cast<size_t>(count)];
      PeakInRun found = FindPeak(d, run_first, run_last);
      if (found.value == 255) {
        // Saturated laser-on pixels were set to 255 by step 1 (a notch cannot split the line); their
        // difference is clipped, so they all take the run's highest true difference among them, the
        // plateau a saturated line has (DESIGN.md), and the candidate is measured on that.
        int plateau = 0;
        for (int i = run_first; i <= run_last; ++i) {
          if (a[i] == 255) plateau = std::max(plateau, 255 - b[i]);
        }
        for (int i = run_first; i <= run_last; ++i) {
          if (a[i] == 255 && b[i] <= 255 - threshold) d[i] = static_cast<uint8_t>(plateau);
        }
        found = FindPeak(d, run_first, run_last);
      }
      c.peak_pos = found.position;
      c.peak = found.value;
      // The half-maximum extent: d >= peak / 2, i.e. d >= ceil(peak / 2) for integers.
      const int lo = c.peak_pos - ExtentLeft(d, c.peak_pos - 1, (c.peak + 1) / 2);
      const int hi = c.peak_pos + ExtentRight(d, c.peak_pos + 1, (c.peak + 1) / 2);
      c.first = lo;
      c.last = hi;
      if (centre_of_mass) {
        // The centre of mass's run (d > 0.15 peak, i.e. d >= 3 peak / 20 + 1 in integers) around the peak:
        // it holds the half-maximum extent, and scanning it from the peak rather than from the extent's
        // ends lets it run beside the width's steps instead of after the decision.
        const int level_min = kComLevelNum * c.peak / kComScale + 1;
        c.com_first = c.peak_pos - ExtentLeft(d, c.peak_pos - 1, level_min);
        c.com_last = c.peak_pos + ExtentRight(d, c.peak_pos + 1, level_min);
      }
      // The width at half maximum: between the crossings of peak / 2, each interpolated linearly between
      // the extent's end pixel and the next one out (at the image's border half a pixel out), i.e.
      // (hi + 1 - n_r / d_r) - (lo - 1 + n_l / d_l) with n = peak / 2 - d(next out) and d = d(end) -
      // d(next out), in integers as (hi - lo + 2) - (2 n_l d_r + 2 n_r d_l) / (2 d_l d_r). The extent ends
      // where d drops below ceil(peak / 2) >= peak / 2, so both d are positive.
      int nl2 = 2, dl = 2, nr2 = 2, dr = 2;  // n doubled
      if (lo > 0) {
        nl2 = c.peak - 2 * d[lo - 1];
        dl = d[lo] - d[lo - 1];
      }
      if (hi < cols - 1) {
        nr2 = c.peak - 2 * d[hi + 1];
        dr = d[hi] - d[hi + 1];
      }
      c.width_den = 2 * dl * dr;
      c.width_num = (hi - lo + 2) * c.width_den - (nl2 * dr + nr2 * dl);
      c.off_saturated = b[c.peak_pos] >= o.off_saturation_dn;
      // A run inside, or within kMergeGapPx of, the half-maximum extent of the previous candidate is the
      // same line (a noise dip, a dark speckle grain): one candidate over both extents.
      if (count > 0 && candidates[static_cast<size_t>(count - 1)].last + kMergeGapPx >= lo) {
        Candidate& prev = candidates[static_cast<size_t>(count - 1)];
        if (prev.last >= lo && hi <= prev.last) {  // wholly inside: the higher peak's candidate
          if (c.peak > prev.peak) prev = c;
          return;
        }
        const Candidate higher = c.peak > prev.peak ? c : prev;
        const int first = std::min(prev.first, lo), last = std::max(prev.last, hi);
        const int com_first = std::min(prev.com_first, c.com_first), com_last = std::max(prev.com_last, c.com_last);
        prev = higher;
        prev.first = first;
        prev.last = last;
        prev.com_first = com_first;
        prev.com_last = com_last;
        prev.width_num = last - first + 1;
        prev.width_den = 1;
        return;
      }
      ++count;
    };
    int run_start = -1, run_last = -2;
    for (int k = 0; k < block_count; ++k) {
      const int base = block_starts_[static_cast<size_t>(k)];
      uint64_t mask = block_masks_[static_cast<size_t>(k)];
      while (mask != 0) {  // one turn per run of set bits, not per bit
        const int from = __builtin_ctzll(mask);
        const uint64_t rest = ~(mask >> from);
        const int length = rest != 0 ? __builtin_ctzll(rest) : 64 - from;
        mask = length + from >= 64 ? 0 : mask & (~uint64_t{0} << (from + length));
        const int j = base + from;
        if (j != run_last + 1) {
          if (run_start >= 0) add_run(run_start, run_last);
          run_start = j;
        }
        run_last = j + length - 1;
      }
    }
    add_run(run_start, run_last);

    // Step 4: plausibility.
    int best = -1, strongest = 0;
    bool any_off_saturated = false;
    for (int k = 0; k < count; ++k) {
      const Candidate& c = candidates[static_cast<size_t>(k)];
      if (c.peak > candidates[static_cast<size_t>(strongest)].peak) strongest = k;
      if (c.off_saturated) {
        any_off_saturated = true;
        continue;
      }
      if (!c.WidthWithin(o.min_width_px, o.max_width_px)) continue;
      if (best < 0 || c.peak > candidates[static_cast<size_t>(best)].peak) best = k;
    }
    if (best < 0) {
      if (any_off_saturated) {
        ++stats.off_saturated;
      } else {
        ++stats.bad_width;
      }
      continue;
    }
    uint8_t flags = 0;
    {
      // A much stronger candidate (the best below multiple_peak_ratio of it) was rejected. Only one
      // reason lets the weaker one stand: the stronger is narrower than min_width (a hot pixel, a glint's
      // core), flagged. Wider than max_width or hidden under a saturated laser-off pixel, it may be the
      // laser itself: the row gets no point rather than a stray one (ExtractTest.NeverAWeakCandidate...).
      const Candidate& s = candidates[static_cast<size_t>(strongest)];
      if (strongest != best && candidates[static_cast<size_t>(best)].peak < o.multiple_peak_ratio * s.peak) {
        if (!s.off_saturated && s.width_num < o.min_width_px * s.width_den) {
          flags |= kFlagStrongerRejected;
        } else {
          ++stats.stronger_rejected;
          continue;
        }
      }
    }
    const bool continuous = previous_column >= 0 && r - previous_row <= 2;
    for (int k = 0; k < count; ++k) {
      const Candidate& c = candidates[static_cast<size_t>(k)];
      if (k == best || c.off_saturated || !c.WidthWithin(o.min_width_px, o.max_width_px)) continue;
      if (c.peak >= o.multiple_peak_ratio * candidates[static_cast<size_t>(best)].peak) {
        flags |= kFlagMultiplePeaks;
        const Candidate& cb = candidates[static_cast<size_t>(best)];
        if (continuous && std::abs(0.5 * (c.first + c.last) - previous_column) <
                              std::abs(0.5 * (cb.first + cb.last) - previous_column)) {
          best = k;
        }
      }
    }
    const Candidate& c = candidates[static_cast<size_t>(best)];
    // Step 5: sub-pixel centre.
    double column;
    if (o.estimator == Estimator::kCenterOfMass) {  // EstimateCentre's, with the vector extent scans
      column = CenterOfMassOver(d, c.com_first, c.com_last, c.peak);
    } else {
      column = EstimateCentre(o.estimator, d, cols, c.first, c.last, c.peak);
    }
    if (column < 0) {
      ++stats.bad_width;
      continue;
    }
    if (a[c.peak_pos] == 255) {
      flags |= kFlagSaturated;
      // A notch: a saturated pixel of the line whose own difference is below half the line's best.
      int best_difference = 0, worst_saturated = 255;
      for (int i = c.first; i <= c.last; ++i) {
        const int x = a[i] > b[i] ? a[i] - b[i] : 0;
        best_difference = std::max(best_difference, x);
        if (a[i] == 255) worst_saturated = std::min(worst_saturated, x);
      }
      if (2 * worst_saturated < best_difference) flags |= kFlagNotched;
    }
    if (c.first == 0 || c.last == cols - 1) flags |= kFlagClipped;
    const double width = c.Width();
    // Uncertainty (see the design notes): noise, speckle and the profile's asymmetry.
    const double asymmetry = column - 0.5 * (c.first + c.last);
    const double noise_term = stats.noise_dn / c.peak * std::sqrt(width * (1.0 / 12.0));
    // Texture across the line: the laser's reflection is weighed by the albedo, which the laser-off frame
    // shows; an albedo that differs between the line's two halves pulls the centre towards the brighter
    // one, by up to a quarter of the width for a step across the middle.
    double texture_term = 0.0;
    {
      const int middle = static_cast<int>(column + 0.5);
      int left = 0, right = 0;
      for (int i = c.com_first; i < middle; ++i) left += b[i];
      for (int i = middle + 1; i <= c.com_last; ++i) right += b[i];
      const int nl = std::max(1, middle - c.com_first), nr = std::max(1, c.com_last - middle);
      const double ml = static_cast<double>(left) / nl, mr = static_cast<double>(right) / nr;
      texture_term = 0.25 * width * std::abs(ml - mr) / std::max(1.0, ml + mr);
    }
    const double uncertainty = 2.0 * std::sqrt(noise_term * noise_term + kSpeckleTerm2 * width +
                                               asymmetry * asymmetry + texture_term * texture_term);
    double quality = 1.0;
    if (stats.noise_dn > 0) quality *= std::min(1.0, c.peak * quality_per_snr);
    quality *= std::min(1.0, (c.peak - 0.5 * threshold) * quality_per_contrast);
    if (width < narrow_width || width > wide_width) quality *= 0.6;
    if (flags & kFlagMultiplePeaks) quality *= 0.5;
    if (flags & kFlagClipped) quality *= 0.3;
    if (flags & kFlagStrongerRejected) quality *= 0.5;
    quality /= 1.0 + uncertainty * uncertainty;
    LinePoint p;
    p.row = r;
    p.column = static_cast<float>(column);
    p.peak = static_cast<float>(c.peak);
    p.width = static_cast<float>(width);
    p.quality = static_cast<float>(std::clamp(quality, 0.0, 1.0));
    p.uncertainty_px = static_cast<float>(uncertainty);
    if (std::abs(asymmetry) > 0.25 * width) flags |= kFlagLopsided;
    p.flags = flags;
    line->points.push_back(p);
    ++stats.found;
    if (flags & kFlagMultiplePeaks) ++stats.multiple_peaks;
    previous_column = column;
    previous_row = r;
  }
  {
    // A steep line (a surface seen at a grazing angle: the line runs along the rows) has a poorly defined
    // centre per row: an error of the profile along the row is the slope times one across it. The
    // uncertainty grows by sqrt(1 + slope^2), the slope from the neighbouring rows' centres.
    std::vector<LinePoint>& points = line->points;
    const size_t n = points.size();
    float before = 0.0f;
    for (size_t i = 0; i < n; ++i) {
      const LinePoint& p = points[i];
      const bool up = i > 0 && points[i - 1].row + 1 == p.row;
      const bool down = i + 1 < n && points[i + 1].row == p.row + 1;
      const float here = p.column;
      float slope = 0.0f;
      if (up && down) {
        slope = 0.5f * (points[i + 1].column - before);
      } else if (up) {
        slope = here - before;
      } else if (down) {
        slope = points[i + 1].column - here;
      }
      before = here;
      const float grow = 1.0f + slope * slope;
      points[i].uncertainty_px *= std::sqrt(grow);
      points[i].quality /= grow;
    }
  }
  if (o.smooth_half_rows > 0) {
    std::vector<LinePoint>& points = line->points;
    const size_t n = points.size();
    row_columns_.resize(n);
    for (size_t i = 0; i < n; ++i) row_columns_[i] = points[i].column;
    SmoothAlongLine(&points, o.smooth_half_rows, o.smooth_order, o.smooth_max_jump_px, o.smooth_outlier_px,
                    &raw_columns_);
    // The smoothing's limits: a point moves by at most its uncertainty, and keeps its own estimate where
    // the profile changes (saturation begins or ends, or the profile is lopsided: texture, an edge).
    for (size_t i = 0; i < n; ++i) {
      LinePoint& p = points[i];
      const float own = row_columns_[i];
      const bool saturated = (p.flags & kFlagSaturated) != 0;
      const bool change =
          (i > 0 && points[i - 1].row + 1 == p.row && ((points[i - 1].flags & kFlagSaturated) != 0) != saturated) ||
          (i + 1 < n && points[i + 1].row == p.row + 1 && ((points[i + 1].flags & kFlagSaturated) != 0) != saturated) ||
          (p.flags & kFlagLopsided) != 0;
      if (change) {
        p.column = own;
        continue;
      }
      p.column = own + std::clamp(p.column - own, -p.uncertainty_px, p.uncertainty_px);
    }
  }
  for (LinePoint& p : line->points) p.flags &= static_cast<uint8_t>(~kFlagLopsided);
  return Status::Ok();
}

void SmoothAlongLine(std::vector<LinePoint>* points, int half_rows, int order, double max_jump_px,
                     double outlier_px, std::vector<float>* scratch) {
  ROTOSCAN_CHECK(points != nullptr && scratch != nullptr && half_rows >= 0 && order >= 0 && order <= 2);
  const int n = static_cast<int>(points->size());
  if (half_rows == 0 || n < 2) return;
  LinePoint* p = points->data();
  // Floats: the raw columns, then per stretch (at most n points) the columns relative to the stretch's
  // first and the first fit's a and b. Padding (pad = h + 8 entries) around raw and rel, for the vector
  // outlier tests' reads past a window's ends (read, then masked), and after af and bf, for the screen's
  // last group.
  const size_t pad = static_cast<size_t>(half_rows) + 8;
  const size_t un = static_cast<size_t>(n);
  scratch->resize(4 * pad + 4 * un + 16);  // only raw's padding needs a value (finite: it is masked)
  float* raw = scratch->data() + pad;
  std::fill(raw - pad, raw, 0.0f);
  std::fill(raw + un, raw + un + pad, 0.0f);
  float* rel = raw + un + 2 * pad;
  float* af = rel + un + pad;
  float* bf = af + un + 8;
  for (int i = 0; i < n; ++i) raw[i] = p[i].column;
  // Order 2: the weighted least-squares polynomial c(x) = a + b x + q x^2 through the neighbours j of
  // point i, x = j - i (a stretch has consecutive rows), triangular weight half_rows + 1 - |x|; the
  // smoothed centre is a. Columns relative to raw[i] so that floats keep their precision. Plain scalar
  // sums and Cramer's rule: this runs for every point of every frame (an Eigen 3x3 version cost 0.6 ms
  // per 964-row frame, twice the whole extraction); `keep(j)` says whether j enters.
  struct Fit {
    double a = 0, b = 0, q = 0;
  };
  auto fit = [&](int i, int lo, int hi, auto&& keep) {
    double s0 = 0, s1 = 0, s2 = 0, s3 = 0, s4 = 0, t0 = 0, t1 = 0, t2 = 0;
    const double ri = raw[i];
    for (int j = lo; j <= hi; ++j) {
      if (!keep(j)) continue;
      const double x = j - i;
      const double w = half_rows + 1 - std::abs(x);
      const double y = raw[j] - ri;
      const double wx = w * x, wxx = wx * x;
      s0 += w;
      s1 += wx;
      s2 += wxx;
      t0 += w * y;
      t1 += wx * y;
      if (order >= 2) {
        s3 += wxx * x;
        s4 += wxx * x * x;
        t2 += wxx * y;
      }
    }
    Fit f;
    if (order >= 2) {
      const double det = s0 * (s2 * s4 - s3 * s3) - s1 * (s1 * s4 - s3 * s2) + s2 * (s1 * s3 - s2 * s2);
      if (std::abs(det) > 1e-9 * s0 * s2 * s4) {  // not enough distinct rows: fall back to the line
        f.a = (t0 * (s2 * s4 - s3 * s3) - s1 * (t1 * s4 - s3 * t2) + s2 * (t1 * s3 - s2 * t2)) / det;
        f.b = (s0 * (t1 * s4 - t2 * s3) - t0 * (s1 * s4 - s3 * s2) + s2 * (s1 * t2 - t1 * s2)) / det;
        f.q = (s0 * (s2 * t2 - s3 * t1) - s1 * (s1 * t2 - s2 * t1) + t0 * (s1 * s3 - s2 * s2)) / det;
        f.a += ri;
        return f;
      }
    }
    const double det = s0 * s2 - s1 * s1;
    if (order >= 1 && det > 1e-9 * s0 * s2) {
      f.a = (s2 * t0 - s1 * t1) / det;
      f.b = (s0 * t1 - s1 * t0) / det;
    } else {
      f.a = t0 / s0;
    }
    f.a += ri;
    return f;
  };
  // Two passes: the second without the neighbours the first does not explain (a glint, a wrong peak),
  // only when there are such. The point itself always stays, so its neighbours alone cannot move it.
  auto robust_fit = [&](int i, int lo, int hi) {
    const Fit first = fit(i, lo, hi, [](int) { return true; });
    auto explained = [&](int j) {
      const double x = j - i;
      return j == i || std::abs(raw[j] - (first.a + x * (first.b + x * first.q))) <= outlier_px;
    };
    bool all = true;
    for (int j = lo; j <= hi && all; ++j) all = explained(j);
    return all ? first.a : fit(i, lo, hi, explained).a;
  };
  // Order 0 and 1 (the default): every fit from prefix sums in O(1). With j the index in the stretch and
  // y the column relative to the stretch's first, the sums of the fit of point k over x in [xa, xb]
  // (j = k + x) split at x = 0 into a left part with w = h + 1 + x and a right part with w = h + 1 - x,
  // and each part's sum w y and w x y comes from the range sums of y, j y and j^2 y (x = j - k). The
  // weights' sums s0, s1, s2 are integers, from running sums over x. A second fit whose kept neighbours
  // are again a range around the point (outliers at the window's ends: a curved line) is O(1) the same
  // way; other second fits subtract the outliers' terms from the first's sums.
  const int h = half_rows;
  SmoothScratch& buffers = smooth_scratch();
  std::vector<double>& prefix = buffers.prefix;
  std::vector<uint64_t>& bits = buffers.bits;
  std::vector<std::array<double, 3>>& cumulative = buffers.cumulative;
  cumulative.resize(static_cast<size_t>(2 * h + 2));
  std::array<double, 3> weight_sums{};  // sums of w, w x, w x^2 over x = -h .. x - 1, at index x + h
  for (int x = -h; x <= h; ++x) {
    cumulative[static_cast<size_t>(x + h)] = weight_sums;
    const double w = h + 1 - std::abs(x);
    weight_sums[0] += w;
    weight_sums[1] += w * x;
    weight_sums[2] += w * x * x;
  }
  cumulative[static_cast<size_t>(2 * h + 1)] = weight_sums;
  const double inv_s0_whole = 1.0 / weight_sums[0], inv_s2_whole = 1.0 / weight_sums[2];
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  const bool avx2 = HaveAvx2();
#endif
  // The exact outlier test of a flagged point in vectors (OutlierBits) while the window fits in the
  // 64 bits; one neighbour at a time beyond.
  const bool vector_test = 2 * h + 1 <= 64;
  std::array<double, 64 + 4> window_x;
  for (int k = 0; k < 64 + 4; ++k) window_x[static_cast<size_t>(k)] = k - h;
  struct Sums {
    double s0, s1, s2, t0, t1;
  };
  auto smooth_stretch = [&](int start, int end) {
    const int len = end - start + 1;
    if (len < 2) return;
    if (order == 2) {
      for (int i = start; i <= end; ++i) {
        p[i].column = static_cast<float>(robust_fit(i, std::max(start, i - h), std::min(end, i + h)));
      }
      return;
    }
    const double origin = raw[start];
    const size_t m = static_cast<size_t>(len);
    prefix.resize(5 * (m + 1));
    double* py = prefix.data();  // sums over j < index of y, j y, j^2 y
    double* pjy = py + (m + 1);
    double* pjjy = pjy + (m + 1);
    double* fit_a = pjjy + (m + 1);  // the first fit, a absolute
    double* fit_b = fit_a + (m + 1);
    // The sums run in registers (a store and reload per step would put store forwarding on each chain).
    double sy = 0, sjy = 0, sjjy = 0, max_rel = 0;
    py[0] = pjy[0] = pjjy[0] = 0.0;
    for (int k = 0; k < len; ++k) {
      const double y = raw[start + k] - origin;
      rel[k] = static_cast<float>(y);
      max_rel = std::max(max_rel, std::abs(y));
      sy += y;
      sjy += k * y;
      sjjy += static_cast<double>(k) * k * y;
      py[k + 1] = sy;
      pjy[k + 1] = sjy;
      pjjy[k + 1] = sjjy;
    }
    // Outside the stretch the screen reads NaN, which its maxima skip: its windows end where the
    // stretch does.
    const float nan = std::numeric_limits<float>::quiet_NaN();
    std::fill(rel - pad, rel, nan);
    std::fill(rel + len, rel + len + pad, nan);
    auto window = [&](int k, int* xa, int* xb) {
      *xa = std::max(-h, -k);
      *xb = std::min(h, len - 1 - k);
    };
    auto range_sums = [&](int k, int xa, int xb) {
      const std::array<double, 3>& hi = cumulative[static_cast<size_t>(xb + h + 1)];
      const std::array<double, 3>& lo = cumulative[static_cast<size_t>(xa + h)];
      const double kd = k;
      const double ly = py[k] - py[k + xa], ljy = pjy[k] - pjy[k + xa], ljjy = pjjy[k] - pjjy[k + xa];
      const double ry = py[k + xb + 1] - py[k], rjy = pjy[k + xb + 1] - pjy[k], rjjy = pjjy[k + xb + 1] - pjjy[k];
      const double lxy = ljy - kd * ly, lxxy = ljjy - 2 * kd * ljy + kd * kd * ly;
      const double rxy = rjy - kd * ry, rxxy = rjjy - 2 * kd * rjy + kd * kd * ry;
      const double hp = h + 1;
      return Sums{hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], hp * (ly + ry) + lxy - rxy, hp * (lxy + rxy) + lxxy - rxxy};
    };
    // a (relative) and b of the fit with these sums, as the general fit solves it.
    auto solve = [&](const Sums& u, double* fa, double* fb) {
      const double det = u.s0 * u.s2 - u.s1 * u.s1;
      if (order >= 1 && det > 1e-9 * u.s0 * u.s2) {
        const double inverse = 1.0 / det;
        *fa = (u.s2 * u.t0 - u.s1 * u.t1) * inverse;
        *fb = (u.s0 * u.t1 - u.s1 * u.t0) * inverse;
      } else {
        *fa = u.t0 / u.s0;
        *fb = 0.0;
      }
    };
    double max_b = 0;
    int vector_from = len, vector_to = len;  // the whole windows done 4 at a time
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
    if (avx2 && len - 2 * h >= 4) {
      vector_from = h;
      vector_to = h + (len - 2 * h) / 4 * 4;
      max_b = WholeWindowFitsAvx2(py, pjy, pjjy, vector_from, vector_to, h, order >= 1, inv_s0_whole, inv_s2_whole,
                                  origin, fit_a, fit_b, af, bf);
    }
#endif
    for (int k = 0; k < len; ++k) {
      if (k == vector_from) {
        k = vector_to - 1;
        continue;
      }
      int xa, xb;
      window(k, &xa, &xb);
      double fa, fb;
      const Sums u = range_sums(k, xa, xb);
      if (xa == -h && xb == h) {  // a whole window: s1 = 0, no division
        fa = u.t0 * inv_s0_whole;
        fb = order >= 1 ? u.t1 * inv_s2_whole : 0.0;
      } else {
        solve(u, &fa, &fb);
      }
      fit_a[k] = fa + origin;
      fit_b[k] = fb;
      af[k] = static_cast<float>(fa);
      bf[k] = static_cast<float>(fb);
      max_b = std::max(max_b, std::abs(fb));
    }
    // The screen: which points' windows may hold a neighbour the first fit does not explain. Its float
    // residuals are off from the double ones by a few ulp of the largest value involved; the margin
    // covers 16, so every point the exact test finds an outlier for is flagged.
    const double magnitude = max_rel + h * max_b + outlier_px + 1.0;
    const double margin = 1e-3 + 16.0 * std::numeric_limits<float>::epsilon() * magnitude;
    const float limit = static_cast<float>(outlier_px - margin);
    const size_t words = m / 64 + 1;
    bits.assign(words + m, 0);  // the screen's bits, then the flagged points' outlier bits
    uint64_t* flagged = bits.data();
    uint64_t* outliers = flagged + words;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
    if (avx2) {
      ScreenWindowsAvx2(rel, af, bf, 0, len, h, limit, flagged);
    } else
#endif
    {
      ScreenWindows(rel, af, bf, 0, len, h, limit, flagged);
    }
    if (vector_test) {  // the exact test of the flagged points, before the window's ends are masked
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
      if (avx2) {
        FlaggedOutliersAvx2(raw + start, fit_a, fit_b, 0, len, h, outlier_px, flagged, window_x.data(), outliers);
      } else
#endif
      {
        FlaggedOutliers(raw + start, fit_a, fit_b, 0, len, h, outlier_px, flagged, window_x.data(), outliers);
      }
    }
    for (int k = 0; k < len; ++k) {
      const int i = start + k;
      if (!((flagged[static_cast<size_t>(k) >> 6] >> (k & 63)) & 1u)) {
        p[i].column = static_cast<float>(fit_a[k]);
        continue;
      }
      int xa, xb;
      window(k, &xa, &xb);
      uint64_t dropped = 0;  // bits x + h, while vector_test
      if (vector_test) {
        const uint64_t in_window = (~uint64_t{0} >> (63 - (xb - xa))) << (xa + h);  // bits xa + h .. xb + h
        dropped = outliers[k] & in_window;
        if (dropped == 0) {
          p[i].column = static_cast<float>(fit_a[k]);
          continue;
        }
        const uint64_t kept = in_window & ~dropped;  // holds bit h: the point itself always stays
        const uint64_t run = kept >> __builtin_ctzll(kept);
        if ((run & (run + 1)) == 0) {  // the kept neighbours are a range: O(1)
          double fa, fb;
          solve(range_sums(k, __builtin_ctzll(kept) - h, 63 - __builtin_clzll(kept) - h), &fa, &fb);
          p[i].column = static_cast<float>(fa + origin);
          continue;
        }
      }
      // The first fit's sums less the outliers' terms.
      Sums u = range_sums(k, xa, xb);
      bool any = false;
      auto drop = [&](int x) {
        any = true;
        const double w = h + 1 - std::abs(x);
        const double y = raw[i + x] - origin;
        u.s0 -= w;
        u.s1 -= w * x;
        u.s2 -= w * x * x;
        u.t0 -= w * y;
        u.t1 -= w * x * y;
      };
      if (vector_test) {
        for (uint64_t o = dropped; o != 0; o &= o - 1) drop(__builtin_ctzll(o) - h);
      } else {
        for (int x = xa; x <= xb; ++x) {
          if (x != 0 && std::abs(raw[i + x] - (fit_a[k] + x * fit_b[k])) > outlier_px) drop(x);
        }
      }
      double fa = fit_a[k] - origin, fb;
      if (any) solve(u, &fa, &fb);
      p[i].column = static_cast<float>(fa + origin);
    }
  };
  // Stretches: runs of consecutive rows whose column steps are at most max_jump_px. A line steeper than
  // that (a surface seen at a grazing angle: wide, unreliable rows) is not smoothed, nor are its rows
  // joined to their neighbours: measured on Spot (rotoscan evaluate --lines, 100 frames), joining rows
  // whose step merely continues the local slope raised the line centre error from 0.217 to 0.263 px.
  auto continues = [&](int k) {
    return p[k + 1].row == p[k].row + 1 && std::abs(raw[k + 1] - raw[k]) <= max_jump_px;
  };
  int start = 0;  // first point of the current stretch
  while (start < n) {
    int end = start;  // last point of the stretch, inclusive
    while (end + 1 < n && continues(end)) ++end;
    smooth_stretch(start, end);
    start = end + 1;
  }
}

Result<cv::Mat> ReadImage8(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    if (std::filesystem::exists(path, ec)) return InvalidArgumentError(path.string() + " is not a regular file");
    return NotFoundError(path.string() + " does not exist");
  }
  // Decoder messages (libpng's) come back in the status, never on stderr.
  ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat image, geometry::ReadImageFile(path));
  if (image.depth() != CV_8U)
    return InvalidArgumentError(path.string() + " is not 8-bit (only 8-bit is read)");
  return image;
}

Result<Line> ExtractLine(const cv::Mat& on, const cv::Mat& off, const ExtractOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  LineExtractor extractor(options);
  Line line;
  ROTOSCAN_RETURN_IF_ERROR(extractor.Extract(on, off, &line));
  return line;
}

}  // namespace rotoscan::laser
