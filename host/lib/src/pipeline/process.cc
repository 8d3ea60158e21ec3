#include "rotoscan/pipeline/process.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "rotoscan/core/check.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/laser/triangulate.h"

namespace rotoscan::pipeline {
namespace {

constexpr size_t kMaxWarnings = 20;

// What one step produced, per laser, in row order.
struct StepOutput {
  bool done = false;
  std::array<std::vector<cloud::CloudPoint>, 2> points;
  std::array<std::vector<int>, 2> rows;
  Eigen::Vector3f camera_in_table = Eigen::Vector3f::Zero();
  int step = 0;
  double table_angle_rad = 0.0;
  std::array<laser::LineStats, 2> stats;
};

// The scan's camera path (cloud::ScanGeometry) when every processed step sits at step index x one fixed
// angle: the camera at angle 0 and the signed turn per step that reproduces each step's camera centre.
cloud::ScanGeometry ScanGeometryOf(const geometry::Rig& rig, const std::vector<StepOutput>& outputs) {
  cloud::ScanGeometry scan;
  scan.camera_at_step0 = rig.WorldFromCamAtAngle(0.0) * Eigen::Vector3d::Zero();
  double rate = 0.0;
  bool have_rate = false;
  for (const StepOutput& o : outputs) {
    if (!o.done || o.step == 0) continue;
    const double r = o.table_angle_rad / o.step;
    if (!have_rate) {
      rate = r;
      have_rate = true;
    } else if (std::abs(r - rate) * std::abs(o.step) > 1e-6) {
      return {};  // not a uniform turn: unknown
    }
  }
  if (!have_rate) return {};
  for (const double sign : {1.0, -1.0}) {
    scan.step_rad = sign * rate;
    bool all = true;
    for (const StepOutput& o : outputs) {
      if (o.done && (scan.CameraAtStep(o.step) - o.camera_in_table.cast<double>()).norm() > 0.05) all = false;
    }
    if (all) {
      scan.known = true;
      return scan;
    }
  }
  return {};  // the table axis is not the table frame's z: unknown
}

int FindRow(const std::vector<int>& rows, int row) {
  auto it = std::lower_bound(rows.begin(), rows.end(), row);
  return (it != rows.end() && *it == row) ? static_cast<int>(it - rows.begin()) : -1;
}

}  // namespace

BundleStepSource::BundleStepSource(bundle::Bundle bundle) : bundle_(std::move(bundle)) {
  for (const bundle::FrameRecord& f : bundle_.frames) {
    if (f.pose < 0) steps_.push_back(f.step);
    if (f.pose < 0 && f.laser == bundle::LaserState::kOff) has_off_frames_ = true;
  }
  std::sort(steps_.begin(), steps_.end());
  steps_.erase(std::unique(steps_.begin(), steps_.end()), steps_.end());
}

Result<StepFrames> BundleStepSource::Load(int index) const {
  ROTOSCAN_CHECK(index >= 0 && index < StepCount());
  StepFrames frames;
  frames.step = steps_[static_cast<size_t>(index)];
  frames.name = "step " + std::to_string(frames.step);
  bool have_angle = false;
  for (bundle::LaserState state : {bundle::LaserState::kLeft, bundle::LaserState::kRight,
                                   bundle::LaserState::kOff, bundle::LaserState::kNatural}) {
    const int i = bundle_.FindFrame(frames.step, state);
    if (i < 0) continue;
    const bundle::FrameRecord& record = bundle_.frames[static_cast<size_t>(i)];
    if (!have_angle || state != bundle::LaserState::kNatural) {
      frames.table_angle_rad = record.table_angle_rad;
      have_angle = true;
    }
    auto image = bundle::ReadFrame(bundle_, record);
    if (!image.ok()) return image.status().WithContext(record.file);
    switch (state) {
      case bundle::LaserState::kLeft: frames.laser[0] = std::move(*image); break;
      case bundle::LaserState::kRight: frames.laser[1] = std::move(*image); break;
      case bundle::LaserState::kOff:
        frames.off = std::move(*image);
        if (bundle_.header.shared_off_frame) frames.natural = frames.off;  // also the color frame
        break;
      case bundle::LaserState::kNatural: frames.natural = std::move(*image); break;
    }
  }
  return frames;
}

Result<cv::Mat> StepSource::LoadNatural(int index, double* table_angle_rad) const {
  ROTOSCAN_ASSIGN_OR_RETURN(StepFrames frames, Load(index));
  if (table_angle_rad != nullptr) *table_angle_rad = frames.table_angle_rad;
  return frames.natural;
}

Result<cv::Mat> BundleStepSource::LoadNatural(int index, double* table_angle_rad) const {
  ROTOSCAN_CHECK(index >= 0 && index < StepCount());
  const int step = steps_[static_cast<size_t>(index)];
  int natural = bundle_.FindFrame(step, bundle::LaserState::kNatural);
  if (natural < 0 && bundle_.header.shared_off_frame) natural = bundle_.FindFrame(step, bundle::LaserState::kOff);
  if (natural < 0) return cv::Mat();
  if (table_angle_rad != nullptr) {
    // The laser frames' angle, as Load() takes it (the natural frame's when the step has no other).
    *table_angle_rad = bundle_.frames[static_cast<size_t>(natural)].table_angle_rad;
    for (bundle::LaserState state : {bundle::LaserState::kLeft, bundle::LaserState::kRight, bundle::LaserState::kOff}) {
      const int i = bundle_.FindFrame(step, state);
      if (i >= 0) {
        *table_angle_rad = bundle_.frames[static_cast<size_t>(i)].table_angle_rad;
        break;
      }
    }
  }
  const bundle::FrameRecord& record = bundle_.frames[static_cast<size_t>(natural)];
  auto image = bundle::ReadFrame(bundle_, record);
  if (!image.ok()) return image.status().WithContext(record.file);
  return std::move(*image);
}

Status ProcessOptions::Check() const {
  ROTOSCAN_RETURN_IF_ERROR(extract.Check());
  ROTOSCAN_RETURN_IF_ERROR(merge_options.Check());
  ROTOSCAN_RETURN_IF_ERROR(color.Check());
  if (threads < 0 || threads > 256) return InvalidArgumentError("process: threads must be in [0, 256]");
  if (!use_laser[0] && !use_laser[1]) return InvalidArgumentError("process: no laser selected");
  if (!(max_neighbor_mm > 0)) return InvalidArgumentError("process: max_neighbor_mm must be > 0");
  if (!(min_quality >= 0 && min_quality <= 1)) {  // NaN too
    return InvalidArgumentError("process: min_quality must be in [0, 1], got " + std::to_string(min_quality));
  }
  return Status::Ok();
}

cv::Mat To8Bit(const cv::Mat& frame, int bit_depth) {
  if (frame.depth() == CV_8U) return frame;
  cv::Mat out;
  const int bits = frame.depth() == CV_16U ? std::clamp(bit_depth, 9, 16) : 16;
  frame.convertTo(out, CV_8U, 255.0 / ((1 << bits) - 1));
  return out;
}

cv::Mat NaturalImageOf(const StepSource& source, const cv::Mat& natural_frame) {
  if (natural_frame.empty()) return cv::Mat();
  cv::Mat natural = To8Bit(natural_frame, source.bit_depth());
  if (source.bayer() && natural.channels() == 1) {
    cv::Mat bgr;
    cv::cvtColor(natural, bgr, cv::COLOR_BayerBG2BGR);
    natural = bgr;
  }
  return natural;
}

std::array<uint8_t, 3> SampleRgb(const cv::Mat& image, double column, double row) {
  ROTOSCAN_CHECK(!image.empty() && image.depth() == CV_8U);
  const int channels = image.channels();
  const double x = std::clamp(column, 0.0, image.cols - 1.0);
  const double y = std::clamp(row, 0.0, image.rows - 1.0);
  const int x0 = std::min(static_cast<int>(x), image.cols - 1),
            y0 = std::min(static_cast<int>(y), image.rows - 1);
  const int x1 = std::min(x0 + 1, image.cols - 1), y1 = std::min(y0 + 1, image.rows - 1);
  const double fx = x - x0, fy = y - y0;
  std::array<uint8_t, 3> rgb{};
  for (int c = 0; c < 3; ++c) {
    const int ch = channels >= 3 ? 2 - c : 0;  // BGR -> RGB; gray replicated
    auto at = [&](int yy, int xx) { return static_cast<double>(image.ptr<uint8_t>(yy)[xx * channels + ch]); };
    const double v =
        (1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x1)) + fy * ((1 - fx) * at(y1, x0) + fx * at(y1, x1));
    rgb[static_cast<size_t>(c)] = static_cast<uint8_t>(std::clamp(std::lround(v), 0L, 255L));
  }
  return rgb;
}

