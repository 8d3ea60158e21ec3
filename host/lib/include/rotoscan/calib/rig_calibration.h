// Calibration of the whole rig (camera, both laser planes, table axis, step angle) from observations of a
// planar target standing on the turntable: the paper's three steps (§4) as the initial value, then one
// joint refinement of everything with Ceres.
//
// Observations (whatever produced them: calibration bundles, the virtual scanner, a test):
//  * TargetView: the target's corners at one table step of one placement (a placement = one way of
//    standing the target on the table; the target does not move on the table between steps). A planar
//    target (checkerboard) has its corners on z = 0; the paper's calibration object (two orthogonal planes
//    with a 10 mm grid, calib/calibration_object.h) gives corners on two planes.
//  * LaserView: laser pixels that lie on one plane of the target (plane_in_target: z = 0 of a board, or one
//    face of the object) at one step of one placement, for one laser.
//
// Three-step initial value (CalibrateThreeStep): (1) the camera, unless one is given: when some target view
// is not planar (the paper's object), the paper's step 1: the 3x4 matrix of every such view by DLT with
// Hartley normalisation (eq. 8-10, geometry/dlt.h), decomposed into K [R | t], K the median over the views
// and no distortion (the paper neglects it); otherwise intrinsics and distortion by OpenCV's
// calibrateCamera on the (planar) views; then every view's pose by solvePnP; (2) the table axis from the
// poses of each placement (calib/axis_fit.h FitAxisFromPoses: direction, point, step angle), combined over
// placements; (3) each laser plane by a robust plane fit (calib/plane_fit.h) of its pixels' rays meeting
// the target plane.
//
// Joint refinement (RefineRig): minimises, with a robust (Huber) loss, the reprojection error of every
// corner (in units of corner_sigma_px) and the laser-plane distance of every laser pixel's point on the
// target (in units of laser_sigma_mm), over intrinsics, distortion, one pose per placement, the axis
// (unit direction on a sphere manifold, point with a gauge residual), the table angle scale, both planes
// (unit normals on a sphere manifold, offsets) and, with refine_table_angles, the table angle of every
// position where the target is seen: a real table slips (a sweep commanded in 3.6 degree steps stepped 2.9
// or 4.05 degrees), so the commanded angles are priors of standard deviation table_angle_sigma_deg, not
// truths. Standard deviations come from ceres::Covariance scaled by the a posteriori variance factor
// (2 cost / (residuals - parameters)).
//
// Pass/fail judges what the user gets: the predicted error of a scanned point at the working distance
// (RigCalibrationSummary::point_std_mm), the parameter covariance propagated through a scan's own
// triangulation (eq. 6) and table turn (eq. 7) to points of both laser lines where the target stood, over a
// whole turn of the table; plus the standard deviations of the laser planes and the axis (DESIGN.md's
// targets). Pixel figures (reprojection RMS, views over 1 px) are information: a view's residual tells
// where to look, but it is the covariance, scaled by the residuals, that says whether scans will be right.
#pragma once

#include <array>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rotoscan/core/status.h"
#include "rotoscan/geometry/camera.h"
#include "rotoscan/geometry/rig.h"

