// Laser line extraction: design notes.
//
// One pass per row, row-major, no allocation per row (the row buffer lives in the extractor):
//  1. d[i] = max(on[i] - off[i], 0) on the laser channel (differential imaging, paper §3.1) and the row
//     maximum, in one loop the compiler vectorises (saturating byte subtraction).
//  2. If the maximum is below the detection threshold T = max(min_contrast_dn, min_snr * noise) the row
//     has no laser (the common case for rows above and below the object: it costs only step 1).
//  3. Otherwise the candidates are the runs of d >= T (16-byte blocks with nothing above T are skipped
//     with one SSE2 compare). For each run: its peak p, the half-maximum extent [a, b] around the peak,
//     the width at half maximum (edges interpolated linearly), and whether the laser-off frame is
//     saturated under it (a specular highlight that hides the laser).
//  4. Candidates narrower than min_width (glints, hot pixels) or wider than max_width (ambient blobs) are
//     dropped. Of the others the highest peak wins; a rival within multiple_peak_ratio of it flags the row
//     (kFlagMultiplePeaks), and then the one nearer the previous row's point wins (lines are continuous).
//  5. The sub-pixel centre of the winner, by the chosen estimator.
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
#include <cmath>
#include <cstring>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "rotoscan/core/check.h"

namespace rotoscan::laser {
namespace {

// The centre of mass weighs d - kCenterOfMassLevel * peak over the run above that level. Measured on the
// synthetic cases of EstimatorComparison with levels 0.5, 0.35, 0.25, 0.2, 0.15 and 0.1: below 0.25 the
// wide weak line gains (more pixels average the noise, 0.092 -> 0.073 px) and nothing loses; 0.15 keeps a
// margin of 6 sigma over a 60 DN line's noise floor.
constexpr double kCenterOfMassLevel = 0.15;

struct Candidate {
  int peak_pos = 0;  // first pixel at the peak value
  int peak = 0;
  int first = 0;  // half-maximum extent, inclusive
  int last = 0;
  double width = 0;
  bool off_saturated = false;
};

// Robust noise sigma of (on - off) from a sparse sample: 1.4826 * MAD, the median interpolated within
// the integer histogram bins so that sub-DN noise is not rounded to 0 or 1.
double EstimateNoise(const cv::Mat& on, const cv::Mat& off, int channel) {
  const int channels = on.channels();
  std::array<uint32_t, 511> histogram{};
  // 16 rows, every 4th pixel: ~5,000 samples at 1288x964, enough for a MAD to a few percent, and cheap
  // (a denser sample was 17% of the extraction time).
  const int row_step = std::max(1, on.rows / 16);
  const int col_step = on.cols >= 256 ? 4 : 1;
  uint32_t total = 0;
  for (int r = row_step / 2; r < on.rows; r += row_step) {
    const uint8_t* a = on.ptr<uint8_t>(r);
    const uint8_t* b = off.ptr<uint8_t>(r);
    for (int c = 0; c < on.cols; c += col_step) {
      const int k = c * channels + channel;
      ++histogram[static_cast<size_t>(int{a[k]} - int{b[k]} + 255)];
      ++total;
    }
  }
  if (total < 16) return 0.0;
  auto interpolated_median = [&](const auto& hist, int bins, uint32_t count) {
    const double half = 0.5 * count;
    double cumulative = 0;
    for (int k = 0; k < bins; ++k) {
      if (cumulative + hist[static_cast<size_t>(k)] >= half && hist[static_cast<size_t>(k)] > 0) {
        return k - 0.5 + (half - cumulative) / hist[static_cast<size_t>(k)];
      }
      cumulative += hist[static_cast<size_t>(k)];
    }
    return static_cast<double>(bins - 1);
  };
  const double median = interpolated_median(histogram, 511, total) - 255.0;
  std::array<uint32_t, 512> deviation{};
  const int m = static_cast<int>(std::lround(median));
  for (int k = 0; k < 511; ++k) deviation[static_cast<size_t>(std::abs(k - 255 - m))] += histogram[k];
  // Deviations are integers: bin 0 holds |x - m| in [0, 0.5), bin j holds [j - 0.5, j + 0.5).
  const double mad = std::max(0.0, interpolated_median(deviation, 512, total) + 0.0);
  return 1.4826 * std::max(0.0, mad);
}

// Scratch of the along-line smoothing's fast path, per thread (SmoothAlongLine is a free function with a
// public signature; a thread-local buffer keeps it allocation-free from the second frame on).
std::vector<double>& prefix_scratch() {
  thread_local std::vector<double> buffer;
  return buffer;
}

// Linear position where d crosses `level` between i (below) and j (at or above), j = i +- 1.
inline double Crossing(const uint8_t* d, int below, int above, double level) {
  const double lo = d[below];
  const double hi = d[above];
  const double t = hi > lo ? (level - lo) / (hi - lo) : 0.5;
  return below + t * (above - below);
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
      const double level = kCenterOfMassLevel * peak;
      while (first > 0 && d[first - 1] > level) --first;
      while (last < size - 1 && d[last + 1] > level) ++last;
      double sum_w = 0, sum_wx = 0;
      for (int i = first; i <= last; ++i) {
        const double w = d[i] - level;
        if (w > 0) {
          sum_w += w;
          sum_wx += w * i;
        }
      }
      if (sum_w <= 0) return 0.5 * (first + last);  // a flat run exactly at half maximum
      return sum_wx / sum_w;
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

// Color input is read in bands of kBandRows rows: OpenCV's vectorised cv::split deinterleaves a band of
// both frames into small buffers that stay in the L2 cache, and the row loop reads the laser channel
// there (cv::extractChannel goes through the generic, scalar mixChannels: 3x slower). The frames are read from memory once, instead of once by a whole-frame channel copy
// and again by the row loop (laser_bench BM_ExtractBgr: 913 -> see README).
constexpr int kBandRows = 32;

Status LineExtractor::ExtractRows(const cv::Mat& on, const cv::Mat& off, int channel, Line* line) {
  const ExtractOptions& o = options_;
  const int rows = on.rows;
  const int cols = on.cols;
  const bool banded = on.channels() > 1;
  line->points.clear();
  line->stats = LineStats{};
  LineStats& stats = line->stats;
  stats.rows = rows;
  stats.noise_dn = o.noise_dn > 0 ? o.noise_dn : EstimateNoise(on, off, channel);
  const double threshold_real = std::max(o.min_contrast_dn, o.min_snr * stats.noise_dn);
  const int threshold = static_cast<int>(std::ceil(std::min(threshold_real, 255.0)));
  stats.threshold_dn = threshold;
  diff_.resize(static_cast<size_t>(cols) + 16);
  block_starts_.resize(static_cast<size_t>(cols) / 16 + 2);
  block_masks_.resize(static_cast<size_t>(cols) / 16 + 2);
  uint8_t* d = diff_.data();

  std::array<Candidate, 32> candidates;
  double previous_column = -1.0;
  int previous_row = -10;
  for (int r = 0; r < rows; ++r) {
    const uint8_t* a;
    const uint8_t* b;
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
    }
    // Step 1: saturating difference, and the 16-pixel blocks that hold a pixel >= threshold, compacted
    // into (start, bit mask) pairs without a branch. Nothing else is read per pixel, so a row without
    // the laser costs two loads, four vector instructions and a store per 16 pixels (the loop runs at
    // the memory-bandwidth bound, laser_bench). A width that is not a multiple of 16 ends with one
    // overlapping block whose already-seen bits are cleared.
    int block_count = 0;
    {
      int* starts = block_starts_.data();
      uint16_t* masks = block_masks_.data();
      auto push = [&](int start, unsigned mask) {
        starts[block_count] = start;
        masks[block_count] = static_cast<uint16_t>(mask);
        block_count += mask != 0;
      };
      int i0 = 0;
#if defined(__SSE2__)
      const __m128i t = _mm_set1_epi8(static_cast<char>(threshold));
      auto block = [&](int at) {
        const __m128i v = _mm_subs_epu8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(a + at)),
                                        _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + at)));
        _mm_storeu_si128(reinterpret_cast<__m128i*>(d + at), v);
        return static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(v, t), v)));
      };
      for (; i0 + 16 <= cols; i0 += 16) push(i0, block(i0));
      if (i0 < cols && cols >= 16) {
        const int at = cols - 16;
        push(at, block(at) & ~((1u << (i0 - at)) - 1u));
        i0 = cols;
      }
