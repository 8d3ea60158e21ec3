// rotoscan calibrate: camera intrinsics from checkerboard or ChArUco images (calibrate camera), or the whole
// rig (camera, both laser planes, table axis) from calibration bundles.
//
// The rig path turns calibration bundles into observations for calib/rig_calibration.h: every (bundle, pose)
// is one placement of the target (a checkerboard, or the paper's two-plane calibration object,
// calib/calibration_object.h); the target's corners come from the natural frame (or the off frame) of each
// step, the laser pixels from the left/right frames against the off frame of the same step
// (laser/extract.h), kept only inside the board's outer corners, or inside one face of the object (the line
// also crosses the table top), each with the target plane it lies on.
//
// Laser pixels next to a checker edge are dropped. The line's centre is the centroid of its profile along
// the image row, and where the target's albedo changes inside that profile (a black/white edge) the centroid
// is pulled towards the white side, by up to the line's half width. The bias is worst when the line runs
// along an edge of the checker (the laser planes contain the table axis and the checker's columns are
// parallel to it on an upright board, so at some table angle the whole line lies within a square's edge):
// on the demo's rendered bundles (2 placements x 24 angles), 390 pixels of two left-laser frames lay 2.3 px
// off the true line and made the left plane's residual 0.048 mm (right: 0.011) and its offset error
// 0.061 mm; without them, 0.007 mm for both. A pixel is kept only when its profile (+-1 FWHM + 1 px along
// the row, mapped onto the target plane by the homography of the view's corners) stays inside one square;
// pixels within the extractor's along-line smoothing window (+-smooth_half_rows) of a dropped one are
// dropped too, since the smoothing spreads its bias along the line.
#include <array>
#include <cmath>
#include <iomanip>
#include <map>
#include <memory>
#include <ostream>
#include <set>
#include <sstream>
#include <tuple>

#include <Eigen/SVD>
#include <opencv2/core.hpp>

#include "calibrate.h"
#include "command.h"
#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/calib/calibration_object.h"
#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/calib/charuco.h"
#include "rotoscan/calib/rig_calibration.h"
#include "rotoscan/core/file.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/laser/extract.h"
#include "rotoscan/pipeline/accuracy.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"

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

// The checker squares of one target plane in the image: a homography from pixels to the plane's two in-plane
// target coordinates (mm; the checker's edges lie at whole multiples of the square there).
struct CheckerPlane {
  Eigen::Matrix3d plane_from_pixel = Eigen::Matrix3d::Identity();
  double square_mm = 0.0;
  bool valid = false;
};

// Homography taking `from` to `to` by the normalised DLT (at least 4 points); false when degenerate.
bool FitHomography(const std::vector<Eigen::Vector2d>& from, const std::vector<Eigen::Vector2d>& to,
                   Eigen::Matrix3d* h) {
  auto normaliser = [](const std::vector<Eigen::Vector2d>& points) -> Eigen::Matrix3d {
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (const auto& p : points) mean += p;
    mean /= static_cast<double>(points.size());
    double spread = 0.0;
    for (const auto& p : points) spread += (p - mean).norm();
    spread /= static_cast<double>(points.size());
    const double k = spread > 0 ? std::sqrt(2.0) / spread : 1.0;
    Eigen::Matrix3d t;
    t << k, 0, -k * mean.x(), 0, k, -k * mean.y(), 0, 0, 1;
    return t;
  };
  const Eigen::Matrix3d tf = normaliser(from), tt = normaliser(to);
  Eigen::MatrixXd a(2 * from.size(), 9);
  for (std::size_t i = 0; i < from.size(); ++i) {
    const Eigen::Vector3d x = tf * from[i].homogeneous();
    const Eigen::Vector3d y = tt * to[i].homogeneous();
    const auto r = static_cast<Eigen::Index>(2 * i);
    a.row(r) << 0, 0, 0, -x.transpose(), y.y() * x.transpose();
    a.row(r + 1) << x.transpose(), 0, 0, 0, -y.x() * x.transpose();
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeFullV);
  const Eigen::VectorXd v = svd.matrixV().col(8);
  if (svd.singularValues()(7) < 1e-9 * svd.singularValues()(0)) return false;
  Eigen::Matrix3d hn;
  hn << v(0), v(1), v(2), v(3), v(4), v(5), v(6), v(7), v(8);
  *h = tt.inverse() * hn * tf;
  return std::isfinite(h->sum());
}

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
  out.valid = pixels.size() >= 4 && square_mm > 0 && FitHomography(pixels, coords, &out.plane_from_pixel);
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

