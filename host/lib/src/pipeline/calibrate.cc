#include "rotoscan/pipeline/calibrate.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <map>
#include <set>
#include <sstream>
#include <utility>

#include <opencv2/core.hpp>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/calib/calibration_object.h"
#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/core/file.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/geometry/dlt.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/laser/extract.h"
#include "rotoscan/pipeline/process.h"

namespace rotoscan::pipeline {
namespace {

// (pose, step): one view of one placement.
using ViewKey = std::pair<int, int>;

ViewKey KeyOf(const bundle::FrameRecord& frame) {
  return {std::max(frame.pose, 0), frame.step};
}

std::string ViewName(const std::filesystem::path& dir, const bundle::FrameRecord& frame) {
  return dir.filename().string() + "/" + frame.file;
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

// The checker squares of one target plane in the image: a homography from pixels to the plane's two in-plane
// target coordinates (mm; the checker's edges lie at whole multiples of the square there).
struct CheckerPlane {
  Eigen::Matrix3d plane_from_pixel = Eigen::Matrix3d::Identity();
  double square_mm = 0.0;
  bool valid = false;
};

CheckerPlane CheckerPlaneOf(const calib::TargetView& view, const Eigen::Vector4d& plane, double square_mm) {
  CheckerPlane out;
  out.square_mm = square_mm;
  // The in-plane axes: the two target axes other than the plane normal's largest component.
  int normal_axis = 0;
  plane.head<3>().cwiseAbs().maxCoeff(&normal_axis);
  const int a = normal_axis == 0 ? 1 : 0, b = normal_axis == 2 ? 1 : 2;
  std::vector<Eigen::Vector2d> pixels, coords;
  for (std::size_t i = 0; i < view.corners_in_target.size(); ++i) {
    const Eigen::Vector3d& x = view.corners_in_target[i];
    if (std::abs(plane.head<3>().dot(x) + plane(3)) > 1e-6) continue;
    pixels.push_back(view.corner_pixels[i]);
    coords.emplace_back(x(a), x(b));
  }
  if (pixels.size() < 4 || !(square_mm > 0)) return out;
  Result<Eigen::Matrix3d> h = geometry::EstimateHomographyDlt(pixels, coords);
  out.valid = h.ok();
  if (out.valid) out.plane_from_pixel = *h;
  return out;
}

// True when the segment between two pixels, mapped onto the target plane, crosses an edge of the checker.
bool CrossesCheckerEdge(const CheckerPlane& plane, const Eigen::Vector2d& p, const Eigen::Vector2d& q) {
  auto map = [&](const Eigen::Vector2d& pixel) -> Eigen::Vector2d {  // in squares
    const Eigen::Vector3d x = plane.plane_from_pixel * pixel.homogeneous();
    return x.hnormalized() / plane.square_mm;
  };
  const Eigen::Vector2d a = map(p), b = map(q);
  return std::floor(a.x()) != std::floor(b.x()) || std::floor(a.y()) != std::floor(b.y());
}

// The points of `line` inside `outline` whose row profile lies on one checker square (see the header).
std::vector<Eigen::Vector2d> LaserPixelsOnTarget(const laser::Line& line,
                                                 const std::array<Eigen::Vector2d, 4>& outline,
                                                 const CheckerPlane& plane, int smooth_half_rows) {
  std::vector<Eigen::Vector2d> inside;
  std::vector<bool> near_edge;
  for (const auto& point : line.points) {
    const Eigen::Vector2d p(point.column, point.row);
    if (!InsideQuad(outline, p, 2.0)) continue;
    const double half = std::max(1.0, static_cast<double>(point.width)) + 1.0;
    const Eigen::Vector2d left(p.x() - half, p.y()), right(p.x() + half, p.y());
    inside.push_back(p);
    near_edge.push_back(plane.valid && CrossesCheckerEdge(plane, left, right));
  }
  std::vector<Eigen::Vector2d> kept;
  for (std::size_t i = 0; i < inside.size(); ++i) {
    bool clean = true;
    for (std::size_t j = 0; j < inside.size() && clean; ++j) {
      clean = !(near_edge[j] && std::abs(inside[j].y() - inside[i].y()) <= smooth_half_rows);
    }
    if (clean) kept.push_back(inside[i]);
  }
  return kept;
}

// The target of one calibration bundle: the paper's object or a checkerboard.
struct BundleTarget {
  bool object = false;
  calib::CalibrationObjectSpec object_spec;    // object
  calib::CheckerboardPattern pattern;          // board
  std::vector<Eigen::Vector3d> board_corners;  // board: corners in the target frame, mm
  double square_mm = 0.0;
  double origin_height_mm = 0.0;  // bundle.h TargetInfo::origin_height_mm
};

Result<BundleTarget> TargetOf(const bundle::Bundle& b, const std::string& where) {
  if (b.header.kind != bundle::BundleKind::kCalibration) {
    return InvalidArgumentError(where + " is a scan bundle, not a calibration bundle");
  }
  const bundle::TargetInfo& info = b.header.target;
  BundleTarget target;
  target.object = info.kind == bundle::TargetKind::kCalibrationObject;
  if (!target.object && info.kind != bundle::TargetKind::kCheckerboard &&
      info.kind != bundle::TargetKind::kTableCheckerboard) {
    return InvalidArgumentError(where + ": target '" + bundle::TargetKindName(info.kind) +
                                "' is not a calibration target (checkerboard or calibration_object)");
  }
  target.square_mm = info.square_mm;
  target.origin_height_mm = info.origin_height_mm;
  if (target.object) {
    target.object_spec.square_mm = info.square_mm;
    if (info.cols > 0) target.object_spec.corners_per_side = info.cols;  // else the paper's 60 mm object
    ROTOSCAN_RETURN_IF_ERROR(target.object_spec.Check().WithContext(where));
  } else {
    Result<calib::CheckerboardPattern> pattern =
        calib::ParsePattern(std::to_string(info.cols) + "x" + std::to_string(info.rows), info.square_mm);
    if (!pattern.ok()) return pattern.status().WithContext(where + ": target");
    target.pattern = *pattern;
    target.board_corners = pattern->CornersInTarget();
  }
  return target;
}

// The bundle's image size and table step into `data`, checked against the earlier bundles'.
Status AddImageSizeAndStep(const bundle::Bundle& b, const std::string& where, calib::CalibrationData* data) {
  const geometry::CameraModel& camera = b.header.camera.model;
  if (data->image_width == 0) {
    data->image_width = camera.width;
    data->image_height = camera.height;
  } else if (data->image_width != camera.width || data->image_height != camera.height) {
    return InvalidArgumentError(where + ": image size differs from the first bundle's");
  }
  if (b.header.table_step_rad > 0) {
    if (data->nominal_step_rad > 0 && std::abs(data->nominal_step_rad - b.header.table_step_rad) > 1e-12) {
      return InvalidArgumentError(where + ": table step differs from the first bundle's");
    }
    data->nominal_step_rad = b.header.table_step_rad;
  }
  return Status::Ok();
}

// The target found in one 8-bit image: its corners and its planes in the image (image quad, plane in the
// target frame) for the laser pixels. The detector's kNotFound when it is not there.
Status DetectTarget(const cv::Mat& image, const BundleTarget& target, calib::TargetView* view,
                    std::vector<calib::CalibrationObjectFace>* faces) {
  if (target.object) {
    ROTOSCAN_ASSIGN_OR_RETURN(calib::CalibrationObjectCorners found,
                              calib::DetectCalibrationObject(image, target.object_spec));
    view->corners_in_target = std::move(found.corners_in_target);
    view->corner_pixels = std::move(found.pixels);
    faces->assign(found.faces.begin(), found.faces.end());
    return Status::Ok();
  }
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<Eigen::Vector2d> corners,
                            calib::DetectCheckerboard(image, target.pattern));
  view->corners_in_target = target.board_corners;
  view->corner_pixels = std::move(corners);
  const auto& px = view->corner_pixels;
  const int cols = target.pattern.cols, rows = target.pattern.rows;
  faces->push_back(
      {Eigen::Vector4d(0, 0, 1, 0), {px[0], px[cols - 1], px[rows * cols - 1], px[(rows - 1) * cols]}});
  return Status::Ok();
}

// The target views of one bundle, by (pose, step), and the target's planes in each.
struct BundleViews {
  std::map<ViewKey, std::size_t> view_of;  // index into CalibrationData::target_views
  std::map<ViewKey, std::vector<calib::CalibrationObjectFace>> faces_of;
  std::string not_found_reason;  // why the target was not found, in a frame where it was not
  int max_pose = 0;
};

// Target corners per (pose, step), from the natural frame, else the off frame, appended to data->target_views
// with placement placement_base + pose.
Result<BundleViews> DetectTargetViews(const bundle::Bundle& b, const std::filesystem::path& dir,
                                      const BundleTarget& target, int placement_base, ProgressScope* scope,
                                      calib::CalibrationData* data) {
  BundleViews views;
  const int bit_depth = b.header.camera.bit_depth;
  for (const bundle::LaserState state : {bundle::LaserState::kNatural, bundle::LaserState::kOff}) {
    for (const auto& frame : b.frames) {
      if (frame.laser != state) continue;
      const ViewKey key = KeyOf(frame);
      if (views.view_of.count(key) != 0) continue;
      scope->Advance();
      ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat image, bundle::ReadFrame(b, frame));
      calib::TargetView view;
      std::vector<calib::CalibrationObjectFace> faces;
      const Status found = DetectTarget(To8Bit(image, bit_depth), target, &view, &faces);
      if (!found.ok()) {
        ROTOSCAN_LOG(kDebug) << dir.string() << "/" << frame.file << ": " << found.message();
        views.not_found_reason = found.message();
        continue;
      }
      view.placement = placement_base + key.first;
      view.origin_height_mm = target.origin_height_mm;
      view.step = frame.step;
      view.table_angle_rad = frame.table_angle_rad;
      view.name = ViewName(dir, frame);
      views.view_of[key] = data->target_views.size();
      views.faces_of[key] = std::move(faces);
      data->target_views.push_back(std::move(view));
      views.max_pose = std::max(views.max_pose, key.first);
    }
  }
  return views;
}

// One warning per bundle for the views without the target (each frame's reason is logged at debug level).
void WarnMissingViews(const bundle::Bundle& b, const std::filesystem::path& dir, const BundleViews& found) {
  std::set<ViewKey> views;
  for (const auto& frame : b.frames) {
    if (frame.laser == bundle::LaserState::kNatural || frame.laser == bundle::LaserState::kOff)
      views.insert(KeyOf(frame));
  }
  std::vector<int> missing;
  for (const auto& key : views) {
    if (found.view_of.count(key) == 0) missing.push_back(key.second);
  }
  if (missing.empty()) return;
  std::ostringstream steps;
  for (size_t k = 0; k < missing.size(); ++k) steps << (k > 0 ? " " : "") << missing[k];
  ROTOSCAN_LOG(kWarning) << dir.string() << ": target not found at " << missing.size() << " of "
                         << views.size() << " views (steps " << steps.str() << "): " << found.not_found_reason
                         << "; those views are left out (--log-level debug lists each frame)";
}

// Laser pixels inside the board's outer corners, or inside a face of the object, from every laser frame of
// a view where the target was found, against the off frame of the same step; appended to data->laser_views.
Status CollectLaserViews(const bundle::Bundle& b, const std::filesystem::path& dir,
                         const BundleTarget& target, int placement_base, const BundleViews& views,
                         ProgressScope* scope, calib::CalibrationData* data) {
  const int bit_depth = b.header.camera.bit_depth;
  laser::LineExtractor extractor;
  for (const auto& frame : b.frames) {
    if (frame.laser != bundle::LaserState::kLeft && frame.laser != bundle::LaserState::kRight) continue;
    scope->Advance();
    const ViewKey key = KeyOf(frame);
    const auto view = views.view_of.find(key);
    const int off_index = b.FindFrame(frame.step, bundle::LaserState::kOff, frame.pose);
    if (view == views.view_of.end() || off_index < 0) continue;
    ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat on, bundle::ReadFrame(b, frame));
    ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat off, bundle::ReadFrame(b, static_cast<std::size_t>(off_index)));
    laser::Line line;
    ROTOSCAN_RETURN_IF_ERROR(
        extractor.Extract(To8Bit(on, bit_depth), To8Bit(off, bit_depth), &line).WithContext(frame.file));
    for (const calib::CalibrationObjectFace& face : views.faces_of.at(key)) {
      calib::LaserView laser_view;
      laser_view.laser =
          frame.laser == bundle::LaserState::kLeft ? geometry::LaserId::kLeft : geometry::LaserId::kRight;
      laser_view.placement = placement_base + key.first;
      laser_view.step = frame.step;
      laser_view.table_angle_rad = frame.table_angle_rad;
      laser_view.plane_in_target = face.plane_in_target;
      laser_view.name = ViewName(dir, frame);
      laser_view.pixels = LaserPixelsOnTarget(
          line, face.outline,
          CheckerPlaneOf(data->target_views[view->second], face.plane_in_target, target.square_mm),
          extractor.options().smooth_half_rows);
      if (!laser_view.pixels.empty()) data->laser_views.push_back(std::move(laser_view));
    }
  }
  return Status::Ok();
}

