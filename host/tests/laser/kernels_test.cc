// The extractor's instruction-set paths against each other (host/lib/src/laser/kernels.h): each SSE2
// kernel must compute exactly what its portable namesake does, on random rows with saturated pixels,
// random runs (at the row's ends too) and rows narrower than a vector. The extractor's own tests run the
// AVX2 and SSSE3 paths against the SSE2 one (internal::AllowVectorExtensions); on x86-64 the portable
// kernels run nowhere else.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "laser/kernels.h"
#include "rotoscan/laser/extract.h"

namespace rotoscan::laser::detail {
namespace {

#if defined(__SSE2__)

// A row of `cols` pixels with kPad zero bytes either side, as the extractor keeps its difference row.
struct PaddedRow {
  explicit PaddedRow(int cols) : bytes(static_cast<size_t>(cols) + 2 * kPad, 0) {}
  uint8_t* data() { return bytes.data() + kPad; }
  std::vector<uint8_t> bytes;
};

// Laser-like rows: a background, a bright saturated stretch, dips (notches) and noise.
void RandomRows(std::mt19937* rng, int cols, std::vector<uint8_t>* on, std::vector<uint8_t>* off) {
  std::uniform_int_distribution<int> byte(0, 255), coin(0, 3);
  on->assign(static_cast<size_t>(cols), 0);
  off->assign(static_cast<size_t>(cols), 0);
  const int centre = std::uniform_int_distribution<int>(0, cols - 1)(*rng);
  for (int i = 0; i < cols; ++i) {
    const int b = coin(*rng) == 0 ? byte(*rng) : 40 + (i * 7) % 50;
    int a = b + std::max(0, 300 - 30 * std::abs(i - centre)) + coin(*rng);
    if (coin(*rng) == 0) a = byte(*rng);
    (*off)[static_cast<size_t>(i)] = static_cast<uint8_t>(b);
    (*on)[static_cast<size_t>(i)] = static_cast<uint8_t>(std::min(a, 255));
  }
}

TEST(KernelsTest, Sse2MatchesPortableOnRandomRows) {
  std::mt19937 rng(15);
  for (int trial = 0; trial < 3000; ++trial) {
    const int cols = trial % 5 == 0 ? std::uniform_int_distribution<int>(1, 15)(rng)
                                    : std::uniform_int_distribution<int>(16, 200)(rng);
    std::vector<uint8_t> on, off;
    RandomRows(&rng, cols, &on, &off);
    const int threshold = std::uniform_int_distribution<int>(1, 60)(rng);
    // Step 1: the difference and its groups, the SSE2 groups then the portable tail as RowPass runs them.
    PaddedRow d_portable(cols), d_sse2(cols);
    std::vector<int> starts_portable(static_cast<size_t>(cols) / 16 + 3), starts_sse2(starts_portable.size());
    std::vector<uint64_t> masks_portable(starts_portable.size()), masks_sse2(starts_portable.size());
    int next_portable = 0, next_sse2 = 0;
    const int count_portable = scalar::RowGroups(on.data(), off.data(), d_portable.data(), cols, threshold,
                                                 starts_portable.data(), masks_portable.data(), 0, &next_portable);
    int count_sse2 = sse2::RowGroups(on.data(), off.data(), d_sse2.data(), cols, threshold, starts_sse2.data(),
                                     masks_sse2.data(), 0, &next_sse2);
    count_sse2 = scalar::RowGroups(on.data(), off.data(), d_sse2.data(), cols, threshold, starts_sse2.data(),
                                   masks_sse2.data(), count_sse2, &next_sse2);
    ASSERT_EQ(d_portable.bytes, d_sse2.bytes) << "cols " << cols;
    // The groups differ in layout (64 against 16 pixels); the pixels they mark must not.
    auto marked = [cols](const std::vector<int>& starts, const std::vector<uint64_t>& masks, int count) {
      std::vector<bool> bits(static_cast<size_t>(cols), false);
      for (int k = 0; k < count; ++k) {
        for (int j = 0; j < 64; ++j) {
          if ((masks[static_cast<size_t>(k)] >> j) & 1u) bits[static_cast<size_t>(starts[static_cast<size_t>(k)] + j)] = true;
        }
      }
      return bits;
    };
    ASSERT_EQ(marked(starts_portable, masks_portable, count_portable), marked(starts_sse2, masks_sse2, count_sse2));

    std::uniform_int_distribution<int> pixel(0, cols - 1);
    for (int run = 0; run < 8; ++run) {
      int first = pixel(rng), last = pixel(rng);
      if (first > last) std::swap(first, last);
      uint8_t* d = d_sse2.data();
      const PeakInRun peak_portable = scalar::FindPeak(d, first, last), peak_sse2 = sse2::FindPeak(d, first, last);
      ASSERT_EQ(peak_portable.value, peak_sse2.value);
      ASSERT_EQ(peak_portable.position, peak_sse2.position);
      const int level = std::uniform_int_distribution<int>(1, 255)(rng);
      const int at = pixel(rng);
      ASSERT_EQ(scalar::ExtentLeft(d, at, level), sse2::ExtentLeft(d, at, level));
      ASSERT_EQ(scalar::ExtentRight(d, at, level), sse2::ExtentRight(d, at, level));
      ASSERT_EQ(scalar::CenterOfMassOver(d, first, last, peak_portable.value),
                sse2::CenterOfMassOver(d, first, last, peak_portable.value));
      const NotchScan notch_portable = scalar::ScanNotch(on.data(), off.data(), first, last, cols);
      const NotchScan notch_sse2 = sse2::ScanNotch(on.data(), off.data(), first, last, cols);
      ASSERT_EQ(notch_portable.best_difference, notch_sse2.best_difference);
      ASSERT_EQ(notch_portable.worst_saturated, notch_sse2.worst_saturated);
      ASSERT_EQ(scalar::SumRange(off.data(), first, last, cols), sse2::SumRange(off.data(), first, last, cols));
      // Over the laser-off row itself (no padding: an exact-size copy, so that an ASan build sees any read
      // outside [first, last]).
      const std::vector<uint8_t> stretch(off.begin() + first, off.begin() + last + 1);
      const ByteRange range_portable = scalar::MinMaxRange(stretch.data(), 0, last - first);
      const ByteRange range_sse2 = sse2::MinMaxRange(stretch.data(), 0, last - first);
      ASSERT_EQ(range_portable.low, range_sse2.low);
      ASSERT_EQ(range_portable.high, range_sse2.high);
      // Either side may be empty, never outside the row.
      const int middle = std::uniform_int_distribution<int>(std::max(first - 2, -1), std::min(last + 2, cols))(rng);
      const SidesSum sides_portable = scalar::SumsAround(off.data(), first, middle, last, cols);
      const SidesSum sides_sse2 = sse2::SumsAround(off.data(), first, middle, last, cols);
      ASSERT_EQ(sides_portable.left, sides_sse2.left);
      ASSERT_EQ(sides_portable.right, sides_sse2.right);
      // The notch filling writes the row: each path on its own copy; one run in four all zero (its peak
      // is 0 at its first pixel).
      PaddedRow fill_portable = d_sse2, fill_sse2 = d_sse2;
      if (run % 4 == 0) {
        std::fill(fill_portable.data() + first, fill_portable.data() + last + 1, 0);
        std::fill(fill_sse2.data() + first, fill_sse2.data() + last + 1, 0);
      }
      const PeakInRun filled_portable =
          scalar::FillPlateau(on.data(), off.data(), fill_portable.data(), first, last, cols, threshold);
      const PeakInRun filled_sse2 =
          sse2::FillPlateau(on.data(), off.data(), fill_sse2.data(), first, last, cols, threshold);
      ASSERT_EQ(fill_portable.bytes, fill_sse2.bytes) << "cols " << cols << " run " << first << ".." << last;
      ASSERT_EQ(filled_portable.value, filled_sse2.value);
      ASSERT_EQ(filled_portable.position, filled_sse2.position);
    }
  }
}

// The noise estimate's SSE2 stretch (noise.cc) against its per-pixel definition, on mostly black rows
// with lit stretches (a webcam frame's kind: the stretch skips 16 pixels none of which is sampled): the
// histograms' sampled bins, summed over the four interleaved ones, must be the same.
TEST(KernelsTest, NoiseStretchMatchesPerPixelHistogram) {
  std::mt19937 rng(19);
  std::uniform_int_distribution<int> byte(0, 255), dark(0, kNoiseMinOffDn - 1), coin(0, 3);
  for (int trial = 0; trial < 2000; ++trial) {
    const int cols = std::uniform_int_distribution<int>(16, 300)(rng);
    const int near = coin(rng) < 2 ? 64 : 256;
    const int min_off = coin(rng) == 0 ? 0 : kNoiseMinOffDn;
    std::vector<uint8_t> on(static_cast<size_t>(cols)), off(static_cast<size_t>(cols));
    const int lit_from = std::uniform_int_distribution<int>(0, cols - 1)(rng);
    const int lit_to = lit_from + std::uniform_int_distribution<int>(0, 40)(rng);
    for (int i = 0; i < cols; ++i) {
      const bool lit = (i >= lit_from && i < lit_to) || (coin(rng) == 0 && coin(rng) == 0 && coin(rng) == 0);
      off[static_cast<size_t>(i)] = static_cast<uint8_t>(lit ? byte(rng) : dark(rng));
      on[static_cast<size_t>(i)] = static_cast<uint8_t>(coin(rng) == 0 ? byte(rng) : std::clamp(off[static_cast<size_t>(i)] + coin(rng) - 1, 0, 255));
    }
    NoiseHistograms partial{};
    const int from = std::uniform_int_distribution<int>(0, cols - 16)(rng);
    const int end = cols;
    const int stopped = sse2::NoiseStretch(on.data(), off.data(), from, end, near, min_off, &partial);
    ASSERT_GE(stopped, end - 15);
    ASSERT_LE(stopped, end);
    std::vector<uint32_t> expected(static_cast<size_t>(2 * near), 0);
    for (int c = from; c < stopped; ++c) {
      if (off[static_cast<size_t>(c)] < min_off) continue;
      ++expected[static_cast<size_t>(std::clamp(int{on[static_cast<size_t>(c)]} - int{off[static_cast<size_t>(c)]}, -near, near - 1) + near)];
    }
    for (int k = 0; k < 2 * near; ++k) {
      const uint32_t got = partial[0][static_cast<size_t>(k)] + partial[1][static_cast<size_t>(k)] +
                           partial[2][static_cast<size_t>(k)] + partial[3][static_cast<size_t>(k)];
      ASSERT_EQ(got, expected[static_cast<size_t>(k)]) << "trial " << trial << " bin " << k;
    }
  }
}

TEST(KernelsTest, SmoothingScreensMatchPortable) {
  std::mt19937 rng(17);
  std::normal_distribution<float> noise(0.0f, 0.3f);
  for (int trial = 0; trial < 300; ++trial) {
    const int h = std::uniform_int_distribution<int>(1, 20)(rng);
    const int n = std::uniform_int_distribution<int>(1, 150)(rng);
    const int pad = h + 8;
    // rel with NaN outside the stretch, af and bf readable 8 past the end (the screen's contract).
    std::vector<float> rel(static_cast<size_t>(n + 2 * pad), std::numeric_limits<float>::quiet_NaN());
    std::vector<float> af(static_cast<size_t>(n + 8), 0.0f), bf(af.size(), 0.0f);
    std::vector<float> raw(static_cast<size_t>(n + 2 * pad), 0.0f);
    const float slope = noise(rng);
    for (int k = 0; k < n; ++k) {
      rel[static_cast<size_t>(pad + k)] = slope * k + noise(rng) + (k % 17 == 3 ? 2.0f : 0.0f);
      raw[static_cast<size_t>(pad + k)] = rel[static_cast<size_t>(pad + k)];
      af[static_cast<size_t>(k)] = slope * k;
      bf[static_cast<size_t>(k)] = slope;
    }
    const float limit = 0.5f;
    std::vector<uint64_t> bits_portable(static_cast<size_t>(n) / 64 + 2, 0), bits_sse2(bits_portable.size(), 0);
    scalar::ScreenWindows(rel.data() + pad, af.data(), bf.data(), 0, n, h, limit, bits_portable.data());
    sse2::ScreenWindows(rel.data() + pad, af.data(), bf.data(), 0, n, h, limit, bits_sse2.data());
    for (int k = 0; k < n; ++k) {
      ASSERT_EQ((bits_portable[static_cast<size_t>(k) / 64] >> (k % 64)) & 1u, (bits_sse2[static_cast<size_t>(k) / 64] >> (k % 64)) & 1u)
          << "h " << h << " point " << k;
    }
    if (2 * h + 1 > 64) continue;
    std::vector<double> window_x(64 + 4);
    for (int k = 0; k < 64 + 4; ++k) window_x[static_cast<size_t>(k)] = k - h;
    for (int k = 0; k < n; ++k) {
      const double a = af[static_cast<size_t>(k)], b = bf[static_cast<size_t>(k)];
      ASSERT_EQ(scalar::OutlierBits(raw.data() + pad, k, h, a, b, 0.5, window_x.data()),
                sse2::OutlierBits(raw.data() + pad, k, h, a, b, 0.5, window_x.data()));
    }
  }
}

#endif  // __SSE2__

#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
// ScorePoints with its AVX2 kernel (4 points at a time) against its scalar loop, field by field and bit for
// bit, on random terms: lopsided and flagged points, rows with and without neighbours, frames with and
// without a noise estimate, and point counts that leave a remainder for the scalar loop.
TEST(KernelsTest, ScorePointsAvx2MatchesScalar) {
  if (!HaveAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  std::mt19937 rng(23);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (int trial = 0; trial < 400; ++trial) {
    const size_t n = std::uniform_int_distribution<size_t>(0, 41)(rng);
    std::vector<PointTerms> terms(n);
    std::vector<LinePoint> points(n);
    int row = std::uniform_int_distribution<int>(0, 3)(rng);
    for (size_t i = 0; i < n; ++i) {
      PointTerms& t = terms[i];
      const double width = 1 + 20 * unit(rng);
      t.width_den = std::uniform_int_distribution<int>(1, 5000)(rng);
      t.width_num = std::round(width * t.width_den);
      t.column = 600 + 10 * unit(rng);
      t.extent_middle = t.column + (unit(rng) < 0.3 ? 0.5 * width : 0.1) * (unit(rng) - 0.5);
      t.peak = std::uniform_int_distribution<int>(1, 255)(rng);
      t.left_n = std::uniform_int_distribution<int>(1, 12)(rng);
      t.right_n = std::uniform_int_distribution<int>(1, 12)(rng);
      t.left = unit(rng) < 0.2 ? 0 : std::uniform_int_distribution<int>(0, 255)(rng) * t.left_n;
      t.right = std::uniform_int_distribution<int>(0, 255)(rng) * t.right_n;
      t.overexposed = false;
      LinePoint& p = points[i];
      row += unit(rng) < 0.8 ? 1 : std::uniform_int_distribution<int>(2, 4)(rng);
      p.row = row;
      p.column = static_cast<float>(t.column);
      p.peak = static_cast<float>(t.peak);
      p.flags = static_cast<uint8_t>(std::uniform_int_distribution<int>(0, 255)(rng) & 0x7f);
    }
    FrameScale frame;
    frame.noise_dn = trial % 5 == 0 ? 0.0 : 3 * unit(rng);
    frame.threshold = std::uniform_int_distribution<int>(1, 60)(rng);
    frame.quality_per_snr = frame.noise_dn > 0 ? 1.0 / (frame.noise_dn * 32) : 0.0;
    frame.quality_per_contrast = 1.0 / std::max(1.0, 2.0 * frame.threshold);
    frame.narrow_width = 3 * unit(rng);
    frame.wide_width = 8 + 8 * unit(rng);
    std::vector<LinePoint> scalar_points = points, avx2_points = points;
    internal::AllowVectorExtensions(false, false);
    ScorePoints(terms.data(), frame, &scalar_points);
    internal::AllowVectorExtensions(true, true);
    ScorePoints(terms.data(), frame, &avx2_points);
    for (size_t i = 0; i < n; ++i) {
      const LinePoint &a = scalar_points[i], &b = avx2_points[i];
      // Bit for bit (memcmp: a NaN would fail an equality test, -0.0 and 0.0 pass one).
      ASSERT_EQ(0, std::memcmp(&a.width, &b.width, sizeof(float))) << "trial " << trial << " point " << i;
      ASSERT_EQ(0, std::memcmp(&a.quality, &b.quality, sizeof(float))) << "trial " << trial << " point " << i;
      ASSERT_EQ(0, std::memcmp(&a.uncertainty_px, &b.uncertainty_px, sizeof(float))) << "trial " << trial << " point " << i;
      ASSERT_EQ(a.flags, b.flags) << "trial " << trial << " point " << i;
    }
  }
}

// AlbedoBlurredRatioAvx2 against the portable AlbedoBlurredRatioAt, every ratio bit for bit (in double: the
// centre of mass that reads them rounds its result to a float column, which would hide a last-bit
// difference): random laser-off rows (dark cells at the division's floor and below, bright ones, noise, edges
// of every height), random differences, floors from 3 to 12.75 DN (AlbedoNormalisedCentre's), runs of 4 to
// 64 pixels anywhere the blur lies inside the row; and AlbedoBlurredRatio, which runs the kernel on a run's
// inner part, against the portable ratio on runs that reach the row's ends.
TEST(KernelsTest, AlbedoBlurredRatioAvx2MatchesPortable) {
  if (!HaveAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  std::mt19937 rng(53);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> byte(0, 255);
  int floored = 0, above = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    const int cols = std::uniform_int_distribution<int>(1, 120)(rng);
    std::vector<uint8_t> b(static_cast<size_t>(cols)), d(static_cast<size_t>(cols));
    int level = byte(rng);
    for (int i = 0; i < cols; ++i) {
      if (unit(rng) < 0.1) level = unit(rng) < 0.5 ? std::uniform_int_distribution<int>(0, 6)(rng) : byte(rng);
      b[static_cast<size_t>(i)] = static_cast<uint8_t>(std::clamp(level + byte(rng) % 7 - 3, 0, 255));
      d[static_cast<size_t>(i)] = static_cast<uint8_t>(byte(rng));
    }
    const double floor_dn = std::max(3.0, 0.05 * byte(rng));
    std::vector<double> portable(static_cast<size_t>(cols));
    for (int i = 0; i < cols; ++i) {
      portable[static_cast<size_t>(i)] = AlbedoBlurredRatioAt(d.data(), b.data(), cols, i, floor_dn);
      const double blurred_floor = d[static_cast<size_t>(i)] * std::pow(floor_dn, -kAlbedoExponent);
      (std::abs(portable[static_cast<size_t>(i)] - blurred_floor) <= 1e-4 * blurred_floor ? floored : above) += 1;
    }
    // The kernel alone, on a run whose blur lies inside the row.
    if (cols >= 2 * kAlbedoRadius + 4) {
      const int lo = std::uniform_int_distribution<int>(kAlbedoRadius, cols - kAlbedoRadius - 4)(rng);
      const int count = 4 * std::uniform_int_distribution<int>(1, (cols - kAlbedoRadius - lo) / 4)(rng);
      std::vector<double> ratio(static_cast<size_t>(count), -1.0);
      AlbedoBlurredRatioAvx2(d.data(), b.data(), lo, count, floor_dn, ratio.data());
      for (int j = 0; j < count; ++j)
        ASSERT_EQ(0, std::memcmp(&ratio[static_cast<size_t>(j)], &portable[static_cast<size_t>(lo + j)], sizeof(double)))
            << "trial " << trial << " pixel " << lo + j << ": " << ratio[static_cast<size_t>(j)] << " against "
            << portable[static_cast<size_t>(lo + j)];
    }
    // The dispatching function on any run, the row's ends included.
    const int lo = std::uniform_int_distribution<int>(0, cols - 1)(rng);
    const int hi = std::uniform_int_distribution<int>(lo, cols - 1)(rng);
    std::vector<double> ratio(static_cast<size_t>(hi - lo + 1), -1.0);
    AlbedoBlurredRatio(d.data(), b.data(), cols, lo, hi, floor_dn, ratio.data());
    for (int i = lo; i <= hi; ++i)
      ASSERT_EQ(0, std::memcmp(&ratio[static_cast<size_t>(i - lo)], &portable[static_cast<size_t>(i)], sizeof(double)))
          << "trial " << trial << " run [" << lo << ", " << hi << "] pixel " << i;
  }
  // Both sides of the floor were exercised.
  EXPECT_GT(floored, 1000);
  EXPECT_GT(above, 10000);
}

// AcrossRowSumsAvx2 against its portable namesake, all six sums bit for bit: random rows (saturated pixels,
// noise), lines of either slope through them at random offsets, windows cut at any column (runs of 0 to 40
// columns, so every remainder of 4), gray and 3-channel rows, sums that start at 0 or elsewhere (whole
// numbers, as the sums always are).
bool SameSums(const AcrossSums& x, const AcrossSums& y) {
  return std::memcmp(&x.n, &y.n, sizeof(double)) == 0 && std::memcmp(&x.d, &y.d, sizeof(double)) == 0 &&
         std::memcmp(&x.dc, &y.dc, sizeof(double)) == 0 && std::memcmp(&x.c, &y.c, sizeof(double)) == 0 &&
         std::memcmp(&x.ddr, &y.ddr, sizeof(double)) == 0 && std::memcmp(&x.dr, &y.dr, sizeof(double)) == 0;
}
TEST(KernelsTest, AcrossRowSumsAvx2MatchesPortable) {
  if (!HaveAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  std::mt19937 rng(43);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  int kept = 0, near_edge = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    const int cols = 64, step = trial % 2 == 0 ? 1 : 3;
    std::vector<uint8_t> on_row, off_row, a(static_cast<size_t>(cols * step)), b(static_cast<size_t>(cols * step));
    RandomRows(&rng, cols, &on_row, &off_row);
    for (int c = 0; c < cols; ++c) {
      a[static_cast<size_t>(c * step)] = on_row[static_cast<size_t>(c)];
      b[static_cast<size_t>(c * step)] = off_row[static_cast<size_t>(c)];
    }
    const double s = (1 + 8 * unit(rng)) * (unit(rng) < 0.5 ? -1 : 1), length = std::sqrt(1 + s * s);
    const double dr = std::uniform_int_distribution<int>(-3, 3)(rng), foot_c = 10 + 44 * unit(rng);
    double t = unit(rng) - 0.5, half = 1 + 4 * unit(rng);
    if (trial % 4 == 1) {  // a pixel's across exactly on the window's edge: |across - t| = half (as rounded)
      const int c = std::uniform_int_distribution<int>(0, cols - 1)(rng);
      half = std::abs((c - foot_c - s * dr) / length - t);
      near_edge += half > 0;
    }
    const double level = 60 * unit(rng);
    const int threshold = std::uniform_int_distribution<int>(1, 40)(rng);
    const int c_first = std::uniform_int_distribution<int>(0, cols - 1)(rng);
    const int c_last = std::min(cols - 1, c_first + std::uniform_int_distribution<int>(-1, 40)(rng));
    const int c0 = static_cast<int>(std::floor(foot_c));
    AcrossSums start;
    if (trial % 3 != 0) start = {7, 900, -3000, -12, 500, 4};
    AcrossSums by_scalar = start, by_avx2 = start;
    scalar::AcrossRowSums(a.data(), b.data(), step, c_first, c_last, dr, foot_c, s, length, t, half, level, threshold,
                          8.0, c0, &by_scalar);
    AcrossRowSumsAvx2(a.data(), b.data(), step, c_first, c_last, dr, foot_c, s, length, t, half, level, threshold, 8.0,
                      c0, &by_avx2);
    ASSERT_TRUE(SameSums(by_scalar, by_avx2)) << "trial " << trial << " n " << by_scalar.n << " / " << by_avx2.n;
    kept += by_scalar.n != start.n;
  }
  EXPECT_GT(kept, 1000);  // pixels were kept, not all rejected
  EXPECT_GT(near_edge, 500);
  // Pixels on the along window's edge (|along| = 8 exactly, or within 1e-12 of it), where the AVX2 loop
  // divides to decide (its test on the numerator leaves the edge's margin undecided): kept as by the scalar
  // loop's own division (fourteenth session).
  int on_edge = 0;
  for (const double dr : {-8.0, 8.0}) {
    for (const double s : {0.0, 1e-13, -1e-13}) {
      const int cols = 40;
      std::vector<uint8_t> a(cols, 200), b(cols, 10);
      const double length = std::sqrt(1 + s * s);
      AcrossSums by_scalar, by_avx2;
      scalar::AcrossRowSums(a.data(), b.data(), 1, 0, cols - 1, dr, 20.0, s, length, 0.0, 30.0, 5.0, 10, 8.0, 20,
                            &by_scalar);
      AcrossRowSumsAvx2(a.data(), b.data(), 1, 0, cols - 1, dr, 20.0, s, length, 0.0, 30.0, 5.0, 10, 8.0, 20, &by_avx2);
      ASSERT_TRUE(SameSums(by_scalar, by_avx2)) << "dr " << dr << " s " << s;
      on_edge += by_scalar.n > 0;
    }
  }
  EXPECT_GT(on_edge, 0);  // the edge's pixels were kept somewhere (|along| = 8 is within the window)
}

// ends.cc's centre across from the sums (AcrossCentre) against the centre of mass defined pixel by pixel,
// sum (d - level) across / sum (d - level) with across = (c - foot_c - s dr) / L, in long double: within
// 1e-12 px; and the sums, whole numbers, the same bits whatever the order the rows are added in (the
// sixteenth session's sums of w and w across, in double pixel by pixel, were not: with the rows added last to
// first rather than first to last, 3,583 of these 4,000 windows gave other bits, measured with that loop).
TEST(KernelsTest, AcrossSumsAreExactAndTheirCentreIsTheDefinition) {
  std::mt19937 rng(53);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  int measured = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    const int cols = 64, rows = 3;
    std::vector<std::vector<uint8_t>> on(rows), off(rows);
    for (int r = 0; r < rows; ++r) RandomRows(&rng, cols, &on[static_cast<size_t>(r)], &off[static_cast<size_t>(r)]);
    const double s = (1 + 8 * unit(rng)) * (unit(rng) < 0.5 ? -1 : 1), length = std::sqrt(1 + s * s);
    const double foot_c = 20 + 24 * unit(rng), t = unit(rng) - 0.5, half = 2 + 6 * unit(rng);
    const double level = 3.0 * (20 + 235 * unit(rng)) / 20.0;
    const int threshold = std::uniform_int_distribution<int>(1, 40)(rng), r0 = 1;
    const int c0 = static_cast<int>(std::floor(foot_c));
    AcrossSums forward, backward;
    long double sum_w = 0, sum_wt = 0;
    for (int k = 0; k < rows; ++k) {
      const int r = k, r_back = rows - 1 - k;
      scalar::AcrossRowSums(on[static_cast<size_t>(r)].data(), off[static_cast<size_t>(r)].data(), 1, 0, cols - 1,
                            r - r0, foot_c, s, length, t, half, level, threshold, 30.0, c0, &forward);
      scalar::AcrossRowSums(on[static_cast<size_t>(r_back)].data(), off[static_cast<size_t>(r_back)].data(), 1, 0,
                            cols - 1, r_back - r0, foot_c, s, length, t, half, level, threshold, 30.0, c0, &backward);
      for (int c = 0; c < cols; ++c) {  // the definition, with the scalar loop's tests
        const double dc = c - foot_c, dr = r - r0;
        const double across = (dc - s * dr) / length;
        if (std::abs((dr + s * dc) / length) > 30.0 || std::abs(across - t) > half) continue;
        const int d = LaserDifference(on[static_cast<size_t>(r)][static_cast<size_t>(c)],
                                      off[static_cast<size_t>(r)][static_cast<size_t>(c)], threshold);
        if (d - level <= 0) continue;
        sum_w += d - static_cast<long double>(level);
        sum_wt += (d - static_cast<long double>(level)) * ((c - static_cast<long double>(foot_c)) - s * dr) / length;
      }
    }
    ASSERT_TRUE(SameSums(forward, backward)) << "trial " << trial;
    double centre = 0;
    const bool found = AcrossCentre(forward, foot_c - c0, s, length, level, &centre);
    ASSERT_EQ(found, sum_w > 0) << "trial " << trial;
    if (!found) continue;
    ASSERT_NEAR(centre, static_cast<double>(sum_wt / sum_w), 1e-12) << "trial " << trial;
    ++measured;
  }
  EXPECT_GT(measured, 3000);
}

// SteepColumnAvx2 against its portable namesake, every bin's 8 sums bit for bit: random columns of random
// frames (saturated pixels, noise), runs of 0 to 40 rows anywhere in the frame (rows relative to a base
// row above or below them), bins 0.2-0.7 of a row apart either way and clamped at both ends, sums that
// start at 0 or elsewhere.
TEST(KernelsTest, SteepColumnAvx2MatchesPortable) {
  if (!HaveAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  std::mt19937 rng(47);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> byte(0, 255);
  const int rows = 300, stride = 5;
  std::vector<uint8_t> on(static_cast<size_t>(rows * stride)), off(on.size());
  int added = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    for (size_t k = 0; k < on.size(); ++k) {
      off[k] = static_cast<uint8_t>(byte(rng) / 4);
      on[k] = static_cast<uint8_t>(std::min(255, off[k] + (unit(rng) < 0.2 ? 255 : byte(rng))));
    }
    const int bins = 40;
    std::vector<double> scalar_moments(8 * bins), avx2_moments;
    for (double& m : scalar_moments) m = trial % 2 == 0 ? 0.0 : std::round(1000 * (unit(rng) - 0.3));
    avx2_moments = scalar_moments;
    const int r_first = std::uniform_int_distribution<int>(0, rows - 1)(rng);
    const int r_last = std::min(rows - 1, r_first + std::uniform_int_distribution<int>(-1, 40)(rng));
    const double per_row = (0.1 + 0.25 * unit(rng)) * (unit(rng) < 0.5 ? -1 : 1);
    const double u0 = 20 * unit(rng) - per_row * r_first;
    const int threshold = std::uniform_int_distribution<int>(1, 40)(rng);
    const int min_d = std::uniform_int_distribution<int>(1, 120)(rng);
    const double cc = std::uniform_int_distribution<int>(0, 900)(rng);
    const int base_row = std::uniform_int_distribution<int>(0, rows - 1)(rng);
    const int column = std::uniform_int_distribution<int>(0, stride - 1)(rng);
    scalar::SteepColumn(on.data() + column, off.data() + column, stride, stride, r_first, r_last, threshold, min_d, u0,
                        per_row, 2.0, bins - 1, cc, base_row, scalar_moments.data());
    SteepColumnAvx2(on.data() + column, off.data() + column, stride, stride, r_first, r_last, threshold, min_d, u0,
                    per_row, 2.0, bins - 1, cc, base_row, avx2_moments.data());
    ASSERT_EQ(0, std::memcmp(scalar_moments.data(), avx2_moments.data(), scalar_moments.size() * sizeof(double)))
        << "trial " << trial;
    added += r_last >= r_first;
  }
  EXPECT_GT(added, 2000);
}

// RecentreLineEnds (ends.cc) with its AVX2 row sums (AcrossRowSumsAvx2) against its scalar loop, bit for
// bit: random steep lines (1.2-6 columns per row, either sign) ending inside the frame, saturated in places
// (the laser-on frame at 255 over a lit laser-off frame), in gray frames and in the red channel of color
// ones (a pixel every 3 bytes), their points a little off the line.
TEST(KernelsTest, LineEndsAvx2MatchesScalar) {
  if (!HaveAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  std::mt19937 rng(41);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  int measured = 0;
  for (int trial = 0; trial < 60; ++trial) {
    const int rows = 120, cols = 400;
    const double slope = (1.2 + 4.8 * unit(rng)) * (unit(rng) < 0.5 ? -1 : 1);
    const int first = 10 + static_cast<int>(20 * unit(rng)), last = first + 40 + static_cast<int>(30 * unit(rng));
    const double c_mid = cols / 2.0, sigma = 1.5 + 2 * unit(rng), peak = 30 + 300 * unit(rng);
    const int r_mid = (first + last) / 2;
    cv::Mat on(rows, cols, CV_8UC1), off(rows, cols, CV_8UC1);
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c < cols; ++c) {
        const int b = static_cast<int>(40 * unit(rng)) + (c % 17 == 0 ? 200 : 0);
        // The distance across the line; the line is lit only between its end rows (give or take a row).
        const double across = (c - c_mid - slope * (r - r_mid)) / std::sqrt(1 + slope * slope);
        const double along_row = r + (c - c_mid - slope * (r - r_mid)) * slope / (1 + slope * slope);
        const bool lit = along_row >= first && along_row <= last;
        const int a = b + (lit ? static_cast<int>(peak * std::exp(-0.5 * across * across / (sigma * sigma))) : 0) +
                      static_cast<int>(3 * unit(rng));
        off.at<uint8_t>(r, c) = static_cast<uint8_t>(b);
        on.at<uint8_t>(r, c) = static_cast<uint8_t>(std::min(a, 255));
      }
    }
    std::vector<LinePoint> points;
    for (int r = first; r <= last; ++r) {
      LinePoint& p = points.emplace_back();
      p.row = r;
      p.column = static_cast<float>(c_mid + slope * (r - r_mid) + (unit(rng) - 0.5) * 1.5);
      p.peak = static_cast<float>(std::min(255.0, peak) * (0.8 + 0.2 * unit(rng)));
      p.width = static_cast<float>(2.355 * sigma * std::sqrt(1 + slope * slope));
      p.uncertainty_px = static_cast<float>(0.2 + unit(rng));
    }
    for (const int channels : {1, 3}) {
      cv::Mat on_frame = on, off_frame = off;
      if (channels == 3) {
        const cv::Mat other(rows, cols, CV_8UC1, cv::Scalar(90));
        cv::merge(std::vector<cv::Mat>{other, other, on}, on_frame);
        cv::merge(std::vector<cv::Mat>{other, other, off}, off_frame);
      }
      const int channel = channels == 3 ? 2 : 0;
      const int threshold = 8 + trial % 20;
      std::vector<LinePoint> scalar_points = points, avx2_points = points;
      internal::AllowVectorExtensions(false, false);
      const int scalar_count = RecentreLineEnds(on_frame, off_frame, channel, threshold, &scalar_points);
      internal::AllowVectorExtensions(true, true);
      const int avx2_count = RecentreLineEnds(on_frame, off_frame, channel, threshold, &avx2_points);
      ASSERT_EQ(scalar_count, avx2_count) << "trial " << trial << " channels " << channels;
      for (size_t i = 0; i < points.size(); ++i) {
        ASSERT_EQ(0, std::memcmp(&scalar_points[i].column, &avx2_points[i].column, sizeof(float)))
            << "trial " << trial << " channels " << channels << " point " << i;
      }
      measured += avx2_count;
    }
  }
  EXPECT_GT(measured, 500);  // the end rows were measured, not skipped
}

// The whole extraction with every vector extension the CPU has against SSE2 alone, every field of every
// point bit for bit: saturated lines with notches, weak wide ones, two lines in a row, noise, rows
// narrower than a vector, every estimator, smoothing on and off.
TEST(KernelsTest, ExtractionIsBitIdenticalOnEveryPath) {
  std::vector<std::pair<cv::Mat, cv::Mat>> pairs;
  std::mt19937 rng(31);
  std::uniform_int_distribution<int> byte(0, 255), coin(0, 5);
  for (int i = 0; i < 8; ++i) {
    const int cols = i % 4 == 3 ? 13 : std::uniform_int_distribution<int>(40, 700)(rng), rows = 96;
    cv::Mat on(rows, cols, CV_8UC1), off(rows, cols, CV_8UC1);
    for (int r = 0; r < rows; ++r) {
      const int c1 = cols / 2 + static_cast<int>(cols / 3 * std::sin(0.05 * r + i));
      const int c2 = std::uniform_int_distribution<int>(0, cols - 1)(rng);
      const int amp2 = std::uniform_int_distribution<int>(10, 300)(rng), wide = std::uniform_int_distribution<int>(1, 40)(rng);
      for (int x = 0; x < cols; ++x) {
        const int b = i % 4 == 1 ? 250 : (coin(rng) == 0 ? byte(rng) : 40 + (x * 7) % 50);
        int a = b + std::max(0, 300 - 30 * std::abs(x - c1)) + std::max(0, amp2 - amp2 * std::abs(x - c2) / wide) + coin(rng);
        if (coin(rng) == 0) a = byte(rng);
        off.at<uint8_t>(r, x) = static_cast<uint8_t>(b);
        on.at<uint8_t>(r, x) = static_cast<uint8_t>(std::min(a, 255));
      }
    }
    pairs.emplace_back(on, off);
  }
  auto extract_all = [&](bool wide, Estimator estimator, int smooth) {
    internal::AllowVectorExtensions(wide, wide);
    ExtractOptions options;
    options.estimator = estimator;
    options.smooth_half_rows = smooth;
    LineExtractor extractor(options);
    std::vector<Line> lines(pairs.size());
    for (size_t k = 0; k < pairs.size(); ++k) EXPECT_TRUE(extractor.Extract(pairs[k].first, pairs[k].second, &lines[k]).ok());
    internal::AllowVectorExtensions(true, true);
    return lines;
  };
  size_t points = 0;
  for (Estimator estimator : {Estimator::kCenterOfMass, Estimator::kParabolic, Estimator::kGaussian, Estimator::kZeroCrossing}) {
    for (int smooth : {0, 12}) {
      const std::vector<Line> wide = extract_all(true, estimator, smooth), narrow = extract_all(false, estimator, smooth);
      for (size_t k = 0; k < pairs.size(); ++k) {
        ASSERT_EQ(wide[k].points.size(), narrow[k].points.size()) << "frame " << k;
        for (size_t j = 0; j < wide[k].points.size(); ++j) {
          const LinePoint &a = wide[k].points[j], &b = narrow[k].points[j];
          const bool same = a.row == b.row && a.flags == b.flags && std::memcmp(&a.column, &b.column, 4) == 0 &&
                            std::memcmp(&a.peak, &b.peak, 4) == 0 && std::memcmp(&a.width, &b.width, 4) == 0 &&
                            std::memcmp(&a.quality, &b.quality, 4) == 0 &&
                            std::memcmp(&a.uncertainty_px, &b.uncertainty_px, 4) == 0;
          ASSERT_TRUE(same) << "estimator " << EstimatorName(estimator) << " smooth " << smooth << " frame " << k
                            << " point " << j;
        }
        points += wide[k].points.size();
      }
    }
  }
  EXPECT_GT(points, 1000u);  // the frames hold lines
}

// The gap step's window rows in AVX2 (GapWindowAvx2, gaps.cc's FillLineGaps, fourteenth session) against its
// scalar loop, every point bit for bit: a faint curved line (its slope from 0.05 to ~3 columns per row, so
// both the near-vertical windows and the banded steep ones) on a lit, noisy background whose rows drop
// below the row pass's threshold in runs of 2-6 (rows the gap step fills), in gray frames and in the red
// channel of color ones (a pixel every 3 bytes), near the frame's edges too.
TEST(KernelsTest, GapWindowAvx2MatchesScalar) {
  if (!HaveAvx2()) GTEST_SKIP() << "no AVX2 on this CPU";
  std::mt19937 rng(53);
  std::normal_distribution<double> noise(0.0, 1.6);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  size_t filled = 0;
  for (int trial = 0; trial < 12; ++trial) {
    const int rows = 240, cols = trial % 4 == 3 ? 150 : 400, channels = trial % 2 == 0 ? 1 : 3;
    cv::Mat on(rows, cols, CV_8UC(channels)), off(rows, cols, CV_8UC(channels));
    const double c_start = trial % 4 == 3 ? 6 + 10 * unit(rng) : 40 + 200 * unit(rng);
    const double slope = (0.05 + 1.5 * unit(rng)) * (unit(rng) < 0.5 ? -1 : 1), bend = 0.004 * (unit(rng) - 0.5);
    int dim_left = 0;
    for (int r = 0; r < rows; ++r) {
      if (dim_left == 0 && unit(rng) < 0.08) dim_left = 2 + static_cast<int>(5 * unit(rng));
      const double amplitude = dim_left > 0 ? 9.0 : 40.0;
      if (dim_left > 0) --dim_left;
      const double centre = c_start + std::abs(slope) * r + bend * r * r;
      const double sigma = 1.5 * std::sqrt(1 + slope * slope);
      for (int x = 0; x < cols; ++x) {
        const double off_value = 60 + 10 * std::sin(0.07 * x + 0.03 * r) + noise(rng);
        const double u = (x - (slope > 0 ? centre : cols - 1 - centre)) / sigma;
        const double on_value = off_value + amplitude * std::exp(-0.5 * u * u) + noise(rng);
        for (int k = 0; k < channels; ++k) {
          off.ptr<uint8_t>(r)[x * channels + k] = cv::saturate_cast<uint8_t>(k == channels - 1 ? off_value : 30.0);
          on.ptr<uint8_t>(r)[x * channels + k] = cv::saturate_cast<uint8_t>(k == channels - 1 ? on_value : 30.0);
        }
      }
    }
    std::vector<LinePoint> wide, narrow;
    for (const bool avx2 : {true, false}) {
      internal::AllowVectorExtensions(avx2, true);
      ExtractOptions options;
      options.smooth_half_rows = 0;
      options.steep_across = false;
      options.line_ends = false;
      options.junction_rows = false;
      Line line;
      EXPECT_TRUE(LineExtractor(options).Extract(on, off, &line).ok());
      internal::AllowVectorExtensions(true, true);
      (avx2 ? wide : narrow) = line.points;
      if (avx2) filled += static_cast<size_t>(line.stats.gap_filled);
    }
    ASSERT_EQ(wide.size(), narrow.size()) << "trial " << trial;
    for (size_t j = 0; j < wide.size(); ++j) {
      const LinePoint &a = wide[j], &b = narrow[j];
      ASSERT_TRUE(a.row == b.row && a.flags == b.flags && std::memcmp(&a.column, &b.column, 4) == 0 &&
                  std::memcmp(&a.peak, &b.peak, 4) == 0 && std::memcmp(&a.width, &b.width, 4) == 0 &&
                  std::memcmp(&a.quality, &b.quality, 4) == 0 &&
                  std::memcmp(&a.uncertainty_px, &b.uncertainty_px, 4) == 0)
          << "trial " << trial << " point " << j << " row " << a.row;
    }
  }
  EXPECT_GT(filled, 50u) << filled;  // the gap step filled rows (so its window rows were summed)
}
#endif  // ROTOSCAN_HAVE_SSSE3_PATH

}  // namespace
}  // namespace rotoscan::laser::detail
