// Extraction + triangulation speed at 1288x964, 8-bit, one core (DESIGN.md "Targets": >= 3,000 laser
// frames/s, >= 20x a straightforward OpenCV centre-of-mass pipeline, within 2x of the memory-bandwidth
// bound). All in one run so the figures are comparable:
//
//   BM_ExtractTriangulate/<estimator>/<smoothing>/<cached>  our extractor + triangulation (distorted
//                                      camera); cached = 1: one pair of frames over and over (the compute)
//   BM_ExtractBgr                      the same on 3-channel BGR frames (channel split included)
//   BM_RowPassOnly                     our row pass alone (frames swapped: no row holds a line)
//   BM_HorusBaseline                   what bq Horus does, with whole-image OpenCV operations as Horus does
//                                      with NumPy (and NumPy's float64): subtract, threshold, blur, a window
//                                      around each row's maximum, centre of mass by a weight matrix, the
//                                      segmented Gaussian filter along the line, undistortPoints, plane
//   BM_HorusBaselineBgr                the same on color frames (subtract the color images, split, red),
//                                      as Horus runs with a color camera: compare with BM_ExtractBgr
//   BM_OpenCvTunedBaseline             the same with a per-row window loop (faster than Horus; reported too)
//   BM_StreamRead/<order>              the memory-bandwidth bound: a plain read of the same bytes (both
//                                      frames) in three orders (0 frame after frame, 1 row by row through
//                                      both, 2 the same prefetched); the fastest is the bound, i.e. the
//                                      fastest any single-pass extractor could go
//   BM_StreamReadBgr/<order>           the same bound for the color frames of BM_ExtractBgr
//
//   BM_ExtractWebcam/<smoothing>       the same on typical frames: rendered webcam frames (below), their
//                                      red channel as gray; compare with BM_StreamReadWebcam
//   BM_Noise/<frames>                  the noise sample alone (the threshold's): 0 the frames above,
//                                      1 the typical frames
//   BM_WebcamStep/<step>               a step after the row loop alone on the typical frames: 0 the gap
//                                      step, 1 the steep step, 2 the line ends, 3 the smoothing (points:
//                                      filled / moved / measured / smoothed per frame); second argument 1:
//                                      one pair, cached
//
// Frames: 16 different pairs (40 MB, more than the caches) of a webcam-like line (12 px wide, saturated,
// 1.4 DN noise) crossing every row: the worst case, a real object covers fewer rows; and the line is
// steep (over 1 column per row) in half the rows, where the steep step (steep.cc) measures it across.
// The typical frames: 16 pairs rendered from glossy-webcam.json and textured-webcam.json (1280x960, 4
// table angles x 2 lasers each; the object's line, the table's, glints, texture), ~10 s to render at the
// start of the first benchmark that uses them.
// Run: build/host/bench/laser/laser_bench --benchmark_repetitions=5 (medians; on an idle machine)
#include <benchmark/benchmark.h>
#include <emmintrin.h>

#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "laser/extract_steps.h"
#include "rotoscan/geometry/camera.h"
#include "rotoscan/geometry/plane.h"
#include "rotoscan/laser/extract.h"
#include "rotoscan/laser/triangulate.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"
#include "synthetic_line.h"