// Renumbers placements densely (a pose without any detected view leaves a gap) and drops laser views of
// placements without a target view.
void RenumberPlacements(calib::CalibrationData* data) {
  std::map<int, int> dense;
  for (const auto& v : data->target_views) dense.emplace(v.placement, 0);
  int next = 0;
  for (auto& [placement, index] : dense) index = next++;
  for (auto& v : data->target_views) v.placement = dense[v.placement];
  std::vector<calib::LaserView> kept;
  for (auto& v : data->laser_views) {
    if (dense.count(v.placement) == 0) continue;
    v.placement = dense[v.placement];
    kept.push_back(std::move(v));
  }
  data->laser_views = std::move(kept);
}

void PrintRigError(const RigError& e, std::ostream& out) {
  out << "fx " << e.fx_percent << " %";
  for (int l = 0; l < 2; ++l) {
    out << ", " << geometry::LaserName(static_cast<geometry::LaserId>(l)) << " normal "
        << e.normal_deg[static_cast<size_t>(l)] << " deg offset " << e.offset_mm[static_cast<size_t>(l)]
        << " mm";
  }
  out << ", axis " << e.axis_offset_mm << " mm " << e.axis_angle_deg << " deg, table top " << e.table_top_mm
      << " mm\n";
}

}  // namespace