namespace {

// The background of the steps that lack their own laser-off frame (see the header): the dark frame in 8 bits
// when one is given, else zero when the source has no laser-off frame at all; otherwise such steps are
// skipped.
struct Background {
  bool dark = false;   // ProcessOptions::dark_frame is given
  bool zero = false;   // no dark frame, and no step of the source has a laser-off frame
  cv::Mat dark_frame;  // 8-bit
};

Result<Background> BackgroundOf(const StepSource& source, const ProcessOptions& options,
                                const geometry::CameraModel& camera) {
  Background background;
  background.dark = !options.dark_frame.empty();
  background.zero = !background.dark && !source.has_off_frames();
  if (!background.dark) return background;
  if (options.dark_frame.cols != camera.width || options.dark_frame.rows != camera.height) {
    return InvalidArgumentError("dark frame size " + std::to_string(options.dark_frame.cols) + "x" +
                                std::to_string(options.dark_frame.rows) + " differs from the calibration's " +
                                std::to_string(camera.width) + "x" + std::to_string(camera.height));
  }
  background.dark_frame = To8Bit(options.dark_frame, source.bit_depth());
  return background;
}

// What the workers share: the first error (it stops the run), the skipped steps with their reasons, and the
// count of steps processed against the background.
class RunLog {
 public:
  void Skip(const std::string& message) {
    std::lock_guard<std::mutex> lock(mutex_);
    ++skipped_;
    if (warnings_.size() < kMaxWarnings) warnings_.push_back(message);
  }
  // Keeps the first error and stops the workers.
  void Fail(Status status) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (first_error_.ok()) first_error_ = std::move(status);
    }
    Stop();
  }
  void Stop() { stop_ = true; }
  bool stopped() const { return stop_.load(); }
  void CountBackgroundStep() { ++background_steps_; }

  // After the workers have joined.
  const Status& first_error() const { return first_error_; }
  int skipped() const { return skipped_; }
  const std::vector<std::string>& warnings() const { return warnings_; }
  int background_steps() const { return background_steps_.load(); }

 private:
  std::mutex mutex_;
  Status first_error_;
  std::vector<std::string> warnings_;
  int skipped_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<int> background_steps_{0};
};