namespace {

using rotoscan::laser::testing::LineSpec;

constexpr int kWidth = 1288;
constexpr int kHeight = 964;
constexpr int kPairs = 16;

struct Frames {
  std::vector<cv::Mat> on, off;
};

const Frames& GrayFrames() {
  static const Frames frames = [] {
    Frames f;
    LineSpec spec;
    spec.amplitude = 400;
    spec.sigma = 2.0;
    spec.flat_half_width = 3.5;
    for (int i = 0; i < kPairs; ++i) {
      cv::Mat on, off;
      rotoscan::laser::testing::MakePair(
          kWidth, kHeight, spec, [i](int r) { return 644.0 + 150.0 * std::sin(r * 0.01 + i); }, 100 + i, &on,
          &off);
      f.on.push_back(on);
      f.off.push_back(off);
    }
    return f;
  }();
  return frames;
}

const Frames& BgrFrames() {
  static const Frames frames = [] {
    Frames f;
    const Frames& gray = GrayFrames();
    for (int i = 0; i < kPairs / 2; ++i) {
      cv::Mat on, off;
      const cv::Mat green(kHeight, kWidth, CV_8UC1, cv::Scalar(90));
      cv::merge(std::vector<cv::Mat>{green, green, gray.on[i]}, on);
      cv::merge(std::vector<cv::Mat>{green, green, gray.off[i]}, off);
      f.on.push_back(on);
      f.off.push_back(off);
    }
    return f;
  }();
  return frames;
}

const Frames& WebcamFrames() {
  static const Frames frames = [] {
    Frames f;
    for (const char* file : {"glossy-webcam.json", "textured-webcam.json"}) {
      auto scene = rotoscan::sim::LoadScene(std::string(ROTOSCAN_SOURCE_DIR) + "/data/scenes/" + file);
      if (!scene.ok()) std::abort();
      auto renderer = rotoscan::sim::Renderer::Create(*scene);
      if (!renderer.ok()) std::abort();
      for (int step = 0; step < 4; ++step) {
        const rotoscan::sim::RenderedStep rendered = (*renderer)->RenderStep(
            step * 3.14159265358979323846 / 4, rotoscan::sim::FrameSeed(scene->seed, 0, step, 0), {true, true, true, false});
        cv::Mat off;
        cv::extractChannel(rendered.frames[2], off, 2);
        for (int k = 0; k < 2; ++k) {
          cv::Mat on;
          cv::extractChannel(rendered.frames[k], on, 2);
          f.on.push_back(on);
          f.off.push_back(k == 0 ? off : off.clone());  // each pair its own bytes
        }
      }
    }
    return f;
  }();
  return frames;
}

rotoscan::geometry::CameraModel Camera() {
  rotoscan::geometry::CameraModel camera =
      rotoscan::geometry::CameraModel::FromFieldOfView(kWidth, kHeight, 20.0);
  camera.distortion = {-0.12, 0.1, 0.0005, -0.0003, 0.0};
  return camera;
}

rotoscan::geometry::Plane Laser() {
  return rotoscan::geometry::Plane::FromPointNormal(Eigen::Vector3d(-173.2, 0, 0),
                                                    Eigen::Vector3d(300, 0, -173.2));
}

void SetCounters(benchmark::State& state, size_t bytes_per_frame) {
  state.SetItemsProcessed(state.iterations());  // items = laser frames
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * bytes_per_frame));
  state.counters["frames_per_s"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}

void BM_ExtractTriangulate(benchmark::State& state) {
  const Frames& f = GrayFrames();
  rotoscan::laser::ExtractOptions options;
  options.estimator = static_cast<rotoscan::laser::Estimator>(state.range(0));
  if (state.range(1) == 0) options.smooth_half_rows = 0;
  if (state.range(1) == 2) options.steep_across = false;  // smoothed, without the steep step
  rotoscan::laser::LineExtractor extractor(options);
  static const rotoscan::laser::Triangulator triangulator(Camera());
  const rotoscan::geometry::Plane plane = Laser();
  rotoscan::laser::Line line;
  std::vector<Eigen::Vector3d> points;
  std::vector<int> kept;
  // Third argument 1: one pair over and over (2.5 MB, held in the L3 cache): the compute without the
  // memory stream, steadier than the full run on a machine whose memory bandwidth others share.
  const size_t pairs = state.range(2) == 1 ? 1 : f.on.size();
  size_t i = 0, total_points = 0;
  for (auto _ : state) {
    const rotoscan::Status status = extractor.Extract(f.on[i], f.off[i], &line);
    benchmark::DoNotOptimize(status);
    triangulator.Triangulate(line, plane, &points, &kept);
    total_points += points.size();
    benchmark::DoNotOptimize(points.data());
    i = (i + 1) % pairs;
  }
  SetCounters(state, 2u * kWidth * kHeight);
  state.counters["points_per_frame"] =
      static_cast<double>(total_points) / std::max<int64_t>(1, state.iterations());
  state.SetLabel(std::string(rotoscan::laser::EstimatorName(options.estimator)) +
                 (options.smooth_half_rows > 0 ? " smoothed" : " per row") + (options.steep_across ? "" : ", no steep step") +
                 (pairs == 1 ? ", cached" : ""));
}
// Arguments: estimator (0 com = the default, 1 parabolic, 2 gaussian, 3 zero-crossing), along-line
// smoothing (1 = the default +-12 rows, 0 = off, 2 = on but the steep step off: the per-row work without
// it, which this frame's steep line makes ~2/3 of the whole), frames (0 = 16 pairs from memory, 1 = one
// cached pair).
BENCHMARK(BM_ExtractTriangulate)
    ->ArgsProduct({{0, 1, 2, 3}, {1}, {0}})
    ->Args({0, 0, 0})
    ->Args({0, 2, 0})
    ->Args({0, 2, 1})
    ->Args({0, 1, 1})
    ->Args({0, 0, 1})
    ->Unit(benchmark::kMicrosecond);