Result<calib::CalibrationData> ObservationsFromBundles(const std::vector<std::filesystem::path>& bundle_dirs,
                                                       Progress* progress) {
  calib::CalibrationData data;
  int placement_base = 0;
  for (const std::filesystem::path& dir : bundle_dirs) {
    ROTOSCAN_ASSIGN_OR_RETURN(const bundle::Bundle b, bundle::ReadBundle(dir));
    const std::string where = "bundle " + dir.string();
    ROTOSCAN_ASSIGN_OR_RETURN(const BundleTarget target, TargetOf(b, where));
    ROTOSCAN_RETURN_IF_ERROR(AddImageSizeAndStep(b, where, &data));
    ProgressScope scope(progress, "reading " + dir.string(), b.frames.size());
    ROTOSCAN_ASSIGN_OR_RETURN(const BundleViews views,
                              DetectTargetViews(b, dir, target, placement_base, &scope, &data));
    WarnMissingViews(b, dir, views);
    ROTOSCAN_RETURN_IF_ERROR(CollectLaserViews(b, dir, target, placement_base, views, &scope, &data));
    placement_base += views.max_pose + 1;
  }
  if (data.nominal_step_rad <= 0) {
    return InvalidArgumentError("no bundle has a table step: include a table calibration bundle");
  }
  RenumberPlacements(&data);
  return data;
}