// The inputs every step reads.
struct StepContext {
  const geometry::Rig& rig;
  const StepSource& source;
  const ProcessOptions& options;
  const laser::ExtractOptions& extract;  // the options' with the source's pixel layout
  const laser::Triangulator& triangulator;
  const Background& background;
};

// One worker's extractor and buffers, reused from step to step.
struct StepWorkspace {
  explicit StepWorkspace(const laser::ExtractOptions& options) : extractor(options) {}
  laser::LineExtractor extractor;
  laser::Line line;
  std::vector<Eigen::Vector3d> points_in_cam;
  std::vector<int> kept;
};

// kInvalidArgument naming the step when one of its frames is not the calibration's size.
Status CheckFrameSizes(const StepFrames& f, const geometry::CameraModel& camera) {
  for (const cv::Mat* m : {&f.laser[0], &f.laser[1], &f.off, &f.natural}) {
    if (!m->empty() && (m->cols != camera.width || m->rows != camera.height)) {
      return InvalidArgumentError(f.name + ": frame size " + std::to_string(m->cols) + "x" +
                                  std::to_string(m->rows) + " differs from the calibration's " +
                                  std::to_string(camera.width) + "x" + std::to_string(camera.height));
    }
  }
  return Status::Ok();
}

// The 8-bit frame the step's laser frames are differenced against: its laser-off frame, or with
// `use_background` the dark frame or zero. kInvalidArgument when the dark frame's channels differ.
Result<cv::Mat> OffFrameOf(const StepContext& ctx, const StepFrames& f, bool use_background) {
  const int bit_depth = ctx.source.bit_depth();
  if (!use_background) return To8Bit(f.off, bit_depth);
  const cv::Mat& on = f.laser[0].empty() ? f.laser[1] : f.laser[0];
  const cv::Mat on8 = To8Bit(on, bit_depth);
  const cv::Mat& dark_frame = ctx.background.dark_frame;
  if (ctx.background.dark && dark_frame.type() != on8.type()) {
    return InvalidArgumentError("dark frame has " + std::to_string(dark_frame.channels()) +
                                " channels, the laser frames of " + f.name + " " +
                                std::to_string(on8.channels()));
  }
  return ctx.background.dark ? dark_frame : cv::Mat(cv::Mat::zeros(on8.size(), on8.type()));
}

