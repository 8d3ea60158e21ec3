#include "rotoscan/calib/rig_calibration.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <string>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <Eigen/Eigenvalues>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/persistence.hpp>

#include "calib/cost_functions/axis_gauge.h"
#include "calib/cost_functions/corner_reprojection.h"
#include "calib/cost_functions/laser_on_target.h"
#include "calib/cost_functions/scanned_point.h"
#include "calib/cost_functions/table_angle_prior.h"
#include "rotoscan/calib/axis_fit.h"
#include "rotoscan/calib/plane_fit.h"
#include "rotoscan/core/check.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/dlt.h"
#include "rotoscan/geometry/rigid.h"

namespace rotoscan::calib {
namespace {

using geometry::LaserId;
using geometry::LaserName;

// Laser points whose standard deviation across their main direction is below this do not fix a plane.
constexpr double kMinLaserSpreadMm = 3.0;

std::string Fixed(double value, int digits) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(digits);
  s << value;
  return s.str();
}

Eigen::Isometry3d TableTurn(const geometry::Rig& rig, double angle) {
  return geometry::RotationAboutAxis(rig.axis_point_in_cam, rig.axis_direction_in_cam, angle);
}

// cam_from_target of a placement at a table step and its commanded angle.
Eigen::Isometry3d CamFromTargetAt(const RigEstimate& estimate, int placement, int step,
                                  double table_angle_rad) {
  return TableTurn(estimate.rig, estimate.TableAngle(placement, step, table_angle_rad)) *
         estimate.cam_from_target0[placement];
}

int PlacementCount(const CalibrationData& data) {
  int count = 0;
  for (const auto& v : data.target_views) count = std::max(count, v.placement + 1);
  return count;
}

// Laser pixels of `view` as 3D points on its target plane (camera frame) under `estimate`.
std::vector<Eigen::Vector3d> LaserPointsInCam(const LaserView& view, const RigEstimate& estimate) {
  const Eigen::Isometry3d cam_from_target =
      CamFromTargetAt(estimate, view.placement, view.step, view.table_angle_rad);
  const Eigen::Vector3d n_in_target = view.plane_in_target.head<3>();
  const Eigen::Vector3d m = cam_from_target.linear() * n_in_target;
  const Eigen::Vector3d o = cam_from_target * (-view.plane_in_target(3) * n_in_target);
  std::vector<Eigen::Vector3d> points;
  points.reserve(view.pixels.size());
  for (const auto& pixel : view.pixels) {
    const Eigen::Vector3d ray = estimate.rig.camera.PixelToRay(pixel);
    const double denominator = m.dot(ray);
    if (std::abs(denominator) < 1e-9) continue;
    points.push_back(ray * (m.dot(o) / denominator));
  }
  return points;
}

// A point where a scan measures (RigCalibrationSummary::point_std_mm): a pixel of laser `laser`'s line
// seen at table angle `angle`.
struct ScanSample {
  int laser = 0;
  Eigen::Vector2d pixel;
  double angle = 0.0;
  double distance_mm = 0.0;  // from the camera
};

// The working volume is where the target stood: heights along the axis over which its corners were seen,
// and their largest distance from the axis. On each laser plane (which contains the axis on a usual rig),
// points at 5 heights and 5 distances across the axis within that reach, each seen at 8 table angles over
// a whole turn; those whose pixel is outside the image are left out.
std::vector<ScanSample> ScanSamples(const CalibrationData& data, const RigEstimate& estimate) {
  const geometry::Rig& rig = estimate.rig;
  const Eigen::Vector3d a = rig.axis_direction_in_cam.normalized();
  const Eigen::Vector3d& c = rig.axis_point_in_cam;
  double low = std::numeric_limits<double>::infinity(), high = -low, reach = 0.0;
  for (const TargetView& view : data.target_views) {
    const Eigen::Isometry3d pose = CamFromTargetAt(estimate, view.placement, view.step, view.table_angle_rad);
    for (const Eigen::Vector3d& corner : view.corners_in_target) {
      const Eigen::Vector3d x = pose * corner - c;
      const double h = a.dot(x);
      low = std::min(low, h);
      high = std::max(high, h);
      reach = std::max(reach, (x - h * a).norm());
    }
  }
  std::vector<ScanSample> samples;
  if (!(high >= low)) return samples;
  constexpr int kHeights = 5, kAcross = 5, kAngles = 8;
  for (int l = 0; l < 2; ++l) {
    const geometry::Plane& plane = rig.laser_plane[l];
    const Eigen::Vector3d across = plane.normal.cross(a);
    if (across.norm() < 1e-6) continue;  // a laser plane across the axis: no line on the object
    for (int i = 0; i < kHeights; ++i) {
      const Eigen::Vector3d on_axis = c + (low + (high - low) * i / (kHeights - 1)) * a;
      const Eigen::Vector3d foot = on_axis - plane.SignedDistance(on_axis) * plane.normal;
      for (int j = 0; j < kAcross; ++j) {
        const Eigen::Vector3d x = foot + reach * (2.0 * j / (kAcross - 1) - 1.0) * across.normalized();
        if (!(x.z() > 0)) continue;
        const Eigen::Vector2d pixel = rig.camera.Project(x);
        if (!rig.camera.IsInside(pixel, 0.0)) continue;
        for (int k = 0; k < kAngles; ++k) samples.push_back({l, pixel, 2.0 * M_PI * k / kAngles, x.norm()});
      }
    }
  }
  return samples;
}

Status CheckData(const CalibrationData& data, const RigCalibrationOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  if (data.image_width <= 0 || data.image_height <= 0) {
    return InvalidArgumentError("calibration data has no image size");
  }
  if (!(data.nominal_step_rad > 0)) return InvalidArgumentError("nominal table step angle must be > 0");
  const int views = static_cast<int>(data.target_views.size());
  if (views == 0) {
    return InvalidArgumentError(
        "the target was not found in any view: check that the bundle's target (pattern size, square size) "
        "is the one captured, that the whole target is in view, lit and in focus");
  }
  if (views < options.min_target_views) {
    return InvalidArgumentError("target found in only " + std::to_string(views) +
                                " views: need >= " + std::to_string(options.min_target_views) +
                                " (turn the table through more steps with the whole target in view)");
  }
  const int placements = PlacementCount(data);
  std::vector<std::set<int>> steps(placements);
  for (const auto& v : data.target_views) {
    if (v.placement < 0) return InvalidArgumentError("view " + v.name + ": negative placement index");
    if (v.corners_in_target.size() != v.corner_pixels.size()) {
      return InvalidArgumentError("view " + v.name + ": corner and pixel counts differ");
    }
    if (v.corners_in_target.size() < 6) {
      return InvalidArgumentError("view " + v.name + ": only " + std::to_string(v.corners_in_target.size()) +
                                  " target corners: need >= 6");
    }
    // Corners on one line fix neither the camera nor the pose (a partial detection, a one-row target).
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& c : v.corners_in_target) mean += c;
    mean /= static_cast<double>(v.corners_in_target.size());
    Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
    for (const auto& c : v.corners_in_target) scatter += (c - mean) * (c - mean).transpose();
    const Eigen::Vector3d spread =
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(scatter).eigenvalues().cwiseMax(0.0).cwiseSqrt();
    if (!(spread(1) > 1e-3 * spread(2))) {
      return InvalidArgumentError("view " + v.name + ": its " + std::to_string(v.corners_in_target.size()) +
                                  " target corners lie on one line: capture the whole target, at least two "
                                  "rows of corners");
    }
    steps[v.placement].insert(v.step);
  }
  int best = 0;
  for (int p = 0; p < placements; ++p) {
    if (steps[p].empty())
      return InvalidArgumentError("placement " + std::to_string(p) + " has no target view");
    best = std::max(best, static_cast<int>(steps[p].size()));
  }
  if (best < options.min_table_positions) {
    return InvalidArgumentError("target seen at only " + std::to_string(best) +
                                " table positions: need >= " + std::to_string(options.min_table_positions) +
                                " (turn the table between captures without moving the target)");
  }
  std::array<int, 2> points{};
  for (const auto& v : data.laser_views) {
    if (v.placement < 0 || v.placement >= placements) {
      return InvalidArgumentError("laser view " + v.name + ": placement " + std::to_string(v.placement) +
                                  " has no target view");
    }
    if (std::abs(v.plane_in_target.head<3>().norm() - 1.0) > 1e-6) {
      return InvalidArgumentError("laser view " + v.name + ": the target plane's normal must be unit");
    }
    points[static_cast<int>(v.laser)] += static_cast<int>(v.pixels.size());
  }
  for (int l = 0; l < 2; ++l) {
    if (points[l] < options.min_laser_points) {
      return InvalidArgumentError(std::string(LaserName(static_cast<LaserId>(l))) +
                                  " laser seen on the target in " + std::to_string(points[l]) +
                                  " pixels only: need >= " + std::to_string(options.min_laser_points) +
                                  " (capture laser frames with the line across the target)");
    }
  }
  return Status::Ok();
}