RigError CompareRigs(const geometry::Rig& estimate, const geometry::Rig& truth) {
  RigError e;
  e.fx_percent = 100.0 * (estimate.camera.fx / truth.camera.fx - 1.0);
  for (size_t l = 0; l < 2; ++l) {
    e.normal_deg[l] = geometry::RadToDeg(
        std::acos(std::min(1.0, std::abs(estimate.laser_plane[l].normal.dot(truth.laser_plane[l].normal)))));
    e.offset_mm[l] =
        std::abs(estimate.laser_plane[l].Canonical().offset - truth.laser_plane[l].Canonical().offset);
  }
  const Eigen::Vector3d off = estimate.axis_point_in_cam - truth.axis_point_in_cam;
  const Eigen::Vector3d& a = truth.axis_direction_in_cam;
  e.axis_offset_mm = (off - a.dot(off) * a).norm();
  e.axis_angle_deg =
      geometry::RadToDeg(std::acos(std::min(1.0, std::abs(estimate.axis_direction_in_cam.dot(a)))));
  e.table_top_mm = std::abs(a.dot(off));
  return e;
}

Result<BundleCalibration> CalibrateFromBundles(const std::vector<std::filesystem::path>& bundle_dirs,
                                               const CalibrateOptions& options, Progress* progress) {
  if (bundle_dirs.empty()) return InvalidArgumentError("no calibration bundle given");
  ROTOSCAN_ASSIGN_OR_RETURN(const calib::CalibrationData data,
                            ObservationsFromBundles(bundle_dirs, progress));
  BundleCalibration result;
  ROTOSCAN_ASSIGN_OR_RETURN(result.three_step, calib::CalibrateThreeStep(data, options.calibration));
  ROTOSCAN_ASSIGN_OR_RETURN(result.calibration,
                            calib::RefineRig(data, result.three_step, options.calibration));
  result.three_step_summary = calib::Evaluate(data, result.three_step, options.calibration);
  // The last bundle's truth (the others should hold the same rig); an unreadable one: no comparison.
  for (auto it = bundle_dirs.rbegin(); it != bundle_dirs.rend(); ++it) {
    const std::filesystem::path truth_path = bundle::TruthRigPath(*it);
    std::error_code ec;
    if (!std::filesystem::exists(truth_path, ec)) continue;
    Result<geometry::Rig> truth = geometry::ReadRigYaml(truth_path);
    if (!truth.ok()) break;
    result.has_truth = true;
    result.truth_path = truth_path;
    result.three_step_error = CompareRigs(result.three_step.rig, *truth);
    result.joint_error = CompareRigs(result.calibration.estimate.rig, *truth);
    break;
  }
  return result;
}

