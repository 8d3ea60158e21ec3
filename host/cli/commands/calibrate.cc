// rotoscan calibrate: camera intrinsics from checkerboard images (calibrate camera), or the whole rig
// (camera, both laser planes, table axis) from calibration bundles.
//
// The rig path turns calibration bundles into observations for calib/rig_calibration.h: every (bundle, pose)
// is one placement of the checkerboard; the board's corners come from the natural frame (or the off frame)
// of each step, the laser pixels from the left/right frames against the off frame of the same step
// (laser/extract.h), kept only inside the board's outer corners (the line also crosses the table top).
#include <array>
#include <cmath>
#include <iomanip>
#include <map>
#include <memory>
#include <ostream>
#include <tuple>

#include <opencv2/core.hpp>

#include "command.h"
#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/calib/rig_calibration.h"
#include "rotoscan/core/file.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/laser/extract.h"

namespace rotoscan::cli {
namespace {

// 8-bit copy of a frame (16-bit frames scaled by their bit depth).
cv::Mat To8Bit(const cv::Mat& image, int bit_depth) {
  if (image.depth() == CV_8U) return image;
  cv::Mat out;
  image.convertTo(out, CV_8U, 255.0 / ((1 << std::max(1, std::min(16, bit_depth))) - 1));
  return out;
}

// True when `p` lies inside the convex quadrilateral `quad` (either winding) by at least `margin` px.
bool InsideQuad(const std::array<Eigen::Vector2d, 4>& quad, const Eigen::Vector2d& p, double margin) {
  double sign = 0.0;
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector2d edge = quad[(i + 1) % 4] - quad[i];
    const double length = edge.norm();
    if (length == 0.0) return false;
    const Eigen::Vector2d to_p = p - quad[i];
    const double distance = (edge.x() * to_p.y() - edge.y() * to_p.x()) / length;  // signed, px
    if (sign == 0.0) sign = distance < 0 ? -1.0 : 1.0;
    if (sign * distance < margin) return false;
  }
  return true;
}

// Observations from calibration bundles (see the file comment).
Result<calib::CalibrationData> ObservationsFromBundles(const std::vector<std::string>& directories,
                                                       Progress* progress) {
  calib::CalibrationData data;
  int placement_base = 0;
  for (const auto& directory : directories) {
    ROTOSCAN_ASSIGN_OR_RETURN(const bundle::Bundle b, bundle::ReadBundle(directory));
    const std::string where = "bundle " + directory;
    if (b.header.kind != bundle::BundleKind::kCalibration) {
      return InvalidArgumentError(where + " is a scan bundle, not a calibration bundle");
    }
    const bundle::TargetInfo& target = b.header.target;
    if (target.kind != bundle::TargetKind::kCheckerboard &&
        target.kind != bundle::TargetKind::kTableCheckerboard) {
      return UnimplementedError(where + ": target '" + bundle::TargetKindName(target.kind) +
                                "' is not supported by the rig calibration yet (use checkerboard bundles)");
    }
    Result<calib::CheckerboardPattern> pattern = calib::ParsePattern(
        std::to_string(target.cols) + "x" + std::to_string(target.rows), target.square_mm);
    if (!pattern.ok()) return pattern.status().WithContext(where + ": target");
    const geometry::CameraModel& camera = b.header.camera.model;
    if (data.image_width == 0) {
      data.image_width = camera.width;
      data.image_height = camera.height;
    } else if (data.image_width != camera.width || data.image_height != camera.height) {
      return InvalidArgumentError(where + ": image size differs from the first bundle's");
    }
    if (b.header.table_step_rad > 0) {
      if (data.nominal_step_rad > 0 && std::abs(data.nominal_step_rad - b.header.table_step_rad) > 1e-12) {
        return InvalidArgumentError(where + ": table step differs from the first bundle's");
      }
      data.nominal_step_rad = b.header.table_step_rad;
    }
    const int bit_depth = b.header.camera.bit_depth;
    const std::vector<Eigen::Vector3d> board = pattern->CornersInTarget();
    ProgressScope scope(progress, "reading " + directory, b.frames.size());
    // Board corners per (pose, step), from the natural frame, else the off frame.
    std::map<std::pair<int, int>, std::size_t> view_of;
    int max_pose = 0;
    for (const bundle::LaserState state : {bundle::LaserState::kNatural, bundle::LaserState::kOff}) {
      for (const auto& frame : b.frames) {
        if (frame.laser != state) continue;
        const std::pair<int, int> key(std::max(frame.pose, 0), frame.step);
        if (view_of.count(key) != 0) continue;
        scope.Advance();
        ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat image, bundle::ReadFrame(b, frame));
        Result<std::vector<Eigen::Vector2d>> corners =
            calib::DetectCheckerboard(To8Bit(image, bit_depth), *pattern);
        if (!corners.ok()) {
          ROTOSCAN_LOG(kWarning) << directory << "/" << frame.file << ": " << corners.status().message();
          continue;
        }
        calib::TargetView view;
        view.placement = placement_base + key.first;
        view.step = frame.step;
        view.table_angle_rad = frame.table_angle_rad;
        view.corners_in_target = board;
        view.corner_pixels = std::move(corners).value();
        view.name = std::filesystem::path(directory).filename().string() + "/" + frame.file;
        view_of[key] = data.target_views.size();
        data.target_views.push_back(std::move(view));
        max_pose = std::max(max_pose, key.first);
      }
    }
    // Laser pixels inside the board's outer corners.
    laser::LineExtractor extractor;
    for (const auto& frame : b.frames) {
      if (frame.laser != bundle::LaserState::kLeft && frame.laser != bundle::LaserState::kRight) continue;
      scope.Advance();
      const std::pair<int, int> key(std::max(frame.pose, 0), frame.step);
      const auto view = view_of.find(key);
      const int off_index = b.FindFrame(frame.step, bundle::LaserState::kOff, frame.pose);
      if (view == view_of.end() || off_index < 0) continue;
      ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat on, bundle::ReadFrame(b, frame));
      ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat off, bundle::ReadFrame(b, static_cast<std::size_t>(off_index)));
      laser::Line line;
      ROTOSCAN_RETURN_IF_ERROR(
          extractor.Extract(To8Bit(on, bit_depth), To8Bit(off, bit_depth), &line).WithContext(frame.file));
      const auto& px = data.target_views[view->second].corner_pixels;
      const int cols = pattern->cols, rows = pattern->rows;
      const std::array<Eigen::Vector2d, 4> outline = {px[0], px[cols - 1], px[rows * cols - 1],
                                                      px[(rows - 1) * cols]};
      calib::LaserView laser_view;
      laser_view.laser =
          frame.laser == bundle::LaserState::kLeft ? geometry::LaserId::kLeft : geometry::LaserId::kRight;
      laser_view.placement = placement_base + key.first;
      laser_view.step = frame.step;
      laser_view.table_angle_rad = frame.table_angle_rad;
      laser_view.name = std::filesystem::path(directory).filename().string() + "/" + frame.file;
      for (const auto& point : line.points) {
        const Eigen::Vector2d p(point.column, point.row);
        if (InsideQuad(outline, p, 2.0)) laser_view.pixels.push_back(p);
      }
      if (!laser_view.pixels.empty()) data.laser_views.push_back(std::move(laser_view));
    }
    placement_base += max_pose + 1;
  }
  if (data.nominal_step_rad <= 0) {
    return InvalidArgumentError("no bundle has a table step: include a table calibration bundle");
  }
  // Renumber placements densely (a pose without any detected view leaves a gap).
  std::map<int, int> dense;
  for (const auto& v : data.target_views) dense.emplace(v.placement, 0);
  int next = 0;
  for (auto& [placement, index] : dense) index = next++;
  for (auto& v : data.target_views) v.placement = dense[v.placement];
  std::vector<calib::LaserView> kept;
  for (auto& v : data.laser_views) {
    if (dense.count(v.placement) == 0) continue;
    v.placement = dense[v.placement];
    kept.push_back(std::move(v));
  }
  data.laser_views = std::move(kept);
  return data;
}

}  // namespace

