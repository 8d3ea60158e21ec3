// The detection threshold's noise estimate (design notes in extract.cc): the robust sigma of the
// difference from a sparse sample of the frame's lit pixels.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

#include "extract_steps.h"
#include "kernels.h"

namespace rotoscan::laser::detail {

namespace {

// The median of a histogram, interpolated within its integer bins so that sub-DN noise is not rounded
// to 0 or 1.
double InterpolatedMedian(const uint32_t* hist, int bins, uint32_t count) {
  const double half = 0.5 * count;
  double cumulative = 0;
  for (int k = 0; k < bins; ++k) {
    if (cumulative + hist[k] >= half && hist[k] > 0) return k - 0.5 + (half - cumulative) / hist[k];
    cumulative += hist[k];
  }
  return static_cast<double>(bins - 1);
}

// A sparse sample of the frame: `row_count` rows spread over it, in each `stretch_count` stretches of
// kStretch pixels spread over the row (the whole row when it is narrower than that many stretches).
struct SampleGrid {
  static constexpr int kStretch = 64;
  int row_step, row_first, stretches, stretch, cols;
  SampleGrid(int rows, int columns, int row_count, int stretch_count) : cols(columns) {
    row_step = std::max(1, rows / row_count);
    row_first = row_step / 2;
    stretches = columns >= stretch_count * kStretch ? stretch_count : 1;
    stretch = stretches > 1 ? kStretch : columns;
  }
  int Start(int j) const { return stretches > 1 ? (2 * j + 1) * cols / (2 * stretches) - kStretch / 2 : 0; }
};

// The histograms of the grid's samples whose laser-off value is at least min_off (the others in
// kNoiseDumpBin), differences clamped to [-near, near - 1]; returns how many were sampled.
uint32_t SampleHistograms(const cv::Mat& on, const cv::Mat& off, int channel, const SampleGrid& grid, int near,
                          int min_off, NoiseHistograms* partial) {
  const int channels = on.channels();
  const int bins = 2 * near;
  for (auto& h : *partial) {
    std::fill(h.begin(), h.begin() + bins, 0u);
    h[kNoiseDumpBin] = 0;
  }
  for (int r = grid.row_first; r < on.rows; r += grid.row_step) {
    const uint8_t* a = on.ptr<uint8_t>(r);
    const uint8_t* b = off.ptr<uint8_t>(r);
    for (int j = 0; j < grid.stretches; ++j) {
      const int from = grid.Start(j);
      int c = from, n = 0;
#if defined(__SSE2__)
      if (channels == 1) {  // the bins of 16 pixels at a time, then counted (kernels_sse2.simd.hpp)
        c = sse2::NoiseStretch(a, b, from, from + grid.stretch, near, min_off, partial);
        n = c - from;
      }
#endif
      for (; c < from + grid.stretch; ++c, ++n) {
        const int k = c * channels + channel;
        const int x = std::clamp(int{a[k]} - int{b[k]}, -near, near - 1);
        ++(*partial)[static_cast<size_t>(n & 3)][static_cast<size_t>(b[k] < min_off ? kNoiseDumpBin : x + near)];
      }
    }
  }
  uint32_t sampled = 0;
  for (int k = 0; k < bins; ++k) {
    for (const auto& h : *partial) sampled += h[static_cast<size_t>(k)];
  }
  return sampled;
}

}  // namespace

// Robust noise sigma of (on - off) from a sparse sample of the pixels lit in the laser-off frame
// (kNoiseMinOffDn, extract_steps.h): 1.4826 * MAD.
double EstimateNoise(const cv::Mat& on, const cv::Mat& off, int channel, bool* on_lit) {
  const int channels = on.channels();
  // First 16 rows spread over the frame, in each 4 stretches of 64 pixels spread over the row: ~4,000
  // samples at 1288x964, enough for a MAD to a few percent. The frames are not in the cache yet, so the
  // cost is the cache lines touched: contiguous stretches touch 1 in 5 of the sampled rows' lines (every
  // 4th pixel of whole rows touched them all and was ~13 % of a frame's extraction, laser_bench). Noise
  // fills few bins, so consecutive increments of one histogram would wait on each other's store; four
  // interleaved ones do not. When fewer than kNoiseMinSamples of those are lit (a small object on a dark
  // background: the webcam sets have 1-10 % of such a sample lit), 64 rows of 8 stretches (8x the
  // sample, ~2.7 % of the frame), and when these are still too few, every sampled pixel counts.
#if defined(__SSE2__)
  const bool on_everywhere = channels > 1;  // the per-pixel loop (every sampled pixel reads both frames)
#else
  const bool on_everywhere = true;
#endif
  NoiseHistograms partial;
  std::array<uint32_t, 512> histogram;
  std::array<uint32_t, 513> deviation;
  const SampleGrid grids[] = {SampleGrid(on.rows, on.cols, 16, 4), SampleGrid(on.rows, on.cols, 64, 8)};
  for (int pass = 0; pass < 3; ++pass) {
    const SampleGrid& grid = grids[pass == 0 ? 0 : 1];
    const int min_off = pass < 2 ? kNoiseMinOffDn : 0;
    // All the lines are requested first, so that their misses overlap instead of following one another.
    // The SSE2 stretch reads the laser-on frame only beside a laser-off pixel that is sampled, so on the
    // second pass, which runs only on a frame mostly black (the first found too few lit), the laser-on
    // lines are left to be read where needed: on a webcam frame ~90 % of the sample is black, and its
    // dump bin's increments and both frames' lines were the estimate's cost (laser_bench BM_Noise/1,
    // 17 -> 5.5 µs a frame; the same bits, laser_digest). On the first pass, and where every pixel is
    // read (the third pass, the per-pixel loop), both frames' lines are requested.
    for (int r = grid.row_first; r < on.rows; r += grid.row_step) {
      for (int j = 0; j < grid.stretches; ++j) {
        const size_t from = static_cast<size_t>(grid.Start(j) * channels);
        const size_t to = static_cast<size_t>((grid.Start(j) + grid.stretch) * channels);
        for (size_t k = from; k < to + 64; k += 64) {
          if (pass != 1 || on_everywhere) __builtin_prefetch(on.ptr<uint8_t>(r) + std::min(k, to - 1));
          __builtin_prefetch(off.ptr<uint8_t>(r) + std::min(k, to - 1));
        }
      }
    }
    // The differences go into bins of x + near clamped to [-near, near - 1]. First with near = 64: 128
    // bins to clear, add up and scan instead of 511 (the histogram's passes were most of the estimate's
    // time). The clamp moves only samples beyond +-64 DN; they stay on their side of the median, and of
    // the MAD when the MAD stays short of the clamped edges, so then the result is that of the full
    // histogram. Otherwise (noise of tens of DN) the sample is taken again with near = 256, i.e. without
    // a clamp.
    for (const int near : {64, 256}) {
      const int bins = 2 * near;
      const uint32_t total = SampleHistograms(on, off, channel, grid, near, min_off, &partial);
      if (total < (min_off > 0 ? kNoiseMinSamples : 16u)) break;  // too few lit: the next pass
      for (int k = 0; k < bins; ++k) histogram[k] = partial[0][k] + partial[1][k] + partial[2][k] + partial[3][k];
      const double median = InterpolatedMedian(histogram.data(), bins, total) - near;
      const int m = static_cast<int>(std::lround(median));
      // Deviations are integers: bin 0 holds |x - m| in [0, 0.5), bin j holds [j - 0.5, j + 0.5).
      std::fill(deviation.begin(), deviation.begin() + bins + 1, 0u);
      for (int k = 0; k < bins; ++k) deviation[static_cast<size_t>(std::abs(k - near - m))] += histogram[k];
      const double mad = std::max(0.0, InterpolatedMedian(deviation.data(), bins + 1, total));
      // Exact when the median's bin and the MAD's lie inside the clamped edges (the edge bins hold
      // everything beyond them).
      const int edge = std::min(near + m, near - 1 - m);  // the clamped edges' deviation
      if (near == 256 || (m > -near && m < near - 1 && std::lround(mad) + 1 < edge)) {
        *on_lit = min_off > 0;
        return 1.4826 * mad;
      }
    }
  }
  *on_lit = false;
  return 0.0;  // no frame holds fewer than 16 pixels here: the extractor's callers check its size
}

}  // namespace rotoscan::laser::detail