Status WriteBundleCalibration(const BundleCalibration& result, const std::filesystem::path& calib_yaml,
                              const std::filesystem::path& report_json) {
  // calib.yaml and the report are committed together: a failure leaves both as they were.
  Result<std::string> yaml = calib::EncodeCalibrationYaml(result.calibration, calib_yaml.string());
  if (!yaml.ok()) return yaml.status();
  std::vector<PendingFile> files = {FileWithContent(calib_yaml, std::move(*yaml))};
  if (!report_json.empty()) {
    files.push_back(FileWithContent(report_json, calib::SummaryToJson(result.calibration.summary)));
  }
  return WriteFilesTogether(files);
}

std::string FormatCalibrationSummary(const BundleCalibration& result) {
  const calib::RigCalibrationSummary& s = result.calibration.summary;
  const geometry::Rig& rig = result.calibration.estimate.rig;
  std::ostringstream out;
  out << std::fixed << std::setprecision(4);
  out << "rig from " << s.target_views << " target views in " << s.placements << " placements, "
      << s.laser_points[0] << " + " << s.laser_points[1] << " laser points\n";
  out << "  fx " << rig.camera.fx << " fy " << rig.camera.fy << " cx " << rig.camera.cx << " cy "
      << rig.camera.cy << " px\n";
  out << "  reprojection RMS " << s.rms_px << " px; laser plane residual left " << s.laser_rms_mm[0]
      << " right " << s.laser_rms_mm[1] << " mm; axis fit " << s.axis_fit_rms_mm << " mm; table angle scale "
      << s.angle_scale << "\n";
  if (std::isfinite(s.point_std_mm)) {
    out << "  predicted error of a scanned point at " << std::setprecision(0) << s.working_distance_mm
        << std::setprecision(4) << " mm: +-" << s.point_std_mm << " mm (up to +-" << s.point_std_max_mm
        << ")";
    if (s.table_angles_refined)
      out << "; table angles refined, largest slip " << s.max_table_slip_deg << " deg";
    out << "\n";
  }
  for (const auto& note : s.notes) out << "  note: " << note << "\n";
  const calib::RigCalibrationSummary& three_step = result.three_step_summary;
  out << "  (three-step before refinement: RMS " << three_step.rms_px << " px, laser "
      << three_step.laser_rms_mm[0] << " / " << three_step.laser_rms_mm[1] << " mm)\n";
  if (result.has_truth) {
    out << "  compared with " << result.truth_path.string() << ":\n";
    out << "  three-step vs truth: ";
    PrintRigError(result.three_step_error, out);
    out << "  joint vs truth:      ";
    PrintRigError(result.joint_error, out);
  }
  if (!s.table_origin_on_table_top) {
    out << "note: the bundles do not give the target's height above the table (bundle.json "
           "target.origin_height_mm), so the table frame's origin is at the height of a target's origin, "
           "not on the table top\n";
  }
  return out.str();
}

}  // namespace rotoscan::pipeline