struct CalibrateRigOptions {
  std::vector<std::string> bundles;
  std::string out = "calib.yaml";
  std::string report;
};

int RunCalibrateRig(const CalibrateRigOptions& options, const Context& context) {
  const std::string command = "calibrate";
  if (options.bundles.empty()) {
    return ReportStatus(context, command, InvalidArgumentError("no calibration bundle given"));
  }
  Result<calib::CalibrationData> data = ObservationsFromBundles(options.bundles, context.progress);
  if (!data.ok()) return ReportStatus(context, command, data.status());
  const calib::RigCalibrationOptions calibration_options;
  Result<calib::RigEstimate> initial = calib::CalibrateThreeStep(*data, calibration_options);
  if (!initial.ok()) return ReportStatus(context, command, initial.status());
  Result<calib::RigCalibration> refined = calib::RefineRig(*data, *initial, calibration_options);
  if (!refined.ok()) return ReportStatus(context, command, refined.status());
  Status written = calib::WriteCalibrationYaml(options.out, *refined);
  if (!written.ok()) return ReportStatus(context, command, written);
  if (!options.report.empty()) {
    written = WriteFileAtomically(options.report, calib::SummaryToJson(refined->summary));
    if (!written.ok()) return ReportStatus(context, command, written);
  }

  const calib::RigCalibrationSummary& s = refined->summary;
  const geometry::Rig& rig = refined->estimate.rig;
  std::ostream& out = *context.out;
  out << std::fixed << std::setprecision(4);
  out << "rig from " << s.target_views << " target views in " << s.placements << " placements, "
      << s.laser_points[0] << " + " << s.laser_points[1] << " laser points\n";
  out << "  fx " << rig.camera.fx << " fy " << rig.camera.fy << " cx " << rig.camera.cx << " cy "
      << rig.camera.cy << " px\n";
  out << "  reprojection RMS " << s.rms_px << " px; laser plane residual left " << s.laser_rms_mm[0]
      << " right " << s.laser_rms_mm[1] << " mm; axis fit " << s.axis_fit_rms_mm << " mm; table angle scale "
      << s.angle_scale << "\n";
  const calib::RigCalibrationSummary three_step = calib::Evaluate(*data, *initial, calibration_options);
  out << "  (three-step before refinement: RMS " << three_step.rms_px << " px, laser "
      << three_step.laser_rms_mm[0] << " / " << three_step.laser_rms_mm[1] << " mm)\n";
  // Virtual-scanner bundles carry the true rig: say how far each estimate is from it (the last bundle's
  // truth; the others should hold the same rig).
  for (auto it = options.bundles.rbegin(); it != options.bundles.rend(); ++it) {
    const std::filesystem::path truth_path = bundle::TruthRigPath(*it);
    std::error_code ec;
    if (!std::filesystem::exists(truth_path, ec)) continue;
    Result<geometry::Rig> truth = geometry::ReadRigYaml(truth_path);
    if (!truth.ok()) break;
    out << "  compared with " << truth_path.string() << ":\n";
    for (const geometry::Rig* estimate : {static_cast<const geometry::Rig*>(&initial->rig), &rig}) {
      out << (estimate == &rig ? "  joint vs truth:      " : "  three-step vs truth: ") << "fx "
          << 100.0 * (estimate->camera.fx / truth->camera.fx - 1.0) << " %";
      for (int l = 0; l < 2; ++l) {
        const double angle = geometry::RadToDeg(std::acos(
            std::min(1.0, std::abs(estimate->laser_plane[l].normal.dot(truth->laser_plane[l].normal)))));
        out << ", " << geometry::LaserName(static_cast<geometry::LaserId>(l)) << " normal " << angle
            << " deg offset "
            << std::abs(estimate->laser_plane[l].Canonical().offset -
                        truth->laser_plane[l].Canonical().offset)
            << " mm";
      }
      const Eigen::Vector3d off = estimate->axis_point_in_cam - truth->axis_point_in_cam;
      const Eigen::Vector3d& a = truth->axis_direction_in_cam;
      out << ", axis " << (off - a.dot(off) * a).norm() << " mm "
          << geometry::RadToDeg(std::acos(std::min(1.0, std::abs(estimate->axis_direction_in_cam.dot(a)))))
          << " deg\n";
    }
    break;
  }
  out << "wrote " << options.out << (options.report.empty() ? "" : " and " + options.report) << "\n";
  if (!s.passed) {
    *context.err << "rotoscan calibrate: the calibration did not pass its checks:\n";
    for (const auto& f : s.failures) *context.err << "  - " << f << "\n";
    return kExitFailure;
  }
  out << "calibration passed its checks\n";
  return kExitOk;
}