namespace rotoscan::calib {

struct TargetView {
  int placement = 0;             // which placement of the target on the table (0, 1, ...)
  int step = 0;                  // table step index: views of one placement at one step share a pose
  double table_angle_rad = 0.0;  // commanded table angle (the model turns by angle_scale times it)
  std::vector<Eigen::Vector3d> corners_in_target;  // mm, target frame
  std::vector<Eigen::Vector2d> corner_pixels;      // same order
  std::string name;                                // for messages and the report
  // Height of the target frame's origin above the table top (bundle.h TargetInfo::origin_height_mm) for
  // a target standing on the table; NaN when unknown or not on the table (a hand-held board).
  double origin_height_mm = std::numeric_limits<double>::quiet_NaN();
};

struct LaserView {
  geometry::LaserId laser = geometry::LaserId::kLeft;
  int placement = 0;
  int step = 0;
  double table_angle_rad = 0.0;         // commanded table angle
  std::vector<Eigen::Vector2d> pixels;  // laser line centres on the target plane below
  // The target plane the pixels lie on, (n, d) with |n| = 1 and n . X + d = 0 in the target frame.
  Eigen::Vector4d plane_in_target{0.0, 0.0, 1.0, 0.0};
  std::string name;
};

struct CalibrationData {
  int image_width = 0;
  int image_height = 0;
  double nominal_step_rad = 0.0;  // table rotation per step as commanded (> 0); rig.step_angle_rad =
                                  // angle_scale * nominal_step_rad
  std::vector<TargetView> target_views;
  std::vector<LaserView> laser_views;
};

struct RigCalibrationOptions {
  int min_target_views = 6;      // fewer is an error saying what to capture
  int min_table_positions = 3;   // distinct steps of one placement needed for the axis
  int min_laser_points = 30;     // per laser
  double laser_inlier_mm = 0.5;  // robust plane fit threshold (three-step)
  double corner_sigma_px = 0.1;  // expected corner noise: residual unit of the joint solve
  double laser_sigma_mm = 0.05;  // expected laser point noise along the plane normal
  double huber_sigmas = 3.0;     // Huber loss threshold, in sigmas
  bool refine_intrinsics = true;
  bool refine_distortion = true;
  bool refine_angle_scale = true;
  // Each table position's angle where the target is seen, with the commanded angle as a prior of this
  // standard deviation (see the file comment). Off: the commanded angles (times the scale) are truths.
  bool refine_table_angles = true;
  double table_angle_sigma_deg = 0.5;
  // What the prior constrains: each position's angle against its commanded one (kAbsolute: a table whose
  // positions are off each on its own), or each move between consecutive positions where the target is
  // seen (kIncrements: a table whose lost steps accumulate, `simulate --table-slip-mode cumulative`; the
  // first position of each placement keeps the absolute prior).
  enum class TableAnglePrior { kAbsolute, kIncrements };
  TableAnglePrior table_angle_prior = TableAnglePrior::kAbsolute;
  int max_iterations = 100;
  bool compute_covariance = true;
  // Pass/fail threshold of the report: the predicted error (1 sigma, RMS over the sample points) of a
  // scanned point at the working distance (DESIGN.md: plane RMS <= 0.05 mm at 300 mm).
  double max_point_std_mm = 0.05;
  // Pixel figures above these are noted in the report (information, not failures).
  double max_rms_px = 0.5;
  double max_view_rms_px = 1.0;
  // Further pass/fail thresholds.
  double max_laser_rms_mm = 0.1;
  double max_axis_rms_mm = 0.1;
  // ... and on the standard deviations of the joint solve (DESIGN.md's accuracy targets): a capture that
  // cannot determine a parameter this well fails, saying what to capture.
  double max_normal_std_deg = 0.05;
  double max_offset_std_mm = 0.05;
  double max_axis_std_mm = 0.05;
  double max_axis_std_deg = 0.05;
  Status Check() const;
};

// The rig plus what the solve needs: one pose per placement at table angle 0, and the ratio of real to
// commanded table angles.
struct RigEstimate {
  geometry::Rig rig;
  std::vector<Eigen::Isometry3d> cam_from_target0;  // per placement
  double angle_scale = 1.0;                         // real table angle / commanded angle
  double axis_fit_rms_mm = 0.0;                     // three-step axis fit residual (calib/axis_fit.h)
  // Refined table angles (RigCalibrationOptions::refine_table_angles): per (placement, step), where the
  // table stood beyond angle_scale times the commanded angle (radians). A position not listed is at
  // angle_scale times its commanded angle.
  std::map<std::pair<int, int>, double> angle_offset_rad;

