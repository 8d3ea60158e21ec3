#include "rotoscan/geometry/rigid.h"

#include "rotoscan/core/check.h"

namespace rotoscan::geometry {

Eigen::Isometry3d RotationAboutAxis(const Eigen::Vector3d& axis_point, const Eigen::Vector3d& axis_direction,
                                    double angle) {
  ROTOSCAN_CHECK(axis_direction.norm() > 0) << "axis direction must be non-zero";
  const Eigen::Matrix3d rotation = Eigen::AngleAxisd(angle, axis_direction.normalized()).toRotationMatrix();
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  transform.linear() = rotation;
  transform.translation() = axis_point - rotation * axis_point;
  return transform;
}

Eigen::Isometry3d FrameFromOriginAndZ(const Eigen::Vector3d& origin, const Eigen::Vector3d& z_axis,
                                      const Eigen::Vector3d& x_hint) {
  ROTOSCAN_CHECK(z_axis.norm() > 0) << "z axis must be non-zero";
  const Eigen::Vector3d z = z_axis.normalized();
  Eigen::Vector3d x = x_hint - x_hint.dot(z) * z;
  ROTOSCAN_CHECK(x.norm() > 1e-9) << "x hint is parallel to the z axis";
  x.normalize();
  Eigen::Isometry3d parent_from_frame = Eigen::Isometry3d::Identity();
  parent_from_frame.linear().col(0) = x;
  parent_from_frame.linear().col(1) = z.cross(x);
  parent_from_frame.linear().col(2) = z;
  parent_from_frame.translation() = origin;
  return parent_from_frame;
}

}  // namespace rotoscan::geometry