bool OnBoardPlane(const TargetView& view) {
  return std::all_of(view.corners_in_target.begin(), view.corners_in_target.end(),
                     [](const Eigen::Vector3d& c) { return c.z() == 0.0; });
}

double Median(std::vector<double> values) {
  ROTOSCAN_CHECK(!values.empty());
  std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
  return values[values.size() / 2];
}

// The paper's step 1 (eq. 8-10): the 3x4 matrix of every view of a non-planar target by DLT with Hartley
// normalisation, decomposed into K [R | t]; the camera is the median K over those views, without distortion.
Result<geometry::CameraModel> CameraFromDlt(const CalibrationData& data) {
  std::vector<double> fx, fy, cx, cy;
  Status last = Status::Ok();
  for (const TargetView& view : data.target_views) {
    if (OnBoardPlane(view)) continue;
    Result<geometry::DltEstimate> dlt =
        geometry::EstimateProjectionDlt(view.corners_in_target, view.corner_pixels);
    if (!dlt.ok()) {
      last = dlt.status().WithContext("view " + view.name);
      continue;
    }
    Result<geometry::ProjectionDecomposition> krt = geometry::DecomposeProjection(dlt->projection);
    if (!krt.ok()) {
      last = krt.status().WithContext("view " + view.name);
      continue;
    }
    fx.push_back(krt->K(0, 0));
    fy.push_back(krt->K(1, 1));
    cx.push_back(krt->K(0, 2));
    cy.push_back(krt->K(1, 2));
  }
  if (fx.empty()) {
    return InvalidArgumentError(
        "no view of the calibration object gives a projection matrix (" + last.message() +
        "): capture the object with both of its planes and their whole grids in view");
  }
  geometry::CameraModel c;
  c.width = data.image_width;
  c.height = data.image_height;
  c.fx = Median(fx);
  c.fy = Median(fy);
  c.cx = Median(cx);
  c.cy = Median(cy);
  ROTOSCAN_RETURN_IF_ERROR(c.Validate().WithContext("camera from the calibration object (DLT)"));
  return c;
}

Eigen::Quaterniond AverageRotation(const std::vector<Eigen::Quaterniond>& rotations) {
  Eigen::Vector4d sum = Eigen::Vector4d::Zero();
  for (const auto& q : rotations) {
    const Eigen::Vector4d c = q.coeffs();
    sum += (c.dot(rotations[0].coeffs()) < 0 ? -c : c);
  }
  return Eigen::Quaterniond(sum.normalized());
}

}  // namespace

Status RigCalibrationOptions::Check() const {
  if (min_target_views < 3) return InvalidArgumentError("min_target_views must be >= 3");
  if (min_table_positions < 2) return InvalidArgumentError("min_table_positions must be >= 2");
  if (min_laser_points < 3) return InvalidArgumentError("min_laser_points must be >= 3");
  for (double v : {laser_inlier_mm, corner_sigma_px, laser_sigma_mm, huber_sigmas, max_rms_px,
                   max_view_rms_px, max_laser_rms_mm, max_axis_rms_mm}) {
    if (!(v > 0) || !std::isfinite(v)) return InvalidArgumentError("calibration tolerances must be > 0");
  }
  for (double v :
       {max_normal_std_deg, max_offset_std_mm, max_axis_std_mm, max_axis_std_deg, max_point_std_mm}) {
    if (!(v > 0) || !std::isfinite(v)) return InvalidArgumentError("calibration thresholds must be > 0");
  }
  if (!(table_angle_sigma_deg > 0) || !(table_angle_sigma_deg <= 90)) {
    return InvalidArgumentError("table_angle_sigma_deg must be in (0, 90]");
  }
  if (max_iterations < 1) return InvalidArgumentError("max_iterations must be >= 1");
  return Status::Ok();
}

