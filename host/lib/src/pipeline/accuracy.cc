#include "rotoscan/pipeline/accuracy.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include <Eigen/SVD>

#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"

namespace rotoscan::pipeline {

void LineAccuracy::Add(const LineAccuracy& o) {
  frames += o.frames;
  truth_rows += o.truth_rows;
  extracted += o.extracted;
  matched += o.matched;
  outliers += o.outliers;
  spurious += o.spurious;
  missed += o.missed;
  sum_error += o.sum_error;
  sum_squared += o.sum_squared;
  max_abs = std::max(max_abs, o.max_abs);
  across_outliers += o.across_outliers;
  across_matched += o.across_matched;
  across_sum_squared += o.across_sum_squared;
}

double DistanceAcrossLine(double column, int row, const std::map<int, std::vector<double>>& by_row) {
  constexpr int kRowsAround = 4;
  constexpr double kMaxStepPx = 64.0;
  double best = std::numeric_limits<double>::infinity();
  for (auto it = by_row.lower_bound(row - kRowsAround); it != by_row.end() && it->first <= row + kRowsAround; ++it) {
    const double y0 = it->first - row;
    const auto next = by_row.find(it->first + 1);
    for (const double c0 : it->second) {
      const double x0 = c0 - column;
      best = std::min(best, std::hypot(x0, y0));
      if (next == by_row.end()) continue;
      const double* c1 = nullptr;
      for (const double& c : next->second) {
        if (c1 == nullptr || std::abs(c - c0) < std::abs(*c1 - c0)) c1 = &c;
      }
      if (std::abs(*c1 - c0) > kMaxStepPx) continue;
      // The segment (x0, y0) -> (x1, y0 + 1), the point at the origin.
      const double dx = *c1 - c0, dy = 1.0;
      const double t = std::clamp(-(x0 * dx + y0 * dy) / (dx * dx + dy * dy), 0.0, 1.0);
      best = std::min(best, std::hypot(x0 + t * dx, y0 + t * dy));
    }
  }
  return best;
}

void LineAccuracyParts::Add(const LineAccuracyParts& o) {
  all.Add(o.all);
  object.Add(o.object);
  table.Add(o.table);
}

LineAccuracyParts CompareWithTruthByPart(const laser::Line& line, const std::vector<bundle::LinePoint>& truth,
                                         double outlier_px) {
  LineAccuracyParts parts;
  std::map<int, std::vector<double>> by_row;
  std::map<int, bool> on_object;  // a row is the object's where any object's line crosses it
  for (const bundle::LinePoint& t : truth) {
    by_row[t.row].push_back(t.column);
    on_object[t.row] = on_object[t.row] || t.object != 0;
  }
  for (LineAccuracy* a : {&parts.all, &parts.object, &parts.table}) a->frames = 1;
  parts.all.truth_rows = by_row.size();
  for (const auto& [row, object] : on_object) ++(object ? parts.object : parts.table).truth_rows;
  std::map<int, bool> found;
  for (const laser::LinePoint& p : line.points) {
    auto it = by_row.find(p.row);
    if (it == by_row.end()) {
      ++parts.all.extracted;
      ++parts.all.spurious;
      continue;
    }
    LineAccuracy& part = on_object[p.row] ? parts.object : parts.table;
    for (LineAccuracy* a : {&parts.all, &part}) ++a->extracted;
    found[p.row] = on_object[p.row];
    const double across = DistanceAcrossLine(p.column, p.row, by_row);
    for (LineAccuracy* a : {&parts.all, &part}) {
      if (across > outlier_px) {
        ++a->across_outliers;
      } else {
        ++a->across_matched;
        a->across_sum_squared += across * across;
      }
    }
    double best = 1e300;
    for (double c : it->second) {
      if (std::abs(p.column - c) < std::abs(best)) best = p.column - c;
    }
    for (LineAccuracy* a : {&parts.all, &part}) {
      if (std::abs(best) > outlier_px) {
        ++a->outliers;
        continue;
      }
      ++a->matched;
      a->sum_error += best;
      a->sum_squared += best * best;
      a->max_abs = std::max(a->max_abs, std::abs(best));
    }
  }
  // Rows found once each (a row with several points is found once).
  size_t found_object = 0;
  for (const auto& [row, object] : found) found_object += object;
  parts.all.missed = parts.all.truth_rows - found.size();
  parts.object.missed = parts.object.truth_rows - found_object;
  parts.table.missed = parts.table.truth_rows - (found.size() - found_object);
  return parts;
}

LineAccuracy CompareWithTruth(const laser::Line& line, const std::vector<bundle::LinePoint>& truth,
                              double outlier_px) {
  return CompareWithTruthByPart(line, truth, outlier_px).all;
}

Result<LineAccuracy> MeasureLineAccuracy(const std::filesystem::path& bundle_dir,
                                         const laser::ExtractOptions& options, size_t max_frames,
                                         double outlier_px, Progress* progress) {
  ROTOSCAN_ASSIGN_OR_RETURN(const LineAccuracyParts parts,
                            MeasureLineAccuracyByPart(bundle_dir, options, max_frames, outlier_px, progress));
  return parts.all;
}

Result<LineAccuracyParts> MeasureLineAccuracyByPart(const std::filesystem::path& bundle_dir,
                                                    const laser::ExtractOptions& options, size_t max_frames,
                                                    double outlier_px, Progress* progress) {
  ROTOSCAN_ASSIGN_OR_RETURN(const bundle::Bundle b, bundle::ReadBundle(bundle_dir));
  if (!b.has_truth)
    return NotFoundError(bundle_dir.string() + " has no truth/ (only virtual scanner bundles do)");
  laser::ExtractOptions o = options;
  if (o.layout == laser::PixelLayout::kAuto && b.header.camera.bayer)
    o.layout = laser::PixelLayout::kBayerRggb;
  laser::LineExtractor extractor(o);
  std::vector<size_t> laser_frames;
  for (size_t i = 0; i < b.frames.size(); ++i) {
    const bundle::LaserState s = b.frames[i].laser;
    if (s == bundle::LaserState::kLeft || s == bundle::LaserState::kRight) laser_frames.push_back(i);
  }
  if (max_frames > 0 && laser_frames.size() > max_frames) laser_frames.resize(max_frames);
  ProgressScope scope(progress, "line accuracy", laser_frames.size());
  LineAccuracyParts total;
  laser::Line line;
  for (size_t index : laser_frames) {
    const bundle::FrameRecord& record = b.frames[index];
    const int off_index = b.FindFrame(record.step, bundle::LaserState::kOff, record.pose);
    if (off_index < 0)
      return NotFoundError(record.file + ": no laser-off frame for step " + std::to_string(record.step));
    ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat on, bundle::ReadFrame(b, record));
    ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat off, bundle::ReadFrame(b, static_cast<size_t>(off_index)));
    ROTOSCAN_RETURN_IF_ERROR(
        extractor
            .Extract(To8Bit(on, b.header.camera.bit_depth), To8Bit(off, b.header.camera.bit_depth), &line)
            .WithContext(record.file));
    ROTOSCAN_ASSIGN_OR_RETURN(const std::vector<bundle::LinePoint> truth, bundle::ReadLineTruth(b, record));
    total.Add(CompareWithTruthByPart(line, truth, outlier_px));
    scope.Advance();
  }
  return total;
}