#endif
      for (; i0 < cols; i0 += 16) {  // portable path (and images narrower than 16 pixels)
        unsigned mask = 0;
        for (int k = 0; k < 16 && i0 + k < cols; ++k) {
          const uint8_t x = a[i0 + k], y = b[i0 + k];
          d[i0 + k] = static_cast<uint8_t>(x > y ? x - y : 0);
          mask |= static_cast<unsigned>(d[i0 + k] >= threshold) << k;
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
    auto add_run = [&](int run_first, int run_last) {
      if (count >= static_cast<int>(candidates.size())) return;
      Candidate& c = candidates[static_cast<size_t>(count)];
      c.peak_pos = run_first;
      c.peak = d[run_first];
      for (int i = run_first + 1; i <= run_last; ++i) {
        if (d[i] > c.peak) {
          c.peak = d[i];
          c.peak_pos = i;
        }
      }
      const double half = 0.5 * c.peak;
      int lo = c.peak_pos, hi = c.peak_pos;
      while (lo > 0 && d[lo - 1] >= half) --lo;
      while (hi < cols - 1 && d[hi + 1] >= half) ++hi;
      c.first = lo;
      c.last = hi;
      const double left = lo > 0 ? Crossing(d, lo - 1, lo, half) : lo - 0.5;
      const double right = hi < cols - 1 ? Crossing(d, hi + 1, hi, half) : hi + 0.5;
      c.width = right - left;
      c.off_saturated = b[c.peak_pos] >= o.off_saturation_dn;
      // A run inside the half-maximum extent of the previous candidate is the same line (a noise dip).
      if (count > 0 && candidates[static_cast<size_t>(count - 1)].last >= lo) {
        Candidate& prev = candidates[static_cast<size_t>(count - 1)];
        if (c.peak > prev.peak) prev = c;
        return;
      }
      ++count;
    };
    int run_start = -1, run_last = -2;
    for (int k = 0; k < block_count; ++k) {
      const int base = block_starts_[static_cast<size_t>(k)];
      unsigned mask = block_masks_[static_cast<size_t>(k)];
      while (mask != 0) {
        const int j = base + __builtin_ctz(mask);
        mask &= mask - 1;
        if (j != run_last + 1) {
          if (run_start >= 0) add_run(run_start, run_last);
          run_start = j;
        }
        run_last = j;
      }
    }
    add_run(run_start, run_last);

    // Step 4: plausibility.
    int best = -1;
    bool any_off_saturated = false;
    for (int k = 0; k < count; ++k) {
      const Candidate& c = candidates[static_cast<size_t>(k)];
      if (c.off_saturated) {
        any_off_saturated = true;
        continue;
      }
      if (c.width < o.min_width_px || c.width > o.max_width_px) continue;
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
    const bool continuous = previous_column >= 0 && r - previous_row <= 2;
    for (int k = 0; k < count; ++k) {
      const Candidate& c = candidates[static_cast<size_t>(k)];
      if (k == best || c.off_saturated || c.width < o.min_width_px || c.width > o.max_width_px) continue;
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
    const double column = EstimateCentre(o.estimator, d, cols, c.first, c.last, c.peak);
    if (column < 0) {
      ++stats.bad_width;
      continue;
    }
    if (a[c.peak_pos] == 255) flags |= kFlagSaturated;
    if (c.first == 0 || c.last == cols - 1) flags |= kFlagClipped;
    double quality = 1.0;
    if (stats.noise_dn > 0)
      quality *= std::min(1.0, c.peak / (stats.noise_dn * std::max(1.0, 4 * o.min_snr)));
    quality *= std::min(1.0, (c.peak - 0.5 * threshold) / std::max(1.0, 2.0 * threshold));
    if (c.width < 1.5 * o.min_width_px || c.width > o.max_width_px / 1.5) quality *= 0.6;
    if (flags & kFlagMultiplePeaks) quality *= 0.5;
    if (flags & kFlagClipped) quality *= 0.3;
    LinePoint p;
    p.row = r;
    p.column = static_cast<float>(column);
    p.peak = static_cast<float>(c.peak);
    p.width = static_cast<float>(c.width);
    p.quality = static_cast<float>(std::clamp(quality, 0.0, 1.0));
    p.flags = flags;
    line->points.push_back(p);
    ++stats.found;
    if (flags & kFlagMultiplePeaks) ++stats.multiple_peaks;
    previous_column = column;
    previous_row = r;
  }
  if (o.smooth_half_rows > 0) {
    SmoothAlongLine(&line->points, o.smooth_half_rows, o.smooth_order, o.smooth_max_jump_px,
                    o.smooth_outlier_px, &raw_columns_);
  }
  return Status::Ok();
}

void SmoothAlongLine(std::vector<LinePoint>* points, int half_rows, int order, double max_jump_px,
                     double outlier_px, std::vector<float>* scratch) {
  ROTOSCAN_CHECK(points != nullptr && scratch != nullptr && half_rows >= 0 && order >= 0 && order <= 2);
  const int n = static_cast<int>(points->size());
  if (half_rows == 0 || n < 2) return;
  LinePoint* p = points->data();
  scratch->resize(static_cast<size_t>(n));
  float* raw = scratch->data();
  for (int i = 0; i < n; ++i) raw[i] = p[i].column;
  // Weighted least-squares polynomial c(x) = a + b x (+ q x^2 for degree 2) through the neighbours j of
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
  auto robust_fit_from = [&](int i, int lo, int hi, const Fit& first) {
    auto explained = [&](int j) {
      const double x = j - i;
      return j == i || std::abs(raw[j] - (first.a + x * (first.b + x * first.q))) <= outlier_px;
    };
    bool all = true;
    for (int j = lo; j <= hi && all; ++j) all = explained(j);
    return all ? first.a : fit(i, lo, hi, explained).a;
  };
  auto robust_fit = [&](int i, int lo, int hi) {
    return robust_fit_from(i, lo, hi, fit(i, lo, hi, [](int) { return true; }));
  };
  // Fast path for a point whose window [i - h, i + h] lies inside its stretch, for order 0 and 1 (the
  // common case: all but 2h points of each stretch). The window is symmetric, so the odd moment s1
  // vanishes and the fit is a = t0 / s0, b = t1 / s2, with t0 = sum w y and t1 = sum w x y over the
  // triangular weights w = h + 1 - |x|. A triangle of half-width h is a box of h + 1 taps convolved with
  // itself, and t1 = tri(j y_j)(i) - i tri(y)(i), so both come from prefix sums in O(1) per point (the
  // direct sums cost 2h + 1 dependent additions each). Columns are taken relative to the stretch's first
  // column to keep the sums small. When a neighbour fails the outlier test, the general fit decides.
  const int h = half_rows;
  const int box = h + 1;
  double s0_sym = 0, s2_sym = 0;
  for (int x = -h; x <= h; ++x) {
    const double w = h + 1 - std::abs(x);
    s0_sym += w;
    s2_sym += w * x * x;
  }
  std::vector<double>& prefix = prefix_scratch();
  auto smooth_stretch = [&](int start, int end) {
    const int len = end - start + 1;
    const double origin = raw[start];
    const bool fast = order <= 1 && len >= 2 * h + 1;
    if (fast) {
      // Layout: P_y, P_jy (prefix sums of y and j y, j from the stretch start), then the box sums of both
      // over box taps starting at each index, then their prefix sums.
      const size_t m = static_cast<size_t>(len);
      prefix.assign(6 * (m + 1), 0.0);
      double* py = prefix.data();
      double* pjy = py + (m + 1);
      double* by = pjy + (m + 1);
      double* bjy = by + (m + 1);
      double* qy = bjy + (m + 1);
      double* qjy = qy + (m + 1);
      for (int k = 0; k < len; ++k) {
        const double y = raw[start + k] - origin;
        py[k + 1] = py[k] + y;
        pjy[k + 1] = pjy[k] + k * y;
      }
      const int boxes = len - box + 1;  // box sums over [k, k + h]
      for (int k = 0; k < boxes; ++k) {
        by[k] = py[k + box] - py[k];
        bjy[k] = pjy[k + box] - pjy[k];
        qy[k + 1] = qy[k] + by[k];
        qjy[k + 1] = qjy[k] + bjy[k];
      }
      for (int k = h; k + h < len; ++k) {
        // tri(v)(k) = sum_{u = k - h}^{k} box(v)[u]: u runs over the h + 1 box starts whose box covers k.
        const double t0 = qy[k + 1] - qy[k - h];
        const double t1 = (qjy[k + 1] - qjy[k - h]) - k * t0;
        const double fa = t0 / s0_sym;
        const double fb = order >= 1 ? t1 / s2_sym : 0.0;
        const int i = start + k;
        bool explained = true;
        for (int x = -h; x <= h; ++x) {
          explained &= std::abs(raw[i + x] - origin - (fa + x * fb)) <= outlier_px;
        }
        if (explained) {
          p[i].column = static_cast<float>(fa + origin);
        } else {
          Fit first;  // the fit above, in the general fit's terms
          first.a = fa + origin;
          first.b = fb;
          p[i].column = static_cast<float>(robust_fit_from(i, i - h, i + h, first));
        }
      }
    }
    for (int i = start; i <= end; ++i) {
      if (fast && i - h >= start && i + h <= end) continue;
      const int lo = std::max(start, i - h), hi = std::min(end, i + h);
      if (lo == hi) continue;
      p[i].column = static_cast<float>(robust_fit(i, lo, hi));
    }
  };
  int start = 0;  // first point of the current stretch
  while (start < n) {
    int end = start;  // last point of the stretch, inclusive
    while (end + 1 < n && p[end + 1].row == p[end].row + 1 &&
           std::abs(raw[end + 1] - raw[end]) <= max_jump_px) {
      ++end;
    }
    smooth_stretch(start, end);
    start = end + 1;
  }
}

Result<cv::Mat> ReadImage8(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return NotFoundError(path.string() + " does not exist");
  cv::Mat image = cv::imread(path.string(), cv::IMREAD_UNCHANGED);
  if (image.empty()) return CorruptDataError(path.string() + " cannot be decoded as an image");
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
