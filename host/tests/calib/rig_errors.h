// Errors of an estimated rig against the true one, for the rendered calibration tests.
#pragma once

#include <algorithm>
#include <cmath>

#include <Eigen/Core>

#include "rotoscan/geometry/plane.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/geometry/rigid.h"

namespace rotoscan::testing {

// Angle between two planes' normals, degrees (either orientation).
inline double NormalErrorDeg(const geometry::Plane& a, const geometry::Plane& b) {
  return geometry::RadToDeg(std::acos(std::min(1.0, std::abs(a.normal.dot(b.normal)))));
}
// Difference of the canonical offsets, mm.
inline double OffsetErrorMm(const geometry::Plane& a, const geometry::Plane& b) {
  return std::abs(a.Canonical().offset - b.Canonical().offset);
}
// Distance of the estimated axis from the true one, across the true axis, at the true axis point (the
// middle of the working volume on the optical axis), mm.
inline double AxisDistanceMm(const geometry::Rig& estimate, const geometry::Rig& truth) {
  const Eigen::Vector3d& a = estimate.axis_direction_in_cam;
  const Eigen::Vector3d p =
      estimate.axis_point_in_cam + a * a.dot(truth.axis_point_in_cam - estimate.axis_point_in_cam);  // nearest
  const Eigen::Vector3d off = p - truth.axis_point_in_cam;
  return (off - truth.axis_direction_in_cam.dot(off) * truth.axis_direction_in_cam).norm();
}
// Angle between the axis directions, degrees.
inline double AxisAngleDeg(const geometry::Rig& a, const geometry::Rig& b) {
  return geometry::RadToDeg(std::acos(std::min(1.0, a.axis_direction_in_cam.dot(b.axis_direction_in_cam))));
}

}  // namespace rotoscan::testing