double RigEstimate::TableAngle(int placement, int step, double commanded_rad) const {
  const auto it = angle_offset_rad.find({placement, step});
  return angle_scale * commanded_rad + (it == angle_offset_rad.end() ? 0.0 : it->second);
}

bool PlaceTableOrigin(const CalibrationData& data, RigEstimate* estimate) {
  ROTOSCAN_CHECK(estimate != nullptr);
  for (const TargetView& view : data.target_views) {
    if (!std::isfinite(view.origin_height_mm)) continue;
    if (view.placement < 0 || view.placement >= static_cast<int>(estimate->cam_from_target0.size())) continue;
    geometry::Rig& rig = estimate->rig;
    const Eigen::Vector3d a = rig.axis_direction_in_cam.normalized();
    const Eigen::Vector3d origin =
        estimate->cam_from_target0[static_cast<size_t>(view.placement)].translation();
    const Eigen::Vector3d foot = rig.axis_point_in_cam + a.dot(origin - rig.axis_point_in_cam) * a;
    rig.axis_point_in_cam = foot - view.origin_height_mm * a;
    return true;
  }
  return false;
}

Result<RigEstimate> CalibrateThreeStep(const CalibrationData& data, const RigCalibrationOptions& options,
                                       const std::optional<geometry::CameraModel>& camera) {
  ROTOSCAN_RETURN_IF_ERROR(CheckData(data, options));
  RigEstimate estimate;
  const int views = static_cast<int>(data.target_views.size());

  // Step 1: the camera (OpenCV's calibrateCamera: Zhang's method with distortion, beyond the paper's DLT
  // which assumes none), then each view's pose.
  cv::Mat k = cv::Mat::eye(3, 3, CV_64F), dist = cv::Mat::zeros(5, 1, CV_64F);
  std::vector<std::vector<cv::Point3f>> object_points(views);
  std::vector<std::vector<cv::Point2f>> image_points(views);
  for (int v = 0; v < views; ++v) {
    const TargetView& view = data.target_views[v];
    for (std::size_t i = 0; i < view.corners_in_target.size(); ++i) {
      object_points[v].emplace_back(static_cast<float>(view.corners_in_target[i].x()),
                                    static_cast<float>(view.corners_in_target[i].y()),
                                    static_cast<float>(view.corners_in_target[i].z()));
      image_points[v].emplace_back(static_cast<float>(view.corner_pixels[i].x()),
                                   static_cast<float>(view.corner_pixels[i].y()));
    }
  }
  const bool all_boards = std::all_of(data.target_views.begin(), data.target_views.end(), OnBoardPlane);
  if (camera.has_value()) {
    ROTOSCAN_RETURN_IF_ERROR(camera->Validate());
    estimate.rig.camera = *camera;
  } else if (!all_boards) {
    ROTOSCAN_ASSIGN_OR_RETURN(estimate.rig.camera, CameraFromDlt(data));
  } else {
    // Only the initial value: an evenly spread subset of at most 20 views keeps OpenCV fast.
    std::vector<std::vector<cv::Point3f>> subset_object;
    std::vector<std::vector<cv::Point2f>> subset_image;
    const int used = std::min(views, 20);
    for (int i = 0; i < used; ++i) {
      const int v = static_cast<int>(static_cast<long>(i) * views / used);
      subset_object.push_back(object_points[v]);
      subset_image.push_back(image_points[v]);
    }
    std::vector<cv::Mat> rvecs, tvecs;
    try {
      cv::calibrateCamera(subset_object, subset_image, cv::Size(data.image_width, data.image_height), k, dist,
                          rvecs, tvecs, 0,
                          cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
    } catch (const cv::Exception& e) {
      return NotConvergedError("camera calibration from the target views failed: " + e.msg);
    }
    geometry::CameraModel& c = estimate.rig.camera;
    c.width = data.image_width;
    c.height = data.image_height;
    c.fx = k.at<double>(0, 0);
    c.fy = k.at<double>(1, 1);
    c.cx = k.at<double>(0, 2);
    c.cy = k.at<double>(1, 2);
    for (int i = 0; i < 5; ++i) c.distortion[i] = dist.at<double>(i);
    ROTOSCAN_RETURN_IF_ERROR(c.Validate().WithContext("camera from the target views"));
  }
  const geometry::CameraModel& c = estimate.rig.camera;
  k = (cv::Mat_<double>(3, 3) << c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
  dist = cv::Mat(std::vector<double>(c.distortion.begin(), c.distortion.end()), true);
  std::vector<Eigen::Isometry3d> poses(views);
  for (int v = 0; v < views; ++v) {
    cv::Mat rvec, tvec, r;
    if (!cv::solvePnP(object_points[v], image_points[v], k, dist, rvec, tvec)) {
      return NotConvergedError("view " + data.target_views[v].name + ": target pose not found");
    }
    cv::Rodrigues(rvec, r);
    poses[v].setIdentity();
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) poses[v].linear()(i, j) = r.at<double>(i, j);
      poses[v].translation()(i) = tvec.at<double>(i);
    }
  }

  // Step 3 of the paper (done before the lasers here, since the laser views need the poses at every step):
  // the axis from each placement's poses, weighted by its number of table positions.
  const int placements = PlacementCount(data);
  Eigen::Vector3d direction = Eigen::Vector3d::Zero(), point = Eigen::Vector3d::Zero();
  Eigen::Vector3d first_direction = Eigen::Vector3d::Zero(), first_point = Eigen::Vector3d::Zero();
  double weight_sum = 0.0, step_sum = 0.0, rms_sq = 0.0;
  std::vector<Eigen::Vector3d> points;
  std::vector<double> weights;
  for (int p = 0; p < placements; ++p) {
    std::map<int, std::pair<Eigen::Isometry3d, double>> by_step;  // pose and commanded angle per step
    for (int v = 0; v < views; ++v) {
      const TargetView& view = data.target_views[v];
      if (view.placement == p) by_step.emplace(view.step, std::make_pair(poses[v], view.table_angle_rad));
    }
    if (static_cast<int>(by_step.size()) < 2) continue;
    std::vector<Eigen::Isometry3d> ordered;
    std::vector<double> commanded;
    for (const auto& [s, pose_angle] : by_step) {
      ordered.push_back(pose_angle.first);
      commanded.push_back(pose_angle.second);
    }
    Result<AxisFit> fit = FitAxisFromPoses(ordered);
    if (!fit.ok()) return fit.status().WithContext("table axis from placement " + std::to_string(p));
    const double w = static_cast<double>(ordered.size());
    if (weight_sum == 0.0) {
      first_direction = fit->direction;
      first_point = fit->point;
    }
    const double sign = fit->direction.dot(first_direction) < 0 ? -1.0 : 1.0;
    direction += w * sign * fit->direction;
    points.push_back(fit->point);
    weights.push_back(w);
    // The angle scale: signed turn between successive positions over the commanded turn.
    double angle = 0.0;
    for (std::size_t i = 1; i < ordered.size(); ++i) {
      const Eigen::AngleAxisd turn(ordered[i].linear() * ordered[i - 1].linear().transpose());
      angle += turn.angle() * (turn.axis().dot(first_direction) < 0 ? -1.0 : 1.0);
    }
    const double commanded_turn = commanded.back() - commanded.front();
    if (std::abs(commanded_turn) < 1e-9) {
      return InvalidArgumentError("placement " + std::to_string(p) +
                                  ": the views have different steps but the same commanded table angle");
    }
    step_sum += w * angle / commanded_turn;
    rms_sq += w * fit->rms_mm * fit->rms_mm;
    weight_sum += w;
  }
  if (weight_sum == 0.0) return InvalidArgumentError("no placement was seen at two table positions");
  estimate.rig.axis_direction_in_cam = direction.normalized();
  double scale = step_sum / weight_sum;
  if (scale < 0) {  // the table turned left-handed about the fitted direction: flip it
    estimate.rig.axis_direction_in_cam = -estimate.rig.axis_direction_in_cam;
    scale = -scale;
  }
  estimate.angle_scale = scale;
  estimate.rig.step_angle_rad = scale * data.nominal_step_rad;
  const Eigen::Vector3d& a = estimate.rig.axis_direction_in_cam;
  for (std::size_t i = 0; i < points.size(); ++i) {
    point += weights[i] * (points[i] - a.dot(points[i] - first_point) * a);
  }
  estimate.rig.axis_point_in_cam =
      point / weight_sum;  // at the height of the first placement's target origin
  estimate.axis_fit_rms_mm = std::sqrt(rms_sq / weight_sum);

  // Each placement's pose at step 0: every view turned back by its step angle, averaged.
  estimate.cam_from_target0.assign(placements, Eigen::Isometry3d::Identity());
  for (int p = 0; p < placements; ++p) {
    std::vector<Eigen::Quaterniond> rotations;
    Eigen::Vector3d translation = Eigen::Vector3d::Zero();
    for (int v = 0; v < views; ++v) {
      if (data.target_views[v].placement != p) continue;
      const Eigen::Isometry3d at0 =
          TableTurn(estimate.rig, -scale * data.target_views[v].table_angle_rad) * poses[v];
      rotations.emplace_back(at0.linear());
      translation += at0.translation();
    }
    estimate.cam_from_target0[p].linear() = AverageRotation(rotations).toRotationMatrix();
    estimate.cam_from_target0[p].translation() = translation / static_cast<double>(rotations.size());
  }

  // Step 2: each laser plane from its pixels' points on the target plane (eq. 11 by a robust TLS fit).
  for (int l = 0; l < 2; ++l) {
    std::vector<Eigen::Vector3d> laser_points;
    for (const auto& view : data.laser_views) {
      if (static_cast<int>(view.laser) != l) continue;
      const auto pts = LaserPointsInCam(view, estimate);
      laser_points.insert(laser_points.end(), pts.begin(), pts.end());
    }
    const std::string name = LaserName(static_cast<LaserId>(l));
    // A laser seen on one target plane only, or on target planes that all contain one line (a board turned
    // about an axis lying in the laser plane), gives collinear points: the plane is not determined.
    if (laser_points.size() >= 3) {
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (const auto& x : laser_points) mean += x;
      mean /= static_cast<double>(laser_points.size());
      Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
      for (const auto& x : laser_points) scatter += (x - mean) * (x - mean).transpose();
      const Eigen::Vector3d spread =
          (Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(scatter / laser_points.size()).eigenvalues())
              .cwiseMax(0.0)
              .cwiseSqrt();
      if (spread(1) < kMinLaserSpreadMm) {
        return InvalidArgumentError(
            name + " laser points lie along one line (" + Fixed(spread(1), 2) +
            " mm across it): the laser plane is not determined; capture the line on the "
            "target at two or more orientations, with the target off the table axis");
      }
    }
    RobustPlaneOptions plane_options;
    plane_options.inlier_threshold_mm = options.laser_inlier_mm;
    Result<PlaneFit> fit = FitPlaneRobust(laser_points, plane_options);
    if (!fit.ok()) return fit.status().WithContext(name + " laser plane");
    estimate.rig.laser_plane[l] = fit->plane.Canonical();
  }
  ROTOSCAN_RETURN_IF_ERROR(estimate.rig.Validate().WithContext("three-step calibration"));
  PlaceTableOrigin(data, &estimate);
  return estimate;
}