// The line of laser `l` in `laser_frame` against `off`, triangulated on that laser's plane (eq. 5-6) and
// moved into the table frame by `world_from_cam` (eq. 7), each point colored from `natural` at its
// sub-pixel position; appended to out->points[l] with its image row. The extractor's error otherwise.
Status TriangulateLaser(const StepContext& ctx, int l, const cv::Mat& laser_frame, int step,
                        const Eigen::Isometry3d& world_from_cam, const cv::Mat& off, const cv::Mat& natural,
                        StepWorkspace* ws, StepOutput* out) {
  ROTOSCAN_RETURN_IF_ERROR(
      ws->extractor.Extract(To8Bit(laser_frame, ctx.source.bit_depth()), off, &ws->line));
  out->stats[static_cast<size_t>(l)] = ws->line.stats;
  ctx.triangulator.Triangulate(ws->line, ctx.rig.laser_plane[l], &ws->points_in_cam, &ws->kept);
  auto& cloud_points = out->points[static_cast<size_t>(l)];
  auto& rows = out->rows[static_cast<size_t>(l)];
  for (size_t k = 0; k < ws->points_in_cam.size(); ++k) {
    const laser::LinePoint& lp = ws->line.points[static_cast<size_t>(ws->kept[k])];
    if (lp.quality < ctx.options.min_quality) continue;
    cloud::CloudPoint p;
    p.position_in_table = (world_from_cam * ws->points_in_cam[k]).cast<float>();
    p.color = natural.empty() ? std::array<uint8_t, 3>{128, 128, 128} : SampleRgb(natural, lp.column, lp.row);
    p.laser = static_cast<uint8_t>(l);
    p.step = step;
    p.quality = lp.quality;
    cloud_points.push_back(p);
    rows.push_back(lp.row);
  }
  return Status::Ok();
}

// Processes one loaded step into `out`. OK with out->done set; OK with out->done false after a skip counted
// in `log`; an error (frame size, dark frame type) stops the run.
Status ProcessStep(const StepContext& ctx, const StepFrames& f, StepWorkspace* ws, RunLog* log,
                   StepOutput* out) {
  const bool use_background = f.off.empty() && (ctx.background.dark || ctx.background.zero);
  if ((f.off.empty() && !use_background) || (f.laser[0].empty() && f.laser[1].empty())) {
    log->Skip(f.name + " skipped: " + (f.off.empty() ? "no laser-off frame" : "no laser frame"));
    return Status::Ok();
  }
  ROTOSCAN_RETURN_IF_ERROR(CheckFrameSizes(f, ctx.rig.camera));
  ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat off, OffFrameOf(ctx, f, use_background));
  if (use_background) log->CountBackgroundStep();
  const cv::Mat natural = NaturalImageOf(ctx.source, f.natural);
  const Eigen::Isometry3d world_from_cam = ctx.rig.WorldFromCamAtAngle(f.table_angle_rad);
  out->camera_in_table = (world_from_cam * Eigen::Vector3d::Zero()).cast<float>();
  out->step = f.step;
  out->table_angle_rad = f.table_angle_rad;
  for (int l = 0; l < 2; ++l) {
    const cv::Mat& laser_frame = f.laser[static_cast<size_t>(l)];
    if (!ctx.options.use_laser[l] || laser_frame.empty()) continue;
    const Status status =
        TriangulateLaser(ctx, l, laser_frame, f.step, world_from_cam, off, natural, ws, out);
    if (!status.ok()) {
      log->Skip(f.name + " " + geometry::LaserName(static_cast<geometry::LaserId>(l)) +
                " skipped: " + status.ToString());
      *out = StepOutput{};
      return Status::Ok();
    }
  }
  out->done = true;
  return Status::Ok();
}