Result<PlaneAccuracy> MeasurePlaneAccuracy(const std::filesystem::path& bundle_dir, const geometry::Rig& rig,
                                           const ProcessOptions& options, double max_distance_mm) {
  ROTOSCAN_ASSIGN_OR_RETURN(const bundle::Bundle b, bundle::ReadBundle(bundle_dir));
  if (!b.has_truth) return NotFoundError(bundle_dir.string() + " has no truth/");
  // The comparison is made in the table frame (the world frame at angle 0), where the cloud is: a
  // calibrated rig puts that frame's origin on the table top (calib PlaceTableOrigin, from the target's
  // height in the calibration bundles), as the true rig does. Comparing in each rig's camera frame instead
  // would score a rig whose K is off in a slightly turned frame (1 deg is 5 mm at 300 mm).
  // The true plane from the exact truth points of object 1.
  std::vector<Eigen::Vector3d> truth_points;
  for (const bundle::FrameRecord& f : b.frames) {
    if (f.laser != bundle::LaserState::kLeft && f.laser != bundle::LaserState::kRight) continue;
    ROTOSCAN_ASSIGN_OR_RETURN(const std::vector<bundle::LinePoint> truth, bundle::ReadLineTruth(b, f));
    for (const bundle::LinePoint& t : truth) {
      if (t.object == 1) truth_points.push_back(t.point_in_world);
    }
  }
  if (truth_points.size() < 3)
    return InvalidArgumentError(bundle_dir.string() + ": no truth points on object 1");
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : truth_points) centroid += p;
  centroid /= static_cast<double>(truth_points.size());
  Eigen::MatrixXd centered(truth_points.size(), 3);
  for (size_t i = 0; i < truth_points.size(); ++i)
    centered.row(static_cast<Eigen::Index>(i)) = (truth_points[i] - centroid).transpose();
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(centered, Eigen::ComputeThinV);
  PlaneAccuracy a;
  a.true_plane = geometry::Plane::FromPointNormal(centroid, svd.matrixV().col(2));
  ROTOSCAN_ASSIGN_OR_RETURN(const ProcessResult result, ProcessBundle(bundle_dir, rig, options));
  double sum = 0, sum2 = 0;
  for (const cloud::CloudPoint& p : result.cloud.points) {
    const double d = a.true_plane.SignedDistance(p.position_in_table.cast<double>());
    if (std::abs(d) > max_distance_mm) continue;
    ++a.points;
    sum += d;
    sum2 += d * d;
  }
  if (a.points == 0)
    return InvalidArgumentError(bundle_dir.string() + ": no cloud point near the true plane");
  a.mean_mm = sum / a.points;
  a.rms_mm = std::sqrt(sum2 / a.points);
  return a;
}

Result<PlaneAccuracy> RunPlaneAccuracy(double distance_mm, const std::filesystem::path& work_dir, int steps,
                                       const std::string& scene_overrides, Progress* progress) {
  const std::string json =
      "{" + (scene_overrides.empty() ? std::string() : scene_overrides + ", ") +
      "\"objects\": [{\"type\": \"plane\", \"distance_mm\": " + std::to_string(distance_mm) +
      ", \"angle_deg\": 20, \"size_mm\": [150, 120], \"color\": [0.9, 0.9, 0.9]}]}";
  ROTOSCAN_ASSIGN_OR_RETURN(const sim::Scene scene, sim::ParseScene(json, work_dir, "plane scene"));
  sim::SimulateOptions options;
  options.out = work_dir / ("plane-" + std::to_string(static_cast<int>(std::lround(distance_mm))));
  options.steps = steps;
  options.overwrite = true;
  ROTOSCAN_RETURN_IF_ERROR(sim::Simulate(scene, options, progress));
  ProcessOptions process;
  process.merge = false;  // both lasers measure the same plane; keep every point
  return MeasurePlaneAccuracy(options.out, scene.rig, process);
}

}  // namespace rotoscan::pipeline