RigCalibrationSummary Evaluate(const CalibrationData& data, const RigEstimate& estimate,
                               const RigCalibrationOptions& options) {
  RigCalibrationSummary s;
  const geometry::CameraModel& camera = estimate.rig.camera;
  double sum_sq = 0.0;
  int count = 0;
  for (const auto& view : data.target_views) {
    const Eigen::Isometry3d pose = CamFromTargetAt(estimate, view.placement, view.step, view.table_angle_rad);
    double view_sq = 0.0;
    for (std::size_t i = 0; i < view.corners_in_target.size(); ++i) {
      const Eigen::Vector3d p = pose * view.corners_in_target[i];
      const double e = p.z() > 0 ? (camera.Project(p) - view.corner_pixels[i]).squaredNorm() : 1e6;
      view_sq += e;
    }
    sum_sq += view_sq;
    count += static_cast<int>(view.corners_in_target.size());
    s.per_view.push_back(
        {view.name, std::sqrt(view_sq / std::max<std::size_t>(1, view.corners_in_target.size())),
         geometry::RadToDeg(estimate.TableAngle(view.placement, view.step, view.table_angle_rad) -
                            view.table_angle_rad)});
  }
  s.rms_px = count > 0 ? std::sqrt(sum_sq / count) : 0.0;
  for (int l = 0; l < 2; ++l) {
    double laser_sq = 0.0;
    int n = 0;
    for (const auto& view : data.laser_views) {
      if (static_cast<int>(view.laser) != l) continue;
      for (const auto& x : LaserPointsInCam(view, estimate)) {
        const double d = estimate.rig.laser_plane[l].SignedDistance(x);
        laser_sq += d * d;
        ++n;
      }
    }
    s.laser_points[l] = n;
    s.laser_rms_mm[l] = n > 0 ? std::sqrt(laser_sq / n) : 0.0;
  }
  s.axis_fit_rms_mm = estimate.axis_fit_rms_mm;
  s.angle_scale = estimate.angle_scale;
  s.target_views = static_cast<int>(data.target_views.size());
  s.placements = static_cast<int>(estimate.cam_from_target0.size());

  if (s.target_views < options.min_target_views) {
    s.failures.push_back("target seen in only " + std::to_string(s.target_views) +
                         " views: need >= " + std::to_string(options.min_target_views));
  }
  // Pixel figures are information (the file comment): what they say about the rig is in the covariance.
  if (s.rms_px > options.max_rms_px) {
    s.notes.push_back("corner reprojection RMS " + Fixed(s.rms_px, 3) + " px > " +
                      Fixed(options.max_rms_px, 3) +
                      " px: blur, compression or a target that is not flat, or its square size wrong");
  }
  for (const auto& v : s.per_view) {
    if (v.rms_px > options.max_view_rms_px) {
      s.notes.push_back("view " + v.name + ": reprojection RMS " + Fixed(v.rms_px, 3) + " px > " +
                        Fixed(options.max_view_rms_px, 3) +
                        " px: the target moved on the table, the table slipped, or a corner was misdetected");
    }
  }
  // Slips: each position's offset beyond the scale (its placement's mean is in the placement's pose).
  std::string slip_view;
  for (std::size_t v = 0; v < data.target_views.size(); ++v) {
    const TargetView& view = data.target_views[v];
    const double slip =
        std::abs(geometry::RadToDeg(estimate.TableAngle(view.placement, view.step, view.table_angle_rad) -
                                    estimate.angle_scale * view.table_angle_rad));
    if (slip > s.max_table_slip_deg) {
      s.max_table_slip_deg = slip;
      slip_view = view.name;
    }
  }
  s.table_angles_refined = !estimate.angle_offset_rad.empty();
  if (s.table_angles_refined && s.max_table_slip_deg > 0.05) {
    s.notes.push_back("the table stood up to " + Fixed(s.max_table_slip_deg, 3) +
                      " deg from its commanded angles (at " + slip_view +
                      "): it slips; each view's angle was refined");
  }
  for (int l = 0; l < 2; ++l) {
    const std::string name = LaserName(static_cast<LaserId>(l));
    if (s.laser_points[l] < options.min_laser_points) {
      s.failures.push_back(name + " laser: only " + std::to_string(s.laser_points[l]) +
                           " points on the target: need >= " + std::to_string(options.min_laser_points));
    } else if (s.laser_rms_mm[l] > options.max_laser_rms_mm) {
      s.failures.push_back(
          name + " laser: plane residual " + Fixed(s.laser_rms_mm[l], 4) + " mm > " +
          Fixed(options.max_laser_rms_mm, 4) +
          " mm: laser points off the target plane (reflections, ambient light) or a bent line");
    }
  }
  if (s.axis_fit_rms_mm > options.max_axis_rms_mm) {
    s.failures.push_back("table axis fit residual " + Fixed(s.axis_fit_rms_mm, 4) + " mm > " +
                         Fixed(options.max_axis_rms_mm, 4) +
                         " mm: the target slid on the table between steps, or the table wobbles");
  }
  s.passed = s.failures.empty();
  return s;
}

