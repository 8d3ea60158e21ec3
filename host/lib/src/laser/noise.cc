// The detection threshold's noise estimate (design notes in extract.cc): the robust sigma of the
// difference from a sparse sample of the frame.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

#include "extract_steps.h"
#include "kernels.h"

namespace rotoscan::laser::detail {

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
        if (channels == 1) {  // the bins of 16 pixels at a time, then counted (kernels_sse2.simd.hpp)
          c = sse2::NoiseStretch(a, b, from, from + stretch, near, &partial);
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

}  // namespace rotoscan::laser::detail
