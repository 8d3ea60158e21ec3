// A laser pixel seen on a plane of the target (z = 0 of a checkerboard, or one face of the paper's
// two-plane calibration object: any plane n_t . X + d_t = 0 of the target frame) must lie on the laser plane
// (private header). The pixel's ray (undistorted with the current intrinsics) meets the target plane at X,
// both in the camera frame; the residual (1) is the laser plane's signed distance n . X + d (mm) / sigma_mm.
// This is the paper's step 2 (eq. 11) made part of the joint solve: the 3D point moves with the camera and
// target estimates instead of being frozen after step 1.
// Parameter blocks: intrinsics[4], distortion[5], pose[6], axis_direction[3], axis_point[3], angle_scale[1],
// angle_offset[1] (rad, the table position's; corner_reprojection.h), plane_normal[3] (unit, camera frame),
// plane_offset[1] (mm).
#pragma once

#include <ceres/autodiff_cost_function.h>
#include <Eigen/Core>

#include "calib/cost_functions/table_model.h"

namespace rotoscan::calib::internal {

class LaserOnTargetCost {
 public:
  // `plane_in_target` = (n_t, d_t) with |n_t| = 1: the target plane the pixel lies on.
  LaserOnTargetCost(const Eigen::Vector2d& pixel, double nominal_angle, double sigma_mm,
                    const Eigen::Vector4d& plane_in_target = Eigen::Vector4d(0, 0, 1, 0))
      : pixel_(pixel), nominal_angle_(nominal_angle), inv_sigma_(1.0 / sigma_mm), plane_(plane_in_target) {}

  template <typename T>
  bool operator()(const T* intrinsics, const T* distortion, const T* pose, const T* axis_direction,
                  const T* axis_point, const T* angle_scale, const T* angle_offset, const T* plane_normal,
                  const T* plane_offset, T* residual) const {
    // The target plane in the camera frame: its point nearest the target origin (-d_t n_t) and that point
    // moved along the unit normal.
    const T origin_in_target[3] = {T(-plane_(3) * plane_(0)), T(-plane_(3) * plane_(1)),
                                   T(-plane_(3) * plane_(2))};
    const T z_in_target[3] = {origin_in_target[0] + T(plane_(0)), origin_in_target[1] + T(plane_(1)),
                              origin_in_target[2] + T(plane_(2))};
    T origin[3], z_tip[3];
    TargetPointInCam(pose, axis_direction, axis_point, angle_scale, angle_offset, nominal_angle_,
                     origin_in_target, origin);
    TargetPointInCam(pose, axis_direction, axis_point, angle_scale, angle_offset, nominal_angle_, z_in_target,
                     z_tip);
    const T m[3] = {z_tip[0] - origin[0], z_tip[1] - origin[1], z_tip[2] - origin[2]};
    T ray[3] = {T(0), T(0), T(1)};
    UndistortPixel(intrinsics, distortion, pixel_.x(), pixel_.y(), &ray[0], &ray[1]);
    const T denominator = m[0] * ray[0] + m[1] * ray[1] + m[2] * ray[2];
    if (!(abs(denominator) > T(1e-9))) return false;  // ray parallel to the target
    const T t = (m[0] * origin[0] + m[1] * origin[1] + m[2] * origin[2]) / denominator;
    const T n_norm = sqrt(plane_normal[0] * plane_normal[0] + plane_normal[1] * plane_normal[1] +
                          plane_normal[2] * plane_normal[2]);
    const T distance =
        (plane_normal[0] * ray[0] + plane_normal[1] * ray[1] + plane_normal[2] * ray[2]) * t / n_norm +
        plane_offset[0];
    residual[0] = distance * T(inv_sigma_);
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Vector2d& pixel, double nominal_angle, double sigma_mm,
                                     const Eigen::Vector4d& plane_in_target = Eigen::Vector4d(0, 0, 1, 0)) {
    return new ceres::AutoDiffCostFunction<LaserOnTargetCost, 1, 4, 5, 6, 3, 3, 1, 1, 3, 1>(
        new LaserOnTargetCost(pixel, nominal_angle, sigma_mm, plane_in_target));
  }

 private:
  Eigen::Vector2d pixel_;
  double nominal_angle_;
  double inv_sigma_;
  Eigen::Vector4d plane_;
};

}  // namespace rotoscan::calib::internal