  // The table angle of a view as this estimate models it: angle_scale * commanded + its offset (radians).
  double TableAngle(int placement, int step, double commanded_rad) const;
};

// The paper's three steps with OpenCV intrinsics (see the file comment). `camera`: known intrinsics to use
// instead of estimating them. Errors (kInvalidArgument) say what to capture: the target found in no view or
// in too few, a view whose corners lie on one line, a placement seen at too few table positions, a laser
// never seen or seen on one target plane only (its points on one line), the calibration object seen on one
// face only (coplanar corners: no DLT).
Result<RigEstimate> CalibrateThreeStep(const CalibrationData& data, const RigCalibrationOptions& options,
                                       const std::optional<geometry::CameraModel>& camera = std::nullopt);

struct StdDevs {
  std::array<double, 4> intrinsics{};        // fx fy cx cy, px
  std::array<double, 5> distortion{};        // k1 k2 p1 p2 k3
  std::array<double, 2> laser_normal_deg{};  // per laser: angular std dev of the normal
  std::array<double, 2> laser_offset_mm{};
  double axis_direction_deg = 0.0;
  double axis_point_mm = 0.0;  // across the axis (the along-axis component is a gauge)
  double angle_scale = 0.0;    // real / commanded table angle
  bool valid = false;          // false when the covariance could not be computed
};

struct ViewResidual {
  std::string name;
  double rms_px = 0.0;
  // Refined table angle minus the commanded one (degrees): angle scale and slip together; 0 when the
  // angles are not refined.
  double table_angle_offset_deg = 0.0;
};

struct RigCalibrationSummary {
  bool converged = false;
  std::string termination;  // Ceres' report line
  int iterations = 0;
  double rms_px = 0.0;                   // all corners
  std::vector<ViewResidual> per_view;    // per target view
  std::array<double, 2> laser_rms_mm{};  // per laser: RMS distance of its target points from its plane
  std::array<int, 2> laser_points{};
  double axis_fit_rms_mm = 0.0;  // three-step axis residual (how well poses fit one rotation axis)
  double angle_scale = 1.0;      // real / commanded table angle
  int target_views = 0;
  int placements = 0;
  StdDevs std_devs;
  // The predicted error of a scanned point (see the file comment): 1-sigma 3D error in mm, RMS and largest
  // over points of both laser lines at the working distance (on the axis, +- the target's reach across
  // it, over the heights where the target was seen) at 8 table angles over a whole turn; NaN when the
  // covariance is not computed. The table angle scale is not in it (a scan's angles are its own commanded
  // ones; std_devs.angle_scale says how well the scale is known).
  double point_std_mm = std::numeric_limits<double>::quiet_NaN();
  double point_std_max_mm = std::numeric_limits<double>::quiet_NaN();
  double working_distance_mm = 0.0;  // mean distance of those points from the camera
  bool table_angles_refined = false;
  double max_table_slip_deg = 0.0;  // largest |refined - commanded| table angle, scale removed (degrees)
  bool passed = false;
  std::vector<std::string> failures;  // why it did not pass, each saying what to do
  std::vector<std::string> notes;     // information: pixel figures over their limits, slipped table positions
  // Whether the table frame's origin is on the table top (PlaceTableOrigin) or, with no target height
  // known, at a target origin's height along the axis.
  bool table_origin_on_table_top = false;
};

struct RigCalibration {
  RigEstimate estimate;
  RigCalibrationSummary summary;
};

// Puts the table frame's origin on the table top (DESIGN.md "Names and frames"): the views fix the axis
// but not where along it the table top is, so the origin is the foot on the axis of the first placement's
// target origin (at table angle 0), lowered by that view's origin_height_mm. True when a view had a
// height; false (the rig unchanged: its origin stays at a target origin's height) otherwise. Both
// CalibrateThreeStep and RefineRig call it; the along-axis position is a gauge of the joint solve.
bool PlaceTableOrigin(const CalibrationData& data, RigEstimate* estimate);

// The joint refinement from `initial` (usually CalibrateThreeStep's). kNotConverged when Ceres fails.
Result<RigCalibration> RefineRig(const CalibrationData& data, const RigEstimate& initial,
                                 const RigCalibrationOptions& options);

// The summary of a rig without refining it (residuals of `estimate` on `data`): for the three-step result.
RigCalibrationSummary Evaluate(const CalibrationData& data, const RigEstimate& estimate,
                               const RigCalibrationOptions& options);

// calib.yaml: geometry::WriteRigNodes, then the report keys (report_passed, report_failures, rms_px,
// per_view_rms_px, per_view_names, per_view_table_angle_offset_deg, point_std_mm, point_std_max_mm,
// report_notes, laser_left_rms_mm, laser_right_rms_mm, axis_fit_rms_mm, angle_scale, std_* ...). Atomic.
Status WriteCalibrationYaml(const std::filesystem::path& path, const RigCalibration& calibration);
// The same YAML text, for writing it together with other files; `name` is for the messages.
Result<std::string> EncodeCalibrationYaml(const RigCalibration& calibration, const std::string& name);
// The report as JSON (for --report).
std::string SummaryToJson(const RigCalibrationSummary& summary);

}  // namespace rotoscan::calib
