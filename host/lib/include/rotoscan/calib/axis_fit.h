// The table's rotation axis: the paper's step 3 (§4.3, eq. 13-15, a circle fit giving the rotation centre
// on the table plane) and, beyond the paper, the full 3D axis (direction and point) since real tables tilt.
//
//  * FitCircle2d: eq. 14-15, the algebraic (Kasa) circle fit, linear least squares in (x_r, y_r, l).
//  * FitCircle3d: points on a circle in space (one target corner tracked around the axis): the circle's
//    plane by total least squares, then eq. 14-15 in that plane. Its centre is on the axis and its normal
//    is the axis direction.
//  * FitAxisFromTracks: several corners tracked around the axis (one circle each): direction = the average
//    of the circle normals weighted by their number of points, sign-aligned; point = the mean of the circle
//    centres projected onto the plane normal to the direction through the first centre. The spread of the
//    centres about the line is the axis fit residual.
//  * FitAxisFromPoses: poses cam_from_target of one target placement at several table angles. The relative
//    rotation between two poses is a rotation about the axis; its angle-axis gives the direction and the
//    step angle, and t_i = R_i0 t_0 + (I - R_i0) c gives a point c on the axis (linear least squares, made
//    unique by putting c at the target origin's height along the axis).
//
// Frames: whatever frame the inputs are in (the camera frame in the calibration), mm and radians.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rotoscan/core/status.h"

namespace rotoscan::calib {

struct CircleFit2d {
  Eigen::Vector2d centre{0, 0};  // (x_r, y_r) of eq. 13
  double radius = 0.0;
  double rms = 0.0;  // RMS of |distance to centre| - radius
};
Result<CircleFit2d> FitCircle2d(const std::vector<Eigen::Vector2d>& points);

struct CircleFit3d {
  Eigen::Vector3d centre{0, 0, 0};
  Eigen::Vector3d normal{0, 0, 1};  // unit; sign arbitrary
  double radius = 0.0;
  double rms = 0.0;  // RMS of the 3D distance from the fitted circle
};
Result<CircleFit3d> FitCircle3d(const std::vector<Eigen::Vector3d>& points);

struct AxisFit {
  Eigen::Vector3d point{0, 0, 0};      // a point on the axis
  Eigen::Vector3d direction{0, 0, 1};  // unit
  double rms_mm = 0.0;                 // residual of the fit (see each function)
  double mean_step_rad = 0.0;          // FitAxisFromPoses only: mean rotation between successive poses
};

// `tracks[k]` = positions of corner k at successive table angles (>= 3 points each, not collinear). The
// direction's sign follows the first track's normal; callers orient it. rms_mm combines the circle
// residuals and the spread of the centres about the axis.
Result<AxisFit> FitAxisFromTracks(const std::vector<std::vector<Eigen::Vector3d>>& tracks);

// `cam_from_target[i]` at table angles increasing with i (>= 2 poses, not all the same). The direction is
// oriented so that the table turns right-handed about it from pose 0 to pose 1. rms_mm is the RMS residual
// of t_i = R_i0 t_0 + (I - R_i0) c.
Result<AxisFit> FitAxisFromPoses(const std::vector<Eigen::Isometry3d>& cam_from_target);

}  // namespace rotoscan::calib
