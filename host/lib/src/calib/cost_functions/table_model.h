// The rig model shared by the calibration cost functions (private header), templated for Ceres Jets.
//
// A target placement p has a pose cam_from_target0 (angle-axis[3], translation[3] in mm) at table angle 0.
// At the commanded (nominal) table angle theta the table has turned by angle_scale * theta + offset
// right-handed about the axis (unit direction a through point c, camera frame); angle_scale absorbs a
// stepper whose real step differs from the nominal one, offset (one per table position, 0 and constant
// when not refined) a table that slipped there. So (the paper's eq. 7 generalised to a tilted axis):
//   point_in_cam = c + Rot(a, angle_scale * theta + offset) (R0 point_in_target + t0 - c).
// Undistortion inverts geometry::DistortNormalized with Newton steps on its analytic 2x2 Jacobian; at
// convergence the Jets carry the implicit-function derivative, so it is exact for Ceres.
#pragma once

#include <ceres/jet.h>
#include <ceres/rotation.h>

#include "rotoscan/geometry/camera.h"

namespace rotoscan::calib::internal {

// Rotates `v` by `angle` about the unit `axis` (Rodrigues).
template <typename T>
void RotateAboutUnitAxis(const T* axis, const T& angle, const T* v, T* out) {
  const T c = cos(angle);
  const T s = sin(angle);
  const T dot = axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2];
  const T cross[3] = {axis[1] * v[2] - axis[2] * v[1], axis[2] * v[0] - axis[0] * v[2],
                      axis[0] * v[1] - axis[1] * v[0]};
  for (int i = 0; i < 3; ++i) out[i] = v[i] * c + cross[i] * s + axis[i] * dot * (T(1) - c);
}

// point_in_cam of `point_in_target` at the nominal table angle `nominal_angle` (radians; see the file
// comment). `pose` = angle-axis[3], translation[3] of cam_from_target at angle 0; `axis_direction` need
// not be exactly unit; `angle_offset`[1] (radians) is added to the modelled table angle.
template <typename T>
void TargetPointInCam(const T* pose, const T* axis_direction, const T* axis_point, const T* angle_scale,
                      const T* angle_offset, double nominal_angle, const T* point_in_target,
                      T* point_in_cam) {
  T at_zero[3];
  ceres::AngleAxisRotatePoint(pose, point_in_target, at_zero);
  const T norm = sqrt(axis_direction[0] * axis_direction[0] + axis_direction[1] * axis_direction[1] +
                      axis_direction[2] * axis_direction[2]);
  const T axis[3] = {axis_direction[0] / norm, axis_direction[1] / norm, axis_direction[2] / norm};
  const T relative[3] = {at_zero[0] + pose[3] - axis_point[0], at_zero[1] + pose[4] - axis_point[1],
                         at_zero[2] + pose[5] - axis_point[2]};
  T turned[3];
  RotateAboutUnitAxis(axis, T(nominal_angle) * angle_scale[0] + angle_offset[0], relative, turned);
  for (int i = 0; i < 3; ++i) point_in_cam[i] = turned[i] + axis_point[i];
}

// The value part of a scalar (double, or a Jet's real part).
inline double ValueOf(double x) {
  return x;
}
template <typename T, int N>
double ValueOf(const ceres::Jet<T, N>& x) {
  return x.a;
}

// One Newton step of undistortion towards (xd, yd) from (*x, *y).
template <typename T>
void UndistortNewtonStep(const T* dist, const T& xd, const T& yd, T* x, T* y) {
  T fx, fy;
  geometry::DistortNormalized(dist, *x, *y, &fx, &fy);
  const T r2 = *x * *x + *y * *y;
  const T radial = T(1) + r2 * (dist[0] + r2 * (dist[1] + r2 * dist[4]));
  const T dradial = dist[0] + r2 * (T(2) * dist[1] + T(3) * r2 * dist[4]);
  const T j00 = radial + T(2) * *x * *x * dradial + T(2) * dist[2] * *y + T(6) * dist[3] * *x;
  const T j01 = T(2) * *x * *y * dradial + T(2) * dist[2] * *x + T(2) * dist[3] * *y;
  const T j11 = radial + T(2) * *y * *y * dradial + T(6) * dist[2] * *y + T(2) * dist[3] * *x;
  const T ex = fx - xd;
  const T ey = fy - yd;
  const T det = j00 * j11 - j01 * j01;
  *x -= (j11 * ex - j01 * ey) / det;
  *y -= (j00 * ey - j01 * ex) / det;
}

// Normalised undistorted coordinates (x/z, y/z) of a pixel. `intrinsics` = fx fy cx cy, `dist` = k1 k2 p1
// p2 k3 (geometry/camera.h). Newton converges quadratically: 8 steps on plain doubles reach double
// precision, then 2 steps in T from that point carry the exact derivatives (for Jets) at little cost.
template <typename T>
void UndistortPixel(const T* intrinsics, const T* dist, double u, double v, T* x, T* y) {
  const T xd = (T(u) - intrinsics[2]) / intrinsics[0];
  const T yd = (T(v) - intrinsics[3]) / intrinsics[1];
  double dist_value[5];
  for (int i = 0; i < 5; ++i) dist_value[i] = ValueOf(dist[i]);
  const double xd_value = ValueOf(xd), yd_value = ValueOf(yd);
  double x_value = xd_value, y_value = yd_value;
  for (int it = 0; it < 8; ++it) UndistortNewtonStep(dist_value, xd_value, yd_value, &x_value, &y_value);
  *x = T(x_value);
  *y = T(y_value);
  for (int it = 0; it < 2; ++it) UndistortNewtonStep(dist, xd, yd, x, y);
}

}  // namespace rotoscan::calib::internal