// One worker: takes steps from `next` until none is left, the progress asks to stop or a step fails.
void RunWorker(const StepContext& ctx, ProgressScope* scope, std::atomic<int>* next, RunLog* log,
               std::vector<StepOutput>* outputs) {
  StepWorkspace ws(ctx.extract);
  const int steps = static_cast<int>(outputs->size());
  while (!log->stopped()) {
    const int index = next->fetch_add(1);
    if (index >= steps) break;
    if (scope->Cancelled()) {
      log->Stop();
      break;
    }
    auto loaded = ctx.source.Load(index);
    scope->Advance();
    if (!loaded.ok()) {
      log->Skip("step #" + std::to_string(index) + " skipped: " + loaded.status().ToString());
      continue;
    }
    const Status status = ProcessStep(ctx, *loaded, &ws, log, &(*outputs)[static_cast<size_t>(index)]);
    if (!status.ok()) {
      log->Fail(status);
      break;
    }
  }
}

// The counts of the summary: steps, skips and their reasons (the background warning first), and the line
// statistics and points per laser of the processed steps.
ProcessSummary SummaryOf(int steps, const RunLog& log, const Background& background,
                         const std::vector<StepOutput>& outputs) {
  ProcessSummary s;
  s.steps = steps;
  s.skipped_steps = log.skipped();
  s.warnings = log.warnings();
  if (log.background_steps() > 0) {
    const std::string what = background.dark ? "the dark frame" : "a zero background";
    s.background_steps = log.background_steps();
    s.warnings.insert(
        s.warnings.begin(),
        std::to_string(s.background_steps) + " steps have no laser-off frame" +
            (background.zero ? " (the scan has none: laser-on frames captured in the dark?)" : "") +
            ": their laser lines were found against " + what +
            ", so ambient light in the laser frames counts as laser");
    ROTOSCAN_LOG(kWarning) << s.warnings.front();
  }
  if (log.skipped() > static_cast<int>(kMaxWarnings)) {
    s.warnings.push_back("... and " + std::to_string(log.skipped() - static_cast<int>(kMaxWarnings)) +
                         " more");
  }
  for (const StepOutput& o : outputs) {
    if (!o.done) continue;
    ++s.processed_steps;
    for (int l = 0; l < 2; ++l) {
      const laser::LineStats& ls = o.stats[static_cast<size_t>(l)];
      s.line_totals.rows += ls.rows;
      s.line_totals.found += ls.found;
      s.line_totals.low_contrast += ls.low_contrast;
      s.line_totals.bad_width += ls.bad_width;
      s.line_totals.off_saturated += ls.off_saturated;
      s.line_totals.multiple_peaks += ls.multiple_peaks;
      s.points_per_laser[static_cast<size_t>(l)] += o.points[static_cast<size_t>(l)].size();
    }
  }
  return s;
}

