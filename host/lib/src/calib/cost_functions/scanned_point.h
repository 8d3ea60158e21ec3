// Where a scan puts a point, as a function of the calibrated parameters (private header): not a cost, the
// quantity whose uncertainty judges a calibration (rig_calibration.h, RigCalibrationSummary::point_std_mm).
// Wrapped in ceres::AutoDiffCostFunction only to get its Jacobian, which the parameter covariance is
// propagated through.
//
// A pixel of laser l's line seen at table angle theta is triangulated as in a scan: its undistorted ray
// (table_model.h UndistortPixel) meets the laser plane (n, d) (the paper's eq. 6: X = ray * -d / (n . ray),
// n normalised), and the table turned back by theta about the axis (a, c) (eq. 7 about a 3D axis):
//   point_in_world = c + Rot(a, -theta) (X - c),
// world being the camera frame at table angle 0. At theta = 0 only the camera and the laser plane enter; at
// other angles the axis does: a scan's points from different angles disagree by its error. The frame is the
// camera's, so nothing here is a gauge (the table frame's origin along the axis and its x direction are
// conventions, and a rigid motion of the whole cloud is no error).
// Residual (3): point_in_world (mm). Parameter blocks: intrinsics[4], distortion[5], plane_normal[3],
// plane_offset[1] (mm), axis_direction[3], axis_point[3] (mm).
#pragma once

#include <ceres/autodiff_cost_function.h>
#include <Eigen/Core>

#include "calib/cost_functions/table_model.h"

namespace rotoscan::calib::internal {

class ScannedPoint {
 public:
  ScannedPoint(const Eigen::Vector2d& pixel, double table_angle) : pixel_(pixel), table_angle_(table_angle) {}

  template <typename T>
  bool operator()(const T* intrinsics, const T* distortion, const T* plane_normal, const T* plane_offset,
                  const T* axis_direction, const T* axis_point, T* point_in_world) const {
    T ray[3] = {T(0), T(0), T(1)};
    UndistortPixel(intrinsics, distortion, pixel_.x(), pixel_.y(), &ray[0], &ray[1]);
    const T n_norm = sqrt(plane_normal[0] * plane_normal[0] + plane_normal[1] * plane_normal[1] +
                          plane_normal[2] * plane_normal[2]);
    const T n_dot_ray =
        (plane_normal[0] * ray[0] + plane_normal[1] * ray[1] + plane_normal[2] * ray[2]) / n_norm;
    if (!(abs(n_dot_ray) > T(1e-9))) return false;  // ray in the laser plane
    const T t = -plane_offset[0] / n_dot_ray;
    const T a_norm = sqrt(axis_direction[0] * axis_direction[0] + axis_direction[1] * axis_direction[1] +
                          axis_direction[2] * axis_direction[2]);
    const T axis[3] = {axis_direction[0] / a_norm, axis_direction[1] / a_norm, axis_direction[2] / a_norm};
    const T relative[3] = {ray[0] * t - axis_point[0], ray[1] * t - axis_point[1],
                           ray[2] * t - axis_point[2]};
    T turned[3];
    RotateAboutUnitAxis(axis, T(-table_angle_), relative, turned);
    for (int i = 0; i < 3; ++i) point_in_world[i] = turned[i] + axis_point[i];
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Vector2d& pixel, double table_angle) {
    return new ceres::AutoDiffCostFunction<ScannedPoint, 3, 4, 5, 3, 1, 3, 3>(
        new ScannedPoint(pixel, table_angle));
  }

 private:
  Eigen::Vector2d pixel_;
  double table_angle_;
};

}  // namespace rotoscan::calib::internal