struct CalibrateCameraOptions {
  std::string images;
  std::string pattern;
  double square_mm = 0.0;
  std::string out = "camera.yaml";
  bool fix_aspect_ratio = false;
  int min_views = 6;
};

int RunCalibrateCamera(const CalibrateCameraOptions& options, const Context& context) {
  const std::string command = "calibrate camera";
  Result<calib::CheckerboardPattern> pattern = calib::ParsePattern(options.pattern, options.square_mm);
  if (!pattern.ok()) return ReportStatus(context, command, pattern.status());
  calib::CameraCalibrationOptions calibration_options;
  calibration_options.pattern = *pattern;
  calibration_options.fix_aspect_ratio = options.fix_aspect_ratio;
  calibration_options.min_views = options.min_views;
  Result<calib::CameraCalibration> result =
      calib::CalibrateCameraFromDirectory(options.images, calibration_options, context.progress);
  if (!result.ok()) return ReportStatus(context, command, result.status());
  const Status written = calib::WriteCameraYaml(options.out, *result);
  if (!written.ok()) return ReportStatus(context, command, written);

  const geometry::CameraModel& c = result->camera;
  std::ostream& out = *context.out;
  out << std::fixed << std::setprecision(3);
  out << "camera " << c.width << "x" << c.height << " from " << result->views.size() << " views\n";
  out << "  fx " << c.fx << " +- " << result->intrinsics_std[0] << "  fy " << c.fy << " +- "
      << result->intrinsics_std[1] << " px\n";
  out << "  cx " << c.cx << " +- " << result->intrinsics_std[2] << "  cy " << c.cy << " +- "
      << result->intrinsics_std[3] << " px\n";
  out << std::setprecision(5) << "  distortion k1 k2 p1 p2 k3:";
  for (double k : c.distortion) out << " " << k;
  out << "\n" << std::setprecision(3) << "  reprojection RMS " << result->rms_px << " px\n";
  for (std::size_t i = 0; i < result->views.size(); ++i) {
    out << "    " << result->views[i] << ": " << result->per_view_rms_px[i] << " px\n";
  }
  for (const auto& r : result->rejected) out << "  skipped " << r << "\n";
  out << "wrote " << options.out << "\n";
  return kExitOk;
}