// The points of `line` inside `outline` whose row profile lies on one checker square (see the file comment).
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

}  // namespace

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
    const bool object = target.kind == bundle::TargetKind::kCalibrationObject;
    if (!object && target.kind != bundle::TargetKind::kCheckerboard &&
        target.kind != bundle::TargetKind::kTableCheckerboard) {
      return InvalidArgumentError(where + ": target '" + bundle::TargetKindName(target.kind) +
                                  "' is not a calibration target (checkerboard or calibration_object)");
    }
    calib::CalibrationObjectSpec object_spec;
    Result<calib::CheckerboardPattern> pattern = calib::CheckerboardPattern{};
    if (object) {
      object_spec.square_mm = target.square_mm;
      if (target.cols > 0) object_spec.corners_per_side = target.cols;  // else the paper's 60 mm object
      ROTOSCAN_RETURN_IF_ERROR(object_spec.Check().WithContext(where));
    } else {
      pattern = calib::ParsePattern(std::to_string(target.cols) + "x" + std::to_string(target.rows),
                                    target.square_mm);
      if (!pattern.ok()) return pattern.status().WithContext(where + ": target");
    }
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
    const std::vector<Eigen::Vector3d> board =
        object ? std::vector<Eigen::Vector3d>{} : pattern->CornersInTarget();
    ProgressScope scope(progress, "reading " + directory, b.frames.size());
    // Target corners per (pose, step), from the natural frame, else the off frame; and the target's planes
    // in the image (image quad, plane in the target frame) for the laser pixels.
    std::map<std::pair<int, int>, std::size_t> view_of;
    std::map<std::pair<int, int>, std::vector<calib::CalibrationObjectFace>> faces_of;
    std::string not_found_reason;  // why the target was not found, in a frame where it was not
    int max_pose = 0;
    for (const bundle::LaserState state : {bundle::LaserState::kNatural, bundle::LaserState::kOff}) {
      for (const auto& frame : b.frames) {
        if (frame.laser != state) continue;
        const std::pair<int, int> key(std::max(frame.pose, 0), frame.step);
        if (view_of.count(key) != 0) continue;
        scope.Advance();
        ROTOSCAN_ASSIGN_OR_RETURN(const cv::Mat image, bundle::ReadFrame(b, frame));
        calib::TargetView view;
        std::vector<calib::CalibrationObjectFace> faces;
        if (object) {
          Result<calib::CalibrationObjectCorners> found =
              calib::DetectCalibrationObject(To8Bit(image, bit_depth), object_spec);
          if (!found.ok()) {
            ROTOSCAN_LOG(kDebug) << directory << "/" << frame.file << ": " << found.status().message();
            not_found_reason = found.status().message();
            continue;
          }
          view.corners_in_target = std::move(found->corners_in_target);
          view.corner_pixels = std::move(found->pixels);
          faces.assign(found->faces.begin(), found->faces.end());
        } else {
          Result<std::vector<Eigen::Vector2d>> corners =
              calib::DetectCheckerboard(To8Bit(image, bit_depth), *pattern);
          if (!corners.ok()) {
            ROTOSCAN_LOG(kDebug) << directory << "/" << frame.file << ": " << corners.status().message();
            not_found_reason = corners.status().message();
            continue;
          }
          view.corners_in_target = board;
          view.corner_pixels = std::move(corners).value();
          const auto& px = view.corner_pixels;
          const int cols = pattern->cols, rows = pattern->rows;
          faces.push_back({Eigen::Vector4d(0, 0, 1, 0),
                           {px[0], px[cols - 1], px[rows * cols - 1], px[(rows - 1) * cols]}});
        }
        view.placement = placement_base + key.first;
        view.origin_height_mm = target.origin_height_mm;
        view.step = frame.step;
        view.table_angle_rad = frame.table_angle_rad;
        view.name = std::filesystem::path(directory).filename().string() + "/" + frame.file;
        view_of[key] = data.target_views.size();
        faces_of[key] = std::move(faces);
        data.target_views.push_back(std::move(view));
        max_pose = std::max(max_pose, key.first);
      }
    }
    // One line per bundle for the views without the target (each frame's reason is logged at debug level).
    {
      std::set<std::pair<int, int>> views;
      for (const auto& frame : b.frames) {
        if (frame.laser == bundle::LaserState::kNatural || frame.laser == bundle::LaserState::kOff)
          views.emplace(std::max(frame.pose, 0), frame.step);
      }
      std::vector<int> missing;
      for (const auto& key : views) {
        if (view_of.count(key) == 0) missing.push_back(key.second);
      }
      if (!missing.empty()) {
        std::ostringstream steps;
        for (size_t k = 0; k < missing.size(); ++k) steps << (k > 0 ? " " : "") << missing[k];
        ROTOSCAN_LOG(kWarning) << directory << ": target not found at " << missing.size() << " of "
                               << views.size() << " views (steps " << steps.str() << "): " << not_found_reason
                               << "; those views are left out (--log-level debug lists each frame)";
      }
    }
    // Laser pixels inside the board's outer corners, or inside a face of the object.
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
      for (const calib::CalibrationObjectFace& face : faces_of[key]) {
        calib::LaserView laser_view;
        laser_view.laser =
            frame.laser == bundle::LaserState::kLeft ? geometry::LaserId::kLeft : geometry::LaserId::kRight;
        laser_view.placement = placement_base + key.first;
        laser_view.step = frame.step;
        laser_view.table_angle_rad = frame.table_angle_rad;
        laser_view.plane_in_target = face.plane_in_target;
        laser_view.name = std::filesystem::path(directory).filename().string() + "/" + frame.file;
        laser_view.pixels =
            LaserPixelsOnTarget(line, face.outline,
                                CheckerPlaneOf(data.target_views[view->second], face.plane_in_target,
                                               target.square_mm),
                                extractor.options().smooth_half_rows);
        if (!laser_view.pixels.empty()) data.laser_views.push_back(std::move(laser_view));
      }
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