// Typical frames (WebcamFrames): the default extractor, smoothing on (1) or off (0) or on without the steep
// step (2) or without the line-end step (3, ends.cc), or the row loop alone (4: the noise sample, the row
// pass, the rows' points and their scores; no gap, steep or line-end step, no smoothing), or the default with
// the gap step's opt-in end part (5, ExtractOptions::extend_line_ends), and triangulation.
void BM_ExtractWebcam(benchmark::State& state) {
  const Frames& f = WebcamFrames();
  rotoscan::laser::ExtractOptions options;
  if (state.range(0) == 0 || state.range(0) == 4) options.smooth_half_rows = 0;
  if (state.range(0) == 2 || state.range(0) == 4) options.steep_across = false;
  if (state.range(0) == 3 || state.range(0) == 4) options.line_ends = false;
  if (state.range(0) == 4) options.fill_gaps = false;
  if (state.range(0) == 5) options.extend_line_ends = true;
  rotoscan::laser::LineExtractor extractor(options);
  static const rotoscan::laser::Triangulator triangulator(Camera());
  rotoscan::laser::Line line;
  std::vector<Eigen::Vector3d> points;
  std::vector<int> kept;
  size_t i = 0, total_points = 0;
  for (auto _ : state) {
    const rotoscan::Status status = extractor.Extract(f.on[i], f.off[i], &line);
    benchmark::DoNotOptimize(status);
    triangulator.Triangulate(line, Laser(), &points, &kept);
    total_points += points.size();
    benchmark::DoNotOptimize(points.data());
    i = (i + 1) % f.on.size();
  }
  SetCounters(state, 2u * f.on[0].total());
  state.counters["points_per_frame"] =
      static_cast<double>(total_points) / std::max<int64_t>(1, state.iterations());
}
BENCHMARK(BM_ExtractWebcam)->Arg(1)->Arg(0)->Arg(2)->Arg(3)->Arg(4)->Arg(5)->Unit(benchmark::kMicrosecond);

// The noise sample alone (noise.cc, the first thing each frame does), from memory: on the worst-case
// frames (0; their background is lit everywhere) and on the typical frames (1).
void BM_Noise(benchmark::State& state) {
  const Frames& f = state.range(0) == 0 ? GrayFrames() : WebcamFrames();
  size_t i = 0;
  bool on_lit = false;
  for (auto _ : state) {
    benchmark::DoNotOptimize(rotoscan::laser::detail::EstimateNoise(f.on[i], f.off[i], 0, &on_lit));
    i = (i + 1) % f.on.size();
  }
  SetCounters(state, 2u * f.on[0].total());
}
BENCHMARK(BM_Noise)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

