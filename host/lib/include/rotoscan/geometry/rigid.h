// Rigid transforms are Eigen::Isometry3d named target_from_source (cam_from_table); compose as
// c_from_a = c_from_b * b_from_a. Angles in radians.
#pragma once

#include <Eigen/Geometry>

namespace rotoscan::geometry {

// Rotation by `angle` (right hand about `axis_direction`) about the line through `axis_point`, all in the
// same frame. The paper's eq. 7 is the case of an axis along z through (x_r, y_r).
Eigen::Isometry3d RotationAboutAxis(const Eigen::Vector3d& axis_point, const Eigen::Vector3d& axis_direction,
                                    double angle);

// A frame whose origin is `origin` and whose z axis is `z_axis`, returned as parent_from_frame; the x axis
// is the projection of `x_hint` (any vector not parallel to z_axis).
Eigen::Isometry3d FrameFromOriginAndZ(const Eigen::Vector3d& origin, const Eigen::Vector3d& z_axis,
                                      const Eigen::Vector3d& x_hint = Eigen::Vector3d::UnitX());

inline double DegToRad(double deg) {
  return deg * 3.14159265358979323846 / 180.0;
}
inline double RadToDeg(double rad) {
  return rad * 180.0 / 3.14159265358979323846;
}

}  // namespace rotoscan::geometry