Result<RigCalibration> RefineRig(const CalibrationData& data, const RigEstimate& initial,
                                 const RigCalibrationOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(CheckData(data, options));
  ROTOSCAN_RETURN_IF_ERROR(initial.rig.Validate().WithContext("initial rig"));
  const int placements = PlacementCount(data);
  ROTOSCAN_CHECK_EQ(static_cast<int>(initial.cam_from_target0.size()), placements);

  // The optimisable state, contiguous per block.
  const geometry::CameraModel& c0 = initial.rig.camera;
  std::array<double, 4> intrinsics = c0.Intrinsics();
  std::array<double, 5> distortion = c0.distortion;
  std::vector<std::array<double, 6>> poses(placements);
  for (int p = 0; p < placements; ++p) {
    const Eigen::AngleAxisd aa(initial.cam_from_target0[p].linear());
    const Eigen::Vector3d r = aa.angle() * aa.axis();
    const Eigen::Vector3d t = initial.cam_from_target0[p].translation();
    poses[p] = {r.x(), r.y(), r.z(), t.x(), t.y(), t.z()};
  }
  Eigen::Vector3d axis_direction = initial.rig.axis_direction_in_cam.normalized();
  Eigen::Vector3d axis_point = initial.rig.axis_point_in_cam;
  double angle_scale = initial.angle_scale;
  std::array<Eigen::Vector3d, 2> normals = {initial.rig.laser_plane[0].normal,
                                            initial.rig.laser_plane[1].normal};
  std::array<double, 2> offsets = {initial.rig.laser_plane[0].offset, initial.rig.laser_plane[1].offset};
  // One table angle offset per (placement, step) observed; free where the target is seen and the angles
  // are refined, else constant. Sized once: Ceres keeps pointers into it.
  std::map<std::pair<int, int>, std::size_t> angle_index;
  std::set<std::pair<int, int>> target_seen;
  for (const auto& view : data.target_views) {
    angle_index.emplace(std::make_pair(view.placement, view.step), angle_index.size());
    target_seen.emplace(view.placement, view.step);
  }
  for (const auto& view : data.laser_views) {
    angle_index.emplace(std::make_pair(view.placement, view.step), angle_index.size());
  }
  std::vector<double> angle_offsets(angle_index.size(), 0.0);
  for (const auto& [key, index] : angle_index) {
    const auto it = initial.angle_offset_rad.find(key);
    if (it != initial.angle_offset_rad.end()) angle_offsets[index] = it->second;
  }
  auto offset_of = [&](int placement, int step) { return &angle_offsets[angle_index.at({placement, step})]; };

  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  ceres::HuberLoss loss(options.huber_sigmas);
  for (const auto& view : data.target_views) {
    for (std::size_t i = 0; i < view.corners_in_target.size(); ++i) {
      problem.AddResidualBlock(
          internal::CornerReprojectionCost::Create(view.corners_in_target[i], view.corner_pixels[i],
                                                   view.table_angle_rad, options.corner_sigma_px),
          &loss, intrinsics.data(), distortion.data(), poses[view.placement].data(), axis_direction.data(),
          axis_point.data(), &angle_scale, offset_of(view.placement, view.step));
    }
  }
  for (const auto& view : data.laser_views) {
    const int l = static_cast<int>(view.laser);
    for (const auto& pixel : view.pixels) {
      problem.AddResidualBlock(internal::LaserOnTargetCost::Create(
                                   pixel, view.table_angle_rad, options.laser_sigma_mm, view.plane_in_target),
                               &loss, intrinsics.data(), distortion.data(), poses[view.placement].data(),
                               axis_direction.data(), axis_point.data(), &angle_scale,
                               offset_of(view.placement, view.step), normals[l].data(), &offsets[l]);
    }
  }
  problem.AddResidualBlock(internal::AxisGaugeCost::Create(axis_point, axis_direction, 1.0), nullptr,
                           axis_point.data());
  problem.SetManifold(axis_direction.data(), new ceres::SphereManifold<3>());
  for (auto& n : normals) problem.SetManifold(n.data(), new ceres::SphereManifold<3>());
  if (!options.refine_intrinsics) problem.SetParameterBlockConstant(intrinsics.data());
  if (!options.refine_distortion) problem.SetParameterBlockConstant(distortion.data());
  if (!options.refine_angle_scale) problem.SetParameterBlockConstant(&angle_scale);
  const double angle_sigma_rad = geometry::DegToRad(options.table_angle_sigma_deg);
  const bool increments =
      options.table_angle_prior == RigCalibrationOptions::TableAnglePrior::kIncrements;
  const std::pair<int, int>* previous = nullptr;  // the last seen position (angle_index is in step order)
  for (const auto& [key, index] : angle_index) {
    if (options.refine_table_angles && target_seen.count(key) != 0) {
      if (increments && previous != nullptr && previous->first == key.first) {
        problem.AddResidualBlock(internal::TableAngleIncrementPriorCost::Create(angle_sigma_rad), nullptr,
                                 &angle_offsets[angle_index.at(*previous)], &angle_offsets[index]);
      } else {
        problem.AddResidualBlock(internal::TableAnglePriorCost::Create(angle_sigma_rad), nullptr,
                                 &angle_offsets[index]);
      }
      previous = &key;
    } else {
      problem.SetParameterBlockConstant(&angle_offsets[index]);
    }
  }

  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::DENSE_QR;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.function_tolerance = 1e-12;
  solver_options.parameter_tolerance = 1e-12;
  solver_options.gradient_tolerance = 1e-14;
  solver_options.logging_type = ceres::SILENT;
  solver_options.num_threads = 1;
  ceres::Solver::Summary solver_summary;
  ceres::Solve(solver_options, &problem, &solver_summary);
  if (!solver_summary.IsSolutionUsable()) {
    return NotConvergedError("joint refinement failed: " + solver_summary.message);
  }

  RigCalibration out;
  RigEstimate& e = out.estimate;
  e = initial;
  geometry::CameraModel& cam = e.rig.camera;
  cam.fx = intrinsics[0];
  cam.fy = intrinsics[1];
  cam.cx = intrinsics[2];
  cam.cy = intrinsics[3];
  cam.distortion = distortion;
  for (int p = 0; p < placements; ++p) {
    double r[9];
    ceres::AngleAxisToRotationMatrix(poses[p].data(), ceres::ColumnMajorAdapter3x3(r));
    e.cam_from_target0[p].linear() = Eigen::Map<const Eigen::Matrix3d>(r);
    e.cam_from_target0[p].translation() = Eigen::Vector3d(poses[p][3], poses[p][4], poses[p][5]);
  }
  e.rig.axis_direction_in_cam = axis_direction.normalized();
  e.rig.axis_point_in_cam = axis_point;
  e.angle_scale = angle_scale;
  e.rig.step_angle_rad = angle_scale * data.nominal_step_rad;
  e.angle_offset_rad.clear();
  if (options.refine_table_angles) {
    for (const auto& [key, index] : angle_index) {
      if (target_seen.count(key) != 0) e.angle_offset_rad[key] = angle_offsets[index];
    }
  }
  for (int l = 0; l < 2; ++l) {
    const double norm = normals[l].norm();
    geometry::Plane plane;
    plane.normal = normals[l] / norm;
    plane.offset = offsets[l] / norm;
    e.rig.laser_plane[l] = plane.Canonical();
  }
  ROTOSCAN_RETURN_IF_ERROR(e.rig.Validate().WithContext("joint refinement result"));

  RigCalibrationSummary& s = out.summary;
  s = Evaluate(data, e, options);
  s.termination = solver_summary.BriefReport();
  s.iterations = static_cast<int>(solver_summary.iterations.size());
  s.converged = solver_summary.termination_type == ceres::CONVERGENCE;
  if (!s.converged) {
    s.failures.push_back("joint refinement did not converge in " + std::to_string(options.max_iterations) +
                         " iterations: " + solver_summary.message);
    s.passed = false;
  }

  if (options.compute_covariance) {
    ceres::Covariance::Options covariance_options;
    covariance_options.algorithm_type = ceres::DENSE_SVD;
    covariance_options.null_space_rank = -1;
    covariance_options.num_threads = 1;
    ceres::Covariance covariance(covariance_options);
    std::vector<const double*> blocks;  // the rig's free blocks: their full covariance, cross terms included
    const std::vector<const double*> rig_blocks = {
        intrinsics.data(), distortion.data(), axis_direction.data(), axis_point.data(), &angle_scale,
        normals[0].data(), &offsets[0],       normals[1].data(),     &offsets[1]};
    for (const double* b : rig_blocks) {
      if (!problem.IsParameterBlockConstant(const_cast<double*>(b))) blocks.push_back(b);
    }
    Eigen::MatrixXd full;  // ambient coordinates, row-major blocks in the order of `blocks`
    std::map<const double*, int> start;
    bool computed = covariance.Compute(blocks, &problem);
    if (computed) {
      int size = 0;
      for (const double* b : blocks) {
        start[b] = size;
        size += problem.ParameterBlockSize(b);
      }
      Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> values(size, size);
      computed = covariance.GetCovarianceMatrix(blocks, values.data());
      full = values;
    }
    if (computed) {
      const int dof = solver_summary.num_residuals_reduced - solver_summary.num_effective_parameters_reduced;
      const double variance_factor = dof > 0 ? 2.0 * solver_summary.final_cost / dof : 1.0;
      full *= variance_factor;
      // The covariance of blocks a and b (zero for a constant block).
      auto cross = [&](const double* a, int na, const double* b, int nb) -> Eigen::MatrixXd {
        const auto ia = start.find(a), ib = start.find(b);
        if (ia == start.end() || ib == start.end()) return Eigen::MatrixXd::Zero(na, nb);
        return full.block(ia->second, ib->second, na, nb);
      };
      auto block = [&](const double* b, int n) { return cross(b, n, b, n); };
      StdDevs& d = s.std_devs;
      const Eigen::MatrixXd ci = block(intrinsics.data(), 4), cd = block(distortion.data(), 5);
      for (int i = 0; i < 4; ++i) d.intrinsics[i] = std::sqrt(std::max(0.0, ci(i, i)));
      for (int i = 0; i < 5; ++i) d.distortion[i] = std::sqrt(std::max(0.0, cd(i, i)));
      for (int l = 0; l < 2; ++l) {
        // The normal's covariance is tangent to the unit sphere: its trace is the angular variance (rad^2).
        d.laser_normal_deg[l] =
            geometry::RadToDeg(std::sqrt(std::max(0.0, block(normals[l].data(), 3).trace())));
        d.laser_offset_mm[l] = std::sqrt(std::max(0.0, block(&offsets[l], 1)(0, 0)));
      }
      d.axis_direction_deg =
          geometry::RadToDeg(std::sqrt(std::max(0.0, block(axis_direction.data(), 3).trace())));
      const Eigen::Matrix3d across =
          Eigen::Matrix3d::Identity() - e.rig.axis_direction_in_cam * e.rig.axis_direction_in_cam.transpose();
      d.axis_point_mm = std::sqrt(std::max(0.0, (across * block(axis_point.data(), 3) * across).trace()));
      d.angle_scale = std::sqrt(std::max(0.0, block(&angle_scale, 1)(0, 0)));
      d.valid = true;
      // The predicted error of a scanned point: the covariance of the blocks a scan uses, propagated through
      // ScannedPoint's Jacobian at points of both laser lines where the target stood.
      double sum_sq = 0.0, distance_sum = 0.0;
      int count = 0;
      for (const ScanSample& sample : ScanSamples(data, e)) {
        const int l = sample.laser;
        const std::array<std::pair<const double*, int>, 6> used = {{{intrinsics.data(), 4},
                                                                    {distortion.data(), 5},
                                                                    {normals[l].data(), 3},
                                                                    {&offsets[l], 1},
                                                                    {axis_direction.data(), 3},
                                                                    {axis_point.data(), 3}}};
        std::unique_ptr<ceres::CostFunction> point(
            internal::ScannedPoint::Create(sample.pixel, sample.angle));
        std::array<std::vector<double>, 6> jacobians;
        std::array<double*, 6> jacobian_pointers{};
        std::array<const double*, 6> parameters{};
        for (std::size_t k = 0; k < used.size(); ++k) {
          jacobians[k].resize(3 * used[k].second);
          jacobian_pointers[k] = jacobians[k].data();
          parameters[k] = used[k].first;
        }
        double value[3];
        if (!point->Evaluate(parameters.data(), value, jacobian_pointers.data())) continue;
        Eigen::Matrix3d point_covariance = Eigen::Matrix3d::Zero();
        for (std::size_t a = 0; a < used.size(); ++a) {
          const Eigen::Map<const Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>> ja(
              jacobians[a].data(), 3, used[a].second);
          for (std::size_t b = 0; b < used.size(); ++b) {
            const Eigen::Map<const Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>> jb(
                jacobians[b].data(), 3, used[b].second);
            point_covariance +=
                ja * cross(used[a].first, used[a].second, used[b].first, used[b].second) * jb.transpose();
          }
        }
        const double variance = std::max(0.0, point_covariance.trace());
        sum_sq += variance;
        s.point_std_max_mm =
            count == 0 ? std::sqrt(variance) : std::max(s.point_std_max_mm, std::sqrt(variance));
        distance_sum += sample.distance_mm;
        ++count;
      }
      if (count > 0) {
        s.point_std_mm = std::sqrt(sum_sq / count);
        s.working_distance_mm = distance_sum / count;
        if (s.point_std_mm > options.max_point_std_mm) {
          s.failures.push_back(
              "a scanned point at " + Fixed(s.working_distance_mm, 0) + " mm would be off by +-" +
              Fixed(s.point_std_mm, 4) + " mm (predicted from the calibration's uncertainty, up to +-" +
              Fixed(s.point_std_max_mm, 4) + " mm) > " + Fixed(options.max_point_std_mm, 4) +
              " mm: capture the target at more table positions and placements, sharper (corners fit to " +
              Fixed(s.rms_px, 2) + " px RMS)");
        }
      } else {
        s.failures.push_back(
            "no point of the laser lines where the target stood is in the image: the "
            "scanned point error cannot be predicted");
      }
      const double turn_deg = 360.0 * d.angle_scale;
      if (turn_deg > 0.1) {
        s.notes.push_back("table angle scale " + Fixed(e.angle_scale, 5) + " +-" + Fixed(d.angle_scale, 5) +
                          ": a whole turn is known to +-" + Fixed(turn_deg, 2) + " deg");
      }
      // Pass/fail on what the capture could determine.
      for (int l = 0; l < 2; ++l) {
        const std::string name = LaserName(static_cast<LaserId>(l));
        if (d.laser_normal_deg[l] > options.max_normal_std_deg ||
            d.laser_offset_mm[l] > options.max_offset_std_mm) {
          s.failures.push_back(name + " laser plane uncertain (normal +-" + Fixed(d.laser_normal_deg[l], 4) +
                               " deg, offset +-" + Fixed(d.laser_offset_mm[l], 4) +
                               " mm): capture its line on the target in more placements and table positions");
        }
      }
      if (d.axis_point_mm > options.max_axis_std_mm || d.axis_direction_deg > options.max_axis_std_deg) {
        s.failures.push_back("table axis uncertain (position +-" + Fixed(d.axis_point_mm, 4) +
                             " mm, direction +-" + Fixed(d.axis_direction_deg, 4) +
                             " deg): capture the target at more table positions over a wider turn, in more "
                             "placements");
      }
      s.passed = s.failures.empty();
    } else {
      s.failures.push_back(
          "parameter standard deviations could not be computed (a parameter is not determined "
          "by the observations): capture more placements and table positions");
      s.passed = false;
    }
  }
  out.summary.table_origin_on_table_top = PlaceTableOrigin(data, &out.estimate);
  return out;
}

