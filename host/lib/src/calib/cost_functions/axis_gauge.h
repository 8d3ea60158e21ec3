// Gauge of the table axis (private header): any point of the axis line is as good as another, so the
// solve would let axis_point slide along the direction and the covariance would be rank deficient. This
// residual (1) pins its component along the initial direction: (a0 . (c - c0)) / sigma_mm. It has no effect
// on the line itself. Parameter block: axis_point[3] (mm).
#pragma once

#include <ceres/autodiff_cost_function.h>
#include <Eigen/Core>

namespace rotoscan::calib::internal {

class AxisGaugeCost {
 public:
  AxisGaugeCost(const Eigen::Vector3d& initial_point, const Eigen::Vector3d& initial_direction,
                double sigma_mm)
      : initial_point_(initial_point),
        initial_direction_(initial_direction.normalized()),
        inv_sigma_(1.0 / sigma_mm) {}

  template <typename T>
  bool operator()(const T* axis_point, T* residual) const {
    T along = T(0);
    for (int i = 0; i < 3; ++i) along += T(initial_direction_(i)) * (axis_point[i] - T(initial_point_(i)));
    residual[0] = along * T(inv_sigma_);
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Vector3d& initial_point,
                                     const Eigen::Vector3d& initial_direction, double sigma_mm) {
    return new ceres::AutoDiffCostFunction<AxisGaugeCost, 1, 3>(
        new AxisGaugeCost(initial_point, initial_direction, sigma_mm));
  }

 private:
  Eigen::Vector3d initial_point_;
  Eigen::Vector3d initial_direction_;
  double inv_sigma_;
};

}  // namespace rotoscan::calib::internal