void RegisterCalibrate(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "calibrate", "Calibrate the rig from calibration bundles, or the camera alone (calibrate camera)");
  auto rig_options = std::make_shared<CalibrateRigOptions>();
  sub->add_option("bundles", rig_options->bundles, "calibration bundle directories");
  sub->add_option("--out", rig_options->out, "output calibration (calib.yaml)")->capture_default_str();
  sub->add_option("--report", rig_options->report, "calibration report (JSON)");
  sub->callback([rig_options, &context, exit_code, sub] {
    if (sub->got_subcommand("camera")) return;
    *exit_code = RunCalibrateRig(*rig_options, context);
  });

  auto camera_options = std::make_shared<CalibrateCameraOptions>();
  CLI::App* camera =
      sub->add_subcommand("camera", "Camera intrinsics and distortion from checkerboard images");
  camera->add_option("--images", camera_options->images, "directory of checkerboard images")->required();
  camera->add_option("--pattern", camera_options->pattern, "inner corners, COLSxROWS (e.g. 9x6)")->required();
  camera->add_option("--square", camera_options->square_mm, "square size in mm")->required();
  camera->add_option("--out", camera_options->out, "output (camera.yaml)")->capture_default_str();
  camera->add_flag("--fix-aspect-ratio", camera_options->fix_aspect_ratio,
                   "estimate one focal length (fx = fy)");
  camera->add_option("--min-views", camera_options->min_views, "fewest views with the board found")
      ->capture_default_str()
      ->check(CLI::Range(3, 10000));
  camera->callback(
      [camera_options, &context, exit_code] { *exit_code = RunCalibrateCamera(*camera_options, context); });
}

}  // namespace rotoscan::cli