// The steps after the row loop alone, on the typical frames (WebcamFrames), each from the points it is given
// in the default extractor (the extractor run with it and the later steps off; copied each iteration):
// 0 the gap step (FillLineGaps, gaps.cc), 1 the steep step (RecentreSteepLines, steep.cc), 2 the line ends
// (RecentreLineEnds, ends.cc), 3 the along-line smoothing (SmoothAlongLine, smooth.cc, with the webcam frames'
// steep steps joined and the curvature correction; on the points of every step before it, the rim step off).
// The frames come from memory here, not from the cache as after the row pass.
void BM_WebcamStep(benchmark::State& state) {
  const Frames& f = WebcamFrames();
  const int which = static_cast<int>(state.range(0));
  std::vector<rotoscan::laser::Line> lines(f.on.size());
  for (size_t i = 0; i < f.on.size(); ++i) {
    rotoscan::laser::ExtractOptions options;
    options.smooth_half_rows = 0;
    options.steep_across = which >= 2;
    options.fill_gaps = which >= 1;
    options.line_ends = which == 3;
    options.rim_rows = which != 3;  // after the smoothing in the extractor
    if (!rotoscan::laser::LineExtractor(options).Extract(f.on[i], f.off[i], &lines[i]).ok()) std::abort();
  }
  std::vector<rotoscan::laser::LinePoint> points;
  const rotoscan::laser::ExtractOptions defaults;
  std::vector<float> scratch;
  size_t i = 0, total = 0;
  for (auto _ : state) {
    points = lines[i].points;
    const rotoscan::laser::LineStats& s = lines[i].stats;
    if (which == 0) {
      total += static_cast<size_t>(rotoscan::laser::detail::FillLineGaps(f.on[i], f.off[i], 0, s.noise_dn, &points));
    } else if (which == 1) {
      total += static_cast<size_t>(
          rotoscan::laser::detail::RecentreSteepLines(f.on[i], f.off[i], 0, s.threshold_dn, &points));
    } else if (which == 2) {
      total += static_cast<size_t>(
          rotoscan::laser::detail::RecentreLineEnds(f.on[i], f.off[i], 0, s.threshold_dn, &points));
    } else {
      rotoscan::laser::SmoothAlongLine(&points, defaults.smooth_half_rows, defaults.smooth_order,
                                       defaults.smooth_max_jump_px, defaults.smooth_outlier_px, &scratch,
                                       defaults.smooth_steep_step_px, defaults.smooth_curvature);
      total += points.size();
    }
    benchmark::DoNotOptimize(points.data());
    if (state.range(1) == 0) i = (i + 1) % f.on.size();
  }
  state.counters["frames_per_s"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["points_per_frame"] = static_cast<double>(total) / std::max<int64_t>(1, state.iterations());
  static const char* const kStepNames[] = {"gap step", "steep step", "line ends", "smoothing"};
  state.SetLabel(std::string(kStepNames[which]) + (state.range(1) == 1 ? ", cached" : ""));
}
// Arguments: the step (above); 1: one pair over and over (the frames in the cache, as after the row pass).
BENCHMARK(BM_WebcamStep)->ArgsProduct({{0, 1, 2, 3}, {0, 1}})->Unit(benchmark::kMicrosecond);


// The parts of BM_ExtractTriangulate/0/1/0 alone, on the lines it extracts (per row, then copied each
// iteration): the along-line smoothing, and the triangulation.
std::vector<rotoscan::laser::Line> PerRowLines() {
  const Frames& f = GrayFrames();
  rotoscan::laser::ExtractOptions options;
  options.smooth_half_rows = 0;
  std::vector<rotoscan::laser::Line> lines(f.on.size());
  for (size_t i = 0; i < f.on.size(); ++i) {
    const rotoscan::Status status = rotoscan::laser::LineExtractor(options).Extract(f.on[i], f.off[i], &lines[i]);
    if (!status.ok()) std::abort();
  }
  return lines;
}
void BM_SmoothOnly(benchmark::State& state) {
  const std::vector<rotoscan::laser::Line> lines = PerRowLines();
  const rotoscan::laser::ExtractOptions o;
  std::vector<rotoscan::laser::LinePoint> points;
  std::vector<float> scratch;
  size_t i = 0;
  for (auto _ : state) {
    points = lines[i].points;
    rotoscan::laser::SmoothAlongLine(&points, o.smooth_half_rows, o.smooth_order, o.smooth_max_jump_px,
                                     o.smooth_outlier_px, &scratch);
    benchmark::DoNotOptimize(points.data());
    i = (i + 1) % lines.size();
  }
  state.counters["frames_per_s"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_SmoothOnly)->Unit(benchmark::kMicrosecond);
void BM_TriangulateOnly(benchmark::State& state) {
  const std::vector<rotoscan::laser::Line> lines = PerRowLines();
  static const rotoscan::laser::Triangulator triangulator(Camera());
  std::vector<Eigen::Vector3d> points;
  std::vector<int> kept;
  size_t i = 0;
  for (auto _ : state) {
    triangulator.Triangulate(lines[i], Laser(), &points, &kept);
    benchmark::DoNotOptimize(points.data());
    i = (i + 1) % lines.size();
  }
  state.counters["frames_per_s"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_TriangulateOnly)->Unit(benchmark::kMicrosecond);

void BM_ExtractBgr(benchmark::State& state) {
  const Frames& f = BgrFrames();
  rotoscan::laser::LineExtractor extractor;
  static const rotoscan::laser::Triangulator triangulator(Camera());
  rotoscan::laser::Line line;
  std::vector<Eigen::Vector3d> points;
  std::vector<int> kept;
  size_t i = 0;
  for (auto _ : state) {
    const rotoscan::Status status = extractor.Extract(f.on[i], f.off[i], &line);
    benchmark::DoNotOptimize(status);
    triangulator.Triangulate(line, Laser(), &points, &kept);
    i = (i + 1) % f.on.size();
  }
  SetCounters(state, 6u * kWidth * kHeight);
}
BENCHMARK(BM_ExtractBgr)->Unit(benchmark::kMicrosecond);

// The row pass alone: the frames swapped (laser-off minus laser-on is below the threshold everywhere), so
// the same bytes are read and no row has a line. Compare with BM_StreamRead.
void BM_RowPassOnly(benchmark::State& state) {
  const Frames& f = GrayFrames();
  rotoscan::laser::LineExtractor extractor;
  rotoscan::laser::Line line;
  size_t i = 0;
  for (auto _ : state) {
    const rotoscan::Status status = extractor.Extract(f.off[i], f.on[i], &line);
    benchmark::DoNotOptimize(status);
    i = (i + 1) % f.on.size();
  }
  SetCounters(state, 2u * kWidth * kHeight);
}
BENCHMARK(BM_RowPassOnly)->Unit(benchmark::kMicrosecond);

// A tuned OpenCV variant of the same (per-row window instead of whole-image weights): not what Horus does,
// measured so that the speed-up is not credited to a strawman alone.
void BM_OpenCvTunedBaseline(benchmark::State& state) {
  const Frames& f = GrayFrames();
  const rotoscan::geometry::CameraModel camera = Camera();
  const cv::Mat K = (cv::Mat_<double>(3, 3) << camera.fx, 0, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1);
  const cv::Mat dist(1, 5, CV_64F, const_cast<double*>(camera.distortion.data()));
  const rotoscan::geometry::Plane plane = Laser();
  cv::Mat diff, blurred;
  std::vector<cv::Point2f> pixels, undistorted;
  std::vector<Eigen::Vector3d> points;
  size_t i = 0;
  constexpr int kWindow = 10;
  for (auto _ : state) {
    cv::subtract(f.on[i], f.off[i], diff);
    cv::threshold(diff, diff, 12, 0, cv::THRESH_TOZERO);
    cv::blur(diff, blurred, cv::Size(5, 5));
    pixels.clear();
    for (int r = 0; r < blurred.rows; ++r) {
      const cv::Mat row = blurred.row(r);
      double max_value;
      cv::Point max_at;
      cv::minMaxLoc(row, nullptr, &max_value, nullptr, &max_at);
      if (max_value < 12) continue;
      const int lo = std::max(0, max_at.x - kWindow), hi = std::min(blurred.cols - 1, max_at.x + kWindow);
      double sum = 0, sum_x = 0;
      for (int c = lo; c <= hi; ++c) {
        const double w = row.at<uint8_t>(0, c);
        sum += w;
        sum_x += w * c;
      }
      if (sum > 0) pixels.emplace_back(static_cast<float>(sum_x / sum), static_cast<float>(r));
    }
    points.clear();
    if (!pixels.empty()) {
      cv::undistortPoints(pixels, undistorted, K, dist);
      for (const cv::Point2f& u : undistorted) {
        const Eigen::Vector3d ray(u.x, u.y, 1.0);
        points.push_back(ray * (-plane.offset / plane.normal.dot(ray)));
      }
    }
    benchmark::DoNotOptimize(points.data());
    i = (i + 1) % f.on.size();
  }
  SetCounters(state, 2u * kWidth * kHeight);
}
BENCHMARK(BM_OpenCvTunedBaseline)->Unit(benchmark::kMicrosecond);

// bq Horus's pipeline (horus/engine/algorithms/laser_segmentation.py, compute_2d_points, with the
// "window" option on and its default "SGF" refinement) written with OpenCV as Horus writes it with OpenCV +
// NumPy: whole-image operations, NumPy's types. Subtract, threshold, blur, threshold again; per row the
// arg-max and a mask keeping +-kWindow px around it; the centre of mass as
// (weight_matrix * image).sum(axis=1) / image.sum(axis=1), where Horus's weight_matrix is float64
// (calibration_data.py builds it with np.linspace) so NumPy multiplies and sums in float64, and the uint8
// row sums are integers; then the segmented Gaussian filter (scipy.ndimage.gaussian_filter, sigma 2,
// truncate 4, mode 'reflect', over each run of rows with a point); then undistortPoints and the ray-plane
// intersection (point_cloud_generation.py).
void SegmentedGaussianFilter(const std::vector<int>& rows, std::vector<cv::Point2f>* pixels) {
  constexpr int kRadius = 8;  // scipy: int(truncate * sigma + 0.5)
  static const std::vector<double> kernel = [] {
    std::vector<double> k(2 * kRadius + 1);
    double sum = 0;
    for (int i = -kRadius; i <= kRadius; ++i) sum += k[static_cast<size_t>(i + kRadius)] = std::exp(-0.125 * i * i);
    for (double& v : k) v /= sum;
    return k;
  }();
  std::vector<float> u(pixels->size());
  size_t start = 0;
  while (start < rows.size()) {
    size_t end = start;
    while (end + 1 < rows.size() && rows[end + 1] == rows[end] + 1) ++end;
    const int n = static_cast<int>(end - start + 1);
    for (int i = 0; i < n; ++i) {
      double acc = 0;
      for (int k = -kRadius; k <= kRadius; ++k) {
        int j = i + k;
        while (j < 0 || j >= n) j = j < 0 ? -j - 1 : 2 * n - j - 1;  // 'reflect': d c b a | a b c d | d c b a
        acc += kernel[static_cast<size_t>(k + kRadius)] * (*pixels)[start + static_cast<size_t>(j)].x;
      }
      u[start + static_cast<size_t>(i)] = static_cast<float>(acc);
    }
    start = end + 1;
  }
  for (size_t i = 0; i < u.size(); ++i) (*pixels)[i].x = u[i];
}

void HorusBaseline(benchmark::State& state, bool color) {
  const Frames& f = color ? BgrFrames() : GrayFrames();
  const rotoscan::geometry::CameraModel camera = Camera();
  const cv::Mat K = (cv::Mat_<double>(3, 3) << camera.fx, 0, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1);
  const cv::Mat dist(1, 5, CV_64F, const_cast<double*>(camera.distortion.data()));
  const rotoscan::geometry::Plane plane = Laser();
  constexpr int kWindow = 10;
  cv::Mat weights(kHeight, kWidth, CV_64F);
  for (int r = 0; r < kHeight; ++r)
    for (int c = 0; c < kWidth; ++c) weights.at<double>(r, c) = c;
  cv::Mat diff, blurred, masked, image_f, weighted, sums, weighted_sums;
  std::vector<cv::Mat> planes;
  std::vector<cv::Point2f> pixels, undistorted;
  std::vector<int> rows;
  std::vector<Eigen::Vector3d> points;
  size_t i = 0;
  for (auto _ : state) {
    cv::subtract(f.on[i], f.off[i], diff);
    if (color) {  // Horus subtracts the color images, then takes the red channel with cv2.split
      cv::split(diff, planes);
      diff = planes[2];
    }
    cv::threshold(diff, diff, 12, 0, cv::THRESH_TOZERO);
    cv::blur(diff, blurred, cv::Size(5, 5));
    cv::threshold(blurred, blurred, 12, 0, cv::THRESH_TOZERO);
    masked = cv::Mat::zeros(blurred.size(), CV_8U);
    for (int r = 0; r < blurred.rows; ++r) {
      cv::Point max_at;
      cv::minMaxLoc(blurred.row(r), nullptr, nullptr, nullptr, &max_at);
      const int lo = std::max(0, max_at.x - kWindow), hi = std::min(blurred.cols - 1, max_at.x + kWindow);
      blurred(cv::Rect(lo, r, hi - lo + 1, 1)).copyTo(masked(cv::Rect(lo, r, hi - lo + 1, 1)));
    }
    masked.convertTo(image_f, CV_64F);
    cv::multiply(image_f, weights, weighted);
    cv::reduce(masked, sums, 1, cv::REDUCE_SUM, CV_32S);
    cv::reduce(weighted, weighted_sums, 1, cv::REDUCE_SUM, CV_64F);
    pixels.clear();
    rows.clear();
    for (int r = 0; r < kHeight; ++r) {
      const int s = sums.at<int>(r, 0);
      if (s > 0) {
        pixels.emplace_back(static_cast<float>(weighted_sums.at<double>(r, 0) / s), static_cast<float>(r));
        rows.push_back(r);
      }
    }
    SegmentedGaussianFilter(rows, &pixels);
    points.clear();
    if (!pixels.empty()) {
      cv::undistortPoints(pixels, undistorted, K, dist);
      for (const cv::Point2f& u : undistorted) {
        const Eigen::Vector3d ray(u.x, u.y, 1.0);
        points.push_back(ray * (-plane.offset / plane.normal.dot(ray)));
      }
    }
    benchmark::DoNotOptimize(points.data());
    i = (i + 1) % f.on.size();
  }
  SetCounters(state, (color ? 6u : 2u) * kWidth * kHeight);
}
void BM_HorusBaseline(benchmark::State& state) { HorusBaseline(state, false); }
BENCHMARK(BM_HorusBaseline)->Unit(benchmark::kMicrosecond);
// The same on color frames, as Horus runs with a color camera: compare with BM_ExtractBgr.
void BM_HorusBaselineBgr(benchmark::State& state) { HorusBaseline(state, true); }
BENCHMARK(BM_HorusBaselineBgr)->Unit(benchmark::kMicrosecond);

// The bound: read every byte of both frames once, nothing else (SSE2 byte maxima, 16 bytes per load).
// Three ways, and the fastest is the bound: frame after frame; row by row through both frames, as the
// extractor reads them; the same with the row 3 rows ahead prefetched, as the extractor does.
enum class ReadOrder { kFrameByFrame = 0, kRowByRow = 1, kRowByRowPrefetched = 2 };
void StreamRead(benchmark::State& state, const Frames& f) {
  const auto order = static_cast<ReadOrder>(state.range(0));
  size_t i = 0;
  for (auto _ : state) {
    const cv::Mat& on = f.on[i];
    const cv::Mat& off = f.off[i];
    const int row_bytes = static_cast<int>(on.cols * on.elemSize());
    const int whole = row_bytes / 16 * 16;
    __m128i x = _mm_setzero_si128(), y = _mm_setzero_si128();
    auto read_row = [&](const uint8_t* p, __m128i* acc) {
      for (int k = 0; k < whole; k += 16) *acc = _mm_max_epu8(*acc, _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + k)));
      if (whole < row_bytes) *acc = _mm_max_epu8(*acc, _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + row_bytes - 16)));
    };
    if (order == ReadOrder::kFrameByFrame) {
      for (int r = 0; r < on.rows; ++r) read_row(on.ptr<uint8_t>(r), &x);
      for (int r = 0; r < off.rows; ++r) read_row(off.ptr<uint8_t>(r), &y);
    } else {
      for (int r = 0; r < on.rows; ++r) {
        if (order == ReadOrder::kRowByRowPrefetched && r + 3 < on.rows) {
          for (int k = 0; k < row_bytes; k += 64) {
            _mm_prefetch(on.ptr<const char>(r + 3) + k, _MM_HINT_T0);
            _mm_prefetch(off.ptr<const char>(r + 3) + k, _MM_HINT_T0);
          }
        }
        read_row(on.ptr<uint8_t>(r), &x);
        read_row(off.ptr<uint8_t>(r), &y);
      }
    }
    benchmark::DoNotOptimize(x);
    benchmark::DoNotOptimize(y);
    i = (i + 1) % f.on.size();
  }
  SetCounters(state, 2u * f.on[0].total() * f.on[0].elemSize());
}
void BM_StreamRead(benchmark::State& state) { StreamRead(state, GrayFrames()); }
BENCHMARK(BM_StreamRead)->DenseRange(0, 2)->Unit(benchmark::kMicrosecond);
void BM_StreamReadBgr(benchmark::State& state) { StreamRead(state, BgrFrames()); }
BENCHMARK(BM_StreamReadBgr)->DenseRange(0, 2)->Unit(benchmark::kMicrosecond);
void BM_StreamReadWebcam(benchmark::State& state) { StreamRead(state, WebcamFrames()); }
BENCHMARK(BM_StreamReadWebcam)->DenseRange(0, 2)->Unit(benchmark::kMicrosecond);

}  // namespace