Result<CalibratedAccuracy> RunCalibratedPlaneAccuracy(const CalibratedAccuracyOptions& options,
                                                      Progress* progress) {
  if (options.work_dir.empty()) return InvalidArgumentError("no work directory");
  const std::string camera = "\"camera\": {\"distortion\": [" + std::to_string(options.k1) + ", 0, 0, 0, 0]}";
  std::vector<std::string> bundles;
  // One calibration bundle of `object` (a JSON object without its closing brace) standing at `placement`.
  auto render = [&](int seed, const std::string& object, const char* placement, const std::string& name,
                    sim::SimulateKind kind) -> Status {
    const std::string json = "{\"seed\": " + std::to_string(seed) + ", " + camera + ", \"objects\": [" +
                             object + ", " + placement + "}]}";
    ROTOSCAN_ASSIGN_OR_RETURN(const sim::Scene scene,
                              sim::ParseScene(json, options.work_dir, "calibration scene"));
    sim::SimulateOptions simulate;
    simulate.out = options.work_dir / name;
    simulate.kind = kind;
    simulate.steps = options.calibration_steps;
    simulate.overwrite = true;
    ROTOSCAN_RETURN_IF_ERROR(sim::Simulate(scene, simulate, progress));
    bundles.push_back(simulate.out.string());
    return Status::Ok();
  };
  if (options.target == CalibrationTarget::kObject) {
    // The placements of data/scenes/calibration-object.json and calibration-object-2.json.
    const char* placements[] = {"\"position_mm\": [0, 20, 0]",
                                "\"position_mm\": [-30, 60, 0], \"rotation_deg\": [0, 0, 30]"};
    for (int p = 0; p < 2; ++p) {
      ROTOSCAN_RETURN_IF_ERROR(render(p + 1, "{\"type\": \"calibration_object\", \"square_mm\": 10",
                                      placements[p], "calibration-object-" + std::to_string(p + 1),
                                      sim::SimulateKind::kCalibrationObject));
    }
  } else {
    // The placements of data/scenes/calibration.json, calibration-2.json and calibration-3.json.
    const char* placements[] = {"\"position_mm\": [20, 20, 0]", "\"position_mm\": [-20, -20, 0]",
                                "\"position_mm\": [0, 25, 0], \"rotation_deg\": [-25, 0, 0]"};
    for (int p = 0; p < 3; ++p) {
      ROTOSCAN_RETURN_IF_ERROR(render(
          p + 1, "{\"type\": \"checkerboard\", \"cols\": 15, \"rows\": 12, \"square_mm\": 4", placements[p],
          "table-board-" + std::to_string(p + 1), sim::SimulateKind::kTableCheckerboard));
    }
  }
  if (options.board_poses > 0) {
    // A checkerboard held over the whole field of view: it fixes the lens distortion, which the object
    // (in the middle of the image) leaves loose. The three-step result does not use it (the paper's DLT
    // models no distortion); the joint refinement does.
    const std::string json = "{\"seed\": 3, " + camera +
                             ", \"objects\": [{\"type\": \"checkerboard\", \"cols\": 9, \"rows\": 6, "
                             "\"square_mm\": 7}]}";
    ROTOSCAN_ASSIGN_OR_RETURN(const sim::Scene scene, sim::ParseScene(json, options.work_dir, "board scene"));
    sim::SimulateOptions simulate;
    simulate.out = options.work_dir / "checkerboard";
    simulate.kind = sim::SimulateKind::kCheckerboard;
    simulate.steps = options.board_poses;
    simulate.overwrite = true;
    ROTOSCAN_RETURN_IF_ERROR(sim::Simulate(scene, simulate, progress));
    bundles.push_back(simulate.out.string());
  }
  ROTOSCAN_ASSIGN_OR_RETURN(const calib::CalibrationData data, ObservationsFromBundles(bundles, progress));
  const calib::RigCalibrationOptions calibration_options;
  ROTOSCAN_ASSIGN_OR_RETURN(const calib::RigEstimate three_step,
                            calib::CalibrateThreeStep(data, calibration_options));
  ROTOSCAN_ASSIGN_OR_RETURN(const calib::RigCalibration joint,
                            calib::RefineRig(data, three_step, calibration_options));

  const std::string json = "{" + camera + ", \"objects\": [{\"type\": \"plane\", \"distance_mm\": " +
                           std::to_string(options.distance_mm) +
                           ", \"angle_deg\": 20, \"size_mm\": [150, 120], \"color\": [0.9, 0.9, 0.9]}]}";
  ROTOSCAN_ASSIGN_OR_RETURN(const sim::Scene scene, sim::ParseScene(json, options.work_dir, "plane scene"));
  sim::SimulateOptions simulate;
  simulate.out = options.work_dir / "plane";
  simulate.steps = options.scan_steps;
  simulate.overwrite = true;
  ROTOSCAN_RETURN_IF_ERROR(sim::Simulate(scene, simulate, progress));
  pipeline::ProcessOptions process;
  process.merge = false;  // both lasers measure the same plane; keep every point
  CalibratedAccuracy out;
  // A calibrated rig may put the plane a few millimetres off: points within 5 mm of the true plane count
  // (the true rig's, within the test's usual 2 mm).
  constexpr double kCalibratedWindowMm = 5.0;
  Result<pipeline::PlaneAccuracy> a3 =
      pipeline::MeasurePlaneAccuracy(simulate.out, three_step.rig, process, kCalibratedWindowMm);
  if (!a3.ok()) return a3.status().WithContext("plane scanned with the three-step rig");
  Result<pipeline::PlaneAccuracy> aj =
      pipeline::MeasurePlaneAccuracy(simulate.out, joint.estimate.rig, process, kCalibratedWindowMm);
  if (!aj.ok()) return aj.status().WithContext("plane scanned with the jointly refined rig");
  ROTOSCAN_ASSIGN_OR_RETURN(const pipeline::PlaneAccuracy at,
                            pipeline::MeasurePlaneAccuracy(simulate.out, scene.rig, process));
  out.three_step_rms_mm = a3->rms_mm;
  out.three_step_mean_mm = a3->mean_mm;
  out.joint_rms_mm = aj->rms_mm;
  out.joint_mean_mm = aj->mean_mm;
  out.true_rig_rms_mm = at.rms_mm;
  out.true_rig_mean_mm = at.mean_mm;
  out.points = aj->points;
  out.three_step = calib::Evaluate(data, three_step, calibration_options);
  out.joint = joint.summary;
  return out;
}

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
  std::vector<OutputPath> outputs{{options.out, "--out"}};
  if (!options.report.empty()) outputs.push_back({options.report, "--report"});
  const Status paths =
      CheckOutputPaths(outputs, std::vector<std::filesystem::path>(options.bundles.begin(), options.bundles.end()));
  if (!paths.ok()) return ReportStatus(context, command, paths);
  Result<calib::CalibrationData> data = ObservationsFromBundles(options.bundles, context.progress);
  if (!data.ok()) return ReportStatus(context, command, data.status());
  const calib::RigCalibrationOptions calibration_options;
  Result<calib::RigEstimate> initial = calib::CalibrateThreeStep(*data, calibration_options);
  if (!initial.ok()) return ReportStatus(context, command, initial.status());
  Result<calib::RigCalibration> refined = calib::RefineRig(*data, *initial, calibration_options);
  if (!refined.ok()) return ReportStatus(context, command, refined.status());
  // calib.yaml and the report are committed together: a failure leaves both as they were.
  Result<std::string> yaml = calib::EncodeCalibrationYaml(*refined, options.out);
  if (!yaml.ok()) return ReportStatus(context, command, yaml.status());
  std::vector<PendingFile> files = {FileWithContent(options.out, std::move(*yaml))};
  if (!options.report.empty()) files.push_back(FileWithContent(options.report, calib::SummaryToJson(refined->summary)));
  const Status written = WriteFilesTogether(files);
  if (!written.ok()) return ReportStatus(context, command, written);

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
  if (std::isfinite(s.point_std_mm)) {
    out << "  predicted error of a scanned point at " << std::setprecision(0) << s.working_distance_mm
        << std::setprecision(4) << " mm: +-" << s.point_std_mm << " mm (up to +-" << s.point_std_max_mm
        << ")";
    if (s.table_angles_refined) out << "; table angles refined, largest slip " << s.max_table_slip_deg << " deg";
    out << "\n";
  }
  for (const auto& note : s.notes) out << "  note: " << note << "\n";
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
          << " deg, table top " << std::abs(a.dot(off)) << " mm\n";
    }
    break;
  }
  if (!s.table_origin_on_table_top) {
    out << "note: the bundles do not give the target's height above the table (bundle.json "
           "target.origin_height_mm), so the table frame's origin is at the height of a target's origin, "
           "not on the table top\n";
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
  std::string charuco;  // ChArUco board squares, COLSxROWS (instead of `pattern`)
  double marker_mm = 0.0;
  std::string dictionary = "DICT_5X5_100";
  double square_mm = 0.0;
  std::string out = "camera.yaml";
  bool fix_aspect_ratio = false;
  int min_views = 6;
};