Status WriteCalibrationYaml(const std::filesystem::path& path, const RigCalibration& calibration) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::string text, EncodeCalibrationYaml(calibration, path.string()));
  return WriteFileAtomically(path, text);
}

Result<std::string> EncodeCalibrationYaml(const RigCalibration& calibration, const std::string& name) {
  const std::string path = name;  // for the messages
  ROTOSCAN_RETURN_IF_ERROR(calibration.estimate.rig.Validate().WithContext("refusing to write " + path));
  const RigCalibrationSummary& s = calibration.summary;
  // Written to memory first: FileStorage does not report a failed write (a full disk).
  std::string text;
  try {
    cv::FileStorage fs(".yaml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY |
                                  cv::FileStorage::FORMAT_YAML);
    if (!fs.isOpened()) return InternalError("cannot start the YAML of " + path);
    geometry::WriteRigNodes(fs, calibration.estimate.rig);
    fs << "report_passed" << (s.passed ? 1 : 0);
    fs << "report_failures"
       << "[";
    for (const auto& f : s.failures) fs << f;
    fs << "]";
    fs << "report_notes"
       << "[";
    for (const auto& n : s.notes) fs << n;
    fs << "]";
    // NaN (not computed) is written as -1.
    fs << "point_std_mm" << (std::isfinite(s.point_std_mm) ? s.point_std_mm : -1.0);
    fs << "point_std_max_mm" << (std::isfinite(s.point_std_max_mm) ? s.point_std_max_mm : -1.0);
    fs << "working_distance_mm" << s.working_distance_mm;
    fs << "table_angles_refined" << static_cast<int>(s.table_angles_refined);
    fs << "max_table_slip_deg" << s.max_table_slip_deg;
    fs << "rms_px" << s.rms_px;
    std::vector<double> view_rms, view_angle;
    fs << "per_view_names"
       << "[";
    for (const auto& v : s.per_view) {
      fs << v.name;
      view_rms.push_back(v.rms_px);
      view_angle.push_back(v.table_angle_offset_deg);
    }
    fs << "]";
    fs << "per_view_rms_px" << cv::Mat(view_rms, true);
    fs << "per_view_table_angle_offset_deg" << cv::Mat(view_angle, true);
    fs << "laser_left_rms_mm" << s.laser_rms_mm[0] << "laser_right_rms_mm" << s.laser_rms_mm[1];
    fs << "laser_left_points" << s.laser_points[0] << "laser_right_points" << s.laser_points[1];
    fs << "axis_fit_rms_mm" << s.axis_fit_rms_mm << "angle_scale" << s.angle_scale;
    fs << "table_origin_on_table_top" << static_cast<int>(s.table_origin_on_table_top);
    fs << "solver_termination" << s.termination << "solver_iterations" << s.iterations;
    const StdDevs& d = s.std_devs;
    fs << "std_valid" << (d.valid ? 1 : 0);
    fs << "std_intrinsics" << cv::Mat(std::vector<double>(d.intrinsics.begin(), d.intrinsics.end()), true);
    fs << "std_distortion" << cv::Mat(std::vector<double>(d.distortion.begin(), d.distortion.end()), true);
    fs << "std_laser_normal_deg"
       << cv::Mat(std::vector<double>(d.laser_normal_deg.begin(), d.laser_normal_deg.end()), true);
    fs << "std_laser_offset_mm"
       << cv::Mat(std::vector<double>(d.laser_offset_mm.begin(), d.laser_offset_mm.end()), true);
    fs << "std_axis_direction_deg" << d.axis_direction_deg << "std_axis_point_mm" << d.axis_point_mm;
    fs << "std_angle_scale" << d.angle_scale;
    text = fs.releaseAndGetString();
  } catch (const cv::Exception& ex) {
    return IoError("writing " + path + ": " + ex.msg);
  }
  return text;
}