// Normals from the scan grid: the tangent along the line (rows r +- 1 of the same step) crossed with the
// tangent across steps (the same row at steps i +- 1), oriented toward the camera of the point's step.
// Neighbours further than `max_neighbor_mm` are another surface. Returns the points given a grid normal.
size_t EstimateGridNormals(double max_neighbor_mm, std::vector<StepOutput>* outputs) {
  const float max_d = static_cast<float>(max_neighbor_mm);
  const int steps = static_cast<int>(outputs->size());
  size_t with_normal = 0;
  for (int i = 0; i < steps; ++i) {
    StepOutput& o = (*outputs)[static_cast<size_t>(i)];
    if (!o.done) continue;
    for (int l = 0; l < 2; ++l) {
      auto& pts = o.points[static_cast<size_t>(l)];
      const auto& rows = o.rows[static_cast<size_t>(l)];
      for (size_t k = 0; k < pts.size(); ++k) {
        const Eigen::Vector3f& p = pts[k].position_in_table;
        auto neighbor = [&](int step_index, int row, Eigen::Vector3f* q) {
          if (step_index < 0 || step_index >= steps) return false;
          const StepOutput& n = (*outputs)[static_cast<size_t>(step_index)];
          if (!n.done) return false;
          const int j = FindRow(n.rows[static_cast<size_t>(l)], row);
          if (j < 0) return false;
          *q = n.points[static_cast<size_t>(l)][static_cast<size_t>(j)].position_in_table;
          return (*q - p).norm() <= max_d;
        };
        auto tangent = [&](int s0, int r0, int s1, int r1, Eigen::Vector3f* t) {
          Eigen::Vector3f a = Eigen::Vector3f::Zero(), b = Eigen::Vector3f::Zero();
          const bool has_a = neighbor(s0, r0, &a), has_b = neighbor(s1, r1, &b);
          if (has_a && has_b) {
            *t = b - a;
          } else if (has_b) {
            *t = b - p;
          } else if (has_a) {
            *t = p - a;
          } else {
            return false;
          }
          return t->squaredNorm() > 1e-12f;
        };
        const int row = rows[k];
        Eigen::Vector3f along, across;
        // Without both grid neighbours the normal is the direction to the camera: oriented to the
        // sensor's side like the rest, and the best guess a single ray gives.
        const Eigen::Vector3f to_camera = (o.camera_in_table - p).normalized();
        pts[k].normal = to_camera;
        if (!tangent(i, row - 1, i, row + 1, &along) || !tangent(i - 1, row, i + 1, row, &across)) continue;
        Eigen::Vector3f normal = along.cross(across);
        if (normal.squaredNorm() < 1e-20f) continue;
        normal.normalize();
        if (normal.dot(o.camera_in_table - p) < 0) normal = -normal;
        pts[k].normal = normal;
        ++with_normal;
      }
    }
  }
  return with_normal;
}

// The steps' points in (step, laser, row) order with the scan's camera path, the two lasers merged when
// asked (cloud/merge.h), else their disagreement measured; fills the summary's merge report. Consumes
// `outputs`.
cloud::PointCloud CloudOf(const geometry::Rig& rig, const ProcessOptions& options,
                          std::vector<StepOutput>* outputs, ProcessSummary* s) {
  const cloud::ScanGeometry scan = ScanGeometryOf(rig, *outputs);
  cloud::PointCloud all;
  all.points.reserve(s->points_per_laser[0] + s->points_per_laser[1]);
  for (const StepOutput& o : *outputs) {
    for (int l = 0; l < 2; ++l) {
      all.points.insert(all.points.end(), o.points[static_cast<size_t>(l)].begin(),
                        o.points[static_cast<size_t>(l)].end());
    }
  }
  outputs->clear();
  cloud::PointCloud cloud;
  if (options.merge && options.use_laser[0] && options.use_laser[1]) {
    cloud = cloud::MergeLasers(all, options.merge_options, &s->merge);
  } else {
    s->merge.left_in = s->merge.left_out = s->points_per_laser[0];
    s->merge.right_in = s->merge.right_out = s->points_per_laser[1];
    s->merge.disagreement = cloud::MeasureLaserDisagreement(all, options.merge_options.overlap_radius_mm);
    cloud = std::move(all);
  }
  cloud.scan = scan;
  return cloud;
}

}  // namespace