int RunCalibrateCamera(const CalibrateCameraOptions& options, const Context& context) {
  const std::string command = "calibrate camera";
  const Status paths = CheckOutputPaths({{options.out, "--out"}}, {options.images});
  if (!paths.ok()) return ReportStatus(context, command, paths);
  Result<calib::CameraCalibration> result = InvalidArgumentError(
      "give the target: --pattern COLSxROWS (checkerboard inner corners) or --charuco COLSxROWS (ChArUco "
      "squares) with --marker MM");
  if (!options.charuco.empty()) {
    if (!(options.marker_mm > 0)) {
      return ReportStatus(context, command,
                          InvalidArgumentError("--charuco needs --marker MM (the side of one marker)"));
    }
    Result<calib::CharucoBoard> board =
        calib::ParseCharucoBoard(options.charuco, options.square_mm, options.marker_mm, options.dictionary);
    if (!board.ok()) return ReportStatus(context, command, board.status());
    calib::CharucoCalibrationOptions charuco_options;
    charuco_options.board = *board;
    charuco_options.fix_aspect_ratio = options.fix_aspect_ratio;
    charuco_options.min_views = options.min_views;
    result = calib::CalibrateCameraFromCharucoDirectory(options.images, charuco_options, context.progress);
  } else if (!options.pattern.empty()) {
    Result<calib::CheckerboardPattern> pattern = calib::ParsePattern(options.pattern, options.square_mm);
    if (!pattern.ok()) return ReportStatus(context, command, pattern.status());
    calib::CameraCalibrationOptions calibration_options;
    calibration_options.pattern = *pattern;
    calibration_options.fix_aspect_ratio = options.fix_aspect_ratio;
    calibration_options.min_views = options.min_views;
    result = calib::CalibrateCameraFromDirectory(options.images, calibration_options, context.progress);
  }
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
      sub->add_subcommand("camera", "Camera intrinsics and distortion from checkerboard or ChArUco images");
  camera->add_option("--images", camera_options->images, "directory of board images")->required();
  CLI::Option* pattern = camera->add_option("--pattern", camera_options->pattern,
                                            "checkerboard inner corners, COLSxROWS (e.g. 9x6)");
  camera->add_option("--charuco", camera_options->charuco, "ChArUco board squares, COLSxROWS (e.g. 8x6)")
      ->excludes(pattern);
  camera->add_option("--marker", camera_options->marker_mm, "ChArUco marker side in mm");
  camera->add_option("--dictionary", camera_options->dictionary, "ChArUco marker dictionary")
      ->capture_default_str();
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