std::string SummaryToJson(const RigCalibrationSummary& s) {
  nlohmann::json j;
  j["passed"] = s.passed;
  j["failures"] = s.failures;
  j["notes"] = s.notes;
  // null when not computed
  j["point_std_mm"] = std::isfinite(s.point_std_mm) ? nlohmann::json(s.point_std_mm) : nlohmann::json();
  j["point_std_max_mm"] =
      std::isfinite(s.point_std_max_mm) ? nlohmann::json(s.point_std_max_mm) : nlohmann::json();
  j["working_distance_mm"] = s.working_distance_mm;
  j["table_angles_refined"] = s.table_angles_refined;
  j["max_table_slip_deg"] = s.max_table_slip_deg;
  j["converged"] = s.converged;
  j["termination"] = s.termination;
  j["iterations"] = s.iterations;
  j["rms_px"] = s.rms_px;
  nlohmann::json views = nlohmann::json::array();
  for (const auto& v : s.per_view) {
    views.push_back(
        {{"name", v.name}, {"rms_px", v.rms_px}, {"table_angle_offset_deg", v.table_angle_offset_deg}});
  }
  j["per_view"] = views;
  j["laser"] = {{"left", {{"rms_mm", s.laser_rms_mm[0]}, {"points", s.laser_points[0]}}},
                {"right", {{"rms_mm", s.laser_rms_mm[1]}, {"points", s.laser_points[1]}}}};
  j["axis_fit_rms_mm"] = s.axis_fit_rms_mm;
  j["angle_scale"] = s.angle_scale;
  j["table_origin_on_table_top"] = s.table_origin_on_table_top;
  j["target_views"] = s.target_views;
  j["placements"] = s.placements;
  const StdDevs& d = s.std_devs;
  j["std_devs"] = {{"valid", d.valid},
                   {"fx_fy_cx_cy_px", d.intrinsics},
                   {"k1_k2_p1_p2_k3", d.distortion},
                   {"laser_normal_deg", d.laser_normal_deg},
                   {"laser_offset_mm", d.laser_offset_mm},
                   {"axis_direction_deg", d.axis_direction_deg},
                   {"axis_point_mm", d.axis_point_mm},
                   {"angle_scale", d.angle_scale}};
  return j.dump(2) + "\n";
}

}  // namespace rotoscan::calib
