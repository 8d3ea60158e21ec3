// Reprojection error of one target corner seen at a table angle (private header).
//
// Residual (2): (projected - observed pixel) / sigma_px, with the projection of geometry/camera.h applied
// to the corner moved by the table model (table_model.h). Parameter blocks: intrinsics[4] (fx fy cx cy),
// distortion[5], pose[6] (cam_from_target at table angle 0: angle-axis, mm), axis_direction[3], axis_point[3]
// (mm), angle_scale[1] (real / nominal table angle), angle_offset[1] (rad: where the table stood at this
// view beyond angle_scale times the commanded angle; table_angle_prior.h).
#pragma once

#include <ceres/autodiff_cost_function.h>
#include <Eigen/Core>

#include "calib/cost_functions/table_model.h"
#include "rotoscan/geometry/camera.h"

namespace rotoscan::calib::internal {

class CornerReprojectionCost {
 public:
  CornerReprojectionCost(const Eigen::Vector3d& corner_in_target, const Eigen::Vector2d& pixel,
                         double nominal_angle, double sigma_px)
      : corner_in_target_(corner_in_target),
        pixel_(pixel),
        nominal_angle_(nominal_angle),
        inv_sigma_(1.0 / sigma_px) {}

  template <typename T>
  bool operator()(const T* intrinsics, const T* distortion, const T* pose, const T* axis_direction,
                  const T* axis_point, const T* angle_scale, const T* angle_offset, T* residual) const {
    const T corner[3] = {T(corner_in_target_.x()), T(corner_in_target_.y()), T(corner_in_target_.z())};
    T point_in_cam[3];
    TargetPointInCam(pose, axis_direction, axis_point, angle_scale, angle_offset, nominal_angle_, corner,
                     point_in_cam);
    if (!(point_in_cam[2] > T(0))) return false;  // behind the camera: reject the step
    T pixel[2];
    geometry::ProjectToPixel(intrinsics, distortion, point_in_cam, pixel);
    residual[0] = (pixel[0] - T(pixel_.x())) * T(inv_sigma_);
    residual[1] = (pixel[1] - T(pixel_.y())) * T(inv_sigma_);
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Vector3d& corner_in_target, const Eigen::Vector2d& pixel,
                                     double nominal_angle, double sigma_px) {
    return new ceres::AutoDiffCostFunction<CornerReprojectionCost, 2, 4, 5, 6, 3, 3, 1, 1>(
        new CornerReprojectionCost(corner_in_target, pixel, nominal_angle, sigma_px));
  }

 private:
  Eigen::Vector3d corner_in_target_;
  Eigen::Vector2d pixel_;
  double nominal_angle_;
  double inv_sigma_;
};

}  // namespace rotoscan::calib::internal