// The steps, in order: the background for steps without a laser-off frame, every step by the workers
// (ProcessStep), the summary's counts, grid normals, and the cloud with the two lasers merged.
Result<ProcessResult> ProcessSteps(const geometry::Rig& rig, const StepSource& source,
                                   const ProcessOptions& options, Progress* progress) {
  const auto start = std::chrono::steady_clock::now();
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  ROTOSCAN_RETURN_IF_ERROR(rig.Validate().WithContext("rig"));
  const int steps = source.StepCount();
  if (steps <= 0) return InvalidArgumentError("the scan has no steps");
  laser::ExtractOptions extract = options.extract;
  if (extract.layout == laser::PixelLayout::kAuto && source.bayer())
    extract.layout = laser::PixelLayout::kBayerRggb;
  const laser::Triangulator triangulator(rig.camera);
  ROTOSCAN_ASSIGN_OR_RETURN(const Background background, BackgroundOf(source, options, rig.camera));
  const StepContext ctx{rig, source, options, extract, triangulator, background};

  std::vector<StepOutput> outputs(static_cast<size_t>(steps));
  RunLog log;
  std::atomic<int> next{0};
  ProgressScope scope(progress, "process", static_cast<uint64_t>(steps));
  auto worker = [&] { RunWorker(ctx, &scope, &next, &log, &outputs); };
  const int threads =
      options.threads > 0 ? options.threads : std::max(1u, std::thread::hardware_concurrency());
  std::vector<std::thread> pool;
  for (int t = 1; t < std::min(threads, steps); ++t) pool.emplace_back(worker);
  worker();
  for (std::thread& t : pool) t.join();
  if (!log.first_error().ok()) return log.first_error();
  if (scope.Cancelled()) return CancelledError("processing cancelled");

  ProcessResult result;
  ProcessSummary& s = result.summary;
  s = SummaryOf(steps, log, background, outputs);
  if (s.processed_steps == 0) {
    return InvalidArgumentError(
        "no step could be processed (" + std::to_string(log.skipped()) + " skipped" +
        (log.warnings().empty() ? std::string() : ", first: " + log.warnings().front()) + ")");
  }
  if (options.estimate_normals) s.points_with_normal = EstimateGridNormals(options.max_neighbor_mm, &outputs);
  result.cloud = CloudOf(rig, options, &outputs, &s);
  s.points_out = result.cloud.size();
  s.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

Result<ProcessResult> ProcessBundle(const std::filesystem::path& bundle_dir, const geometry::Rig& rig,
                                    const ProcessOptions& options, Progress* progress) {
  auto bundle = bundle::ReadBundle(bundle_dir);
  if (!bundle.ok()) return bundle.status();
  if (bundle->header.kind != bundle::BundleKind::kScan) {
    return InvalidArgumentError(bundle_dir.string() + " is a calibration bundle, not a scan");
  }
  const geometry::CameraModel& nominal = bundle->header.camera.model;
  if (nominal.width != rig.camera.width || nominal.height != rig.camera.height) {
    return InvalidArgumentError(bundle_dir.string() + ": image size " + std::to_string(nominal.width) + "x" +
                                std::to_string(nominal.height) + " differs from the calibration's " +
                                std::to_string(rig.camera.width) + "x" + std::to_string(rig.camera.height));
  }
  BundleStepSource source(std::move(*bundle));
  auto result = ProcessSteps(rig, source, options, progress);
  if (!result.ok()) return result;
  const auto start = std::chrono::steady_clock::now();
  ColorOptions color = options.color;
  if (color.threads == 0) color.threads = options.threads;
  ROTOSCAN_RETURN_IF_ERROR(
      ColorFromViews(rig, source, color, &result->cloud, &result->summary.color, progress));
  result->summary.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

std::string FormatSummary(const ProcessSummary& s) {
  std::ostringstream out;
  out.setf(std::ios::fixed);
  out.precision(4);
  out << "steps " << s.processed_steps << " of " << s.steps << " processed, " << s.skipped_steps
      << " skipped\n";
  out << "laser rows: " << s.line_totals.found << " found of " << s.line_totals.rows << " (no contrast "
      << s.line_totals.low_contrast << ", bad width " << s.line_totals.bad_width << ", off saturated "
      << s.line_totals.off_saturated << ", multiple peaks " << s.line_totals.multiple_peaks << ")\n";
  out << "points: left " << s.points_per_laser[0] << ", right " << s.points_per_laser[1] << ", with normal "
      << s.points_with_normal << "\n";
  const cloud::LaserDisagreement& d = s.merge.disagreement;
  if (d.pairs == 0) {
    out << "laser disagreement: not measured (no overlapping pair of points with normals)\n";
  } else {
    out << "laser disagreement: " << d.pairs << " pairs, mean offset " << d.mean_signed_mm << " mm, rms "
        << d.rms_mm << " mm, median |d| " << d.median_abs_mm << " mm\n";
  }
  out << "merge: kept left " << s.merge.left_out << " of " << s.merge.left_in << ", right "
      << s.merge.right_out << " of " << s.merge.right_in << " (" << s.merge.shared_voxels
      << " shared voxels) -> " << s.points_out << " points\n";
  out << FormatColorSummary(s.color);
  out.precision(2);
  out << "time " << s.seconds << " s\n";
  for (const std::string& w : s.warnings) out << "warning: " << w << "\n";
  return out.str();
}

}  // namespace rotoscan::pipeline
