// Pinhole camera with OpenCV's radial-tangential (Brown-Conrady) distortion, k1 k2 p1 p2 k3.
//
// Frames and units: a point_in_cam is in millimetres in the camera frame (x right, y down, z forward); a
// pixel is (column, row) with (0, 0) the centre of the top-left pixel, as in OpenCV. The paper's eq. 2 is
// the distortion-free case: x_p = fx * x_c / z_c + cx, y_p = fy * y_c / z_c + cy.
//
// The templated functions below are the single definition of the projection; the Ceres cost functions of
// the calib module instantiate them with Jets, so the model cannot drift between code paths.
#pragma once

#include <array>

#include <Eigen/Core>

#include "rotoscan/core/status.h"

namespace rotoscan::geometry {

// Applies distortion to normalised image coordinates (x/z, y/z). `dist` = k1 k2 p1 p2 k3.
template <typename T>
void DistortNormalized(const T* dist, const T& x, const T& y, T* xd, T* yd) {
  const T r2 = x * x + y * y;
  const T radial = T(1) + r2 * (dist[0] + r2 * (dist[1] + r2 * dist[4]));
  *xd = x * radial + T(2) * dist[2] * x * y + dist[3] * (r2 + T(2) * x * x);
  *yd = y * radial + dist[2] * (r2 + T(2) * y * y) + T(2) * dist[3] * x * y;
}

// Projects point_in_cam to a pixel. `intrinsics` = fx fy cx cy; `dist` = k1 k2 p1 p2 k3.
// The caller ensures z > 0.
template <typename T>
void ProjectToPixel(const T* intrinsics, const T* dist, const T* point_in_cam, T* pixel) {
  const T x = point_in_cam[0] / point_in_cam[2];
  const T y = point_in_cam[1] / point_in_cam[2];
  T xd, yd;
  DistortNormalized(dist, x, y, &xd, &yd);
  pixel[0] = intrinsics[0] * xd + intrinsics[2];
  pixel[1] = intrinsics[1] * yd + intrinsics[3];
}

struct CameraModel {
  int width = 0;                          // pixels
  int height = 0;                         // pixels
  double fx = 0, fy = 0, cx = 0, cy = 0;  // pixels
  std::array<double, 5> distortion{};     // k1 k2 p1 p2 k3 (OpenCV order)

  // A camera of the given size and horizontal field of view (degrees), principal point at the centre,
  // square pixels, no distortion.
  static CameraModel FromFieldOfView(int width, int height, double horizontal_fov_deg);

  // OK, or kInvalidArgument naming what is wrong (non-positive size or focal length, non-finite values).
  Status Validate() const;

  // OK when the lens model can be inverted over the whole image (every pixel's ray is finite and projects
  // back onto the pixel); kInvalidArgument naming the first pixel where it cannot (a field of view too
  // wide for the distortion coefficients: the inverse diverges and the ray is NaN).
  Status CheckInvertible() const;

  Eigen::Matrix3d K() const;
  std::array<double, 4> Intrinsics() const { return {fx, fy, cx, cy}; }
  bool HasDistortion() const;

  // Pixel of a point in the camera frame (z must be > 0), distortion applied.
  Eigen::Vector2d Project(const Eigen::Vector3d& point_in_cam) const;

  // Removes distortion: the normalised coordinates (x/z, y/z) whose projection is `pixel`. Iterative
  // (fixed point, then Gauss-Newton polish); exact to ~1e-12 inside the image for realistic lenses.
  Eigen::Vector2d Undistort(const Eigen::Vector2d& pixel) const;
  // The same from a starting point close to the answer (e.g. the neighbouring pixel's answer shifted by
  // the pixel step): Gauss-Newton alone, usually one or two steps; falls back to Undistort(pixel) if it
  // does not converge. For tables over the whole image (laser/triangulate.h).
  Eigen::Vector2d Undistort(const Eigen::Vector2d& pixel, const Eigen::Vector2d& guess) const;

  // The ray through `pixel` as a direction in the camera frame with z = 1 (distortion removed).
  Eigen::Vector3d PixelToRay(const Eigen::Vector2d& pixel) const;

  // True when `pixel` (column, row; pixel centres at whole numbers, the image edges at -0.5 and
  // width - 0.5) lies inside the image by at least `margin` pixels.
  bool IsInside(const Eigen::Vector2d& pixel, double margin = 0.0) const;

 private:
  // Gauss-Newton on distort(p) = target (normalised coordinates), at most `iterations` steps; true when
  // the residual is below 1e-13.
  bool PolishUndistorted(const Eigen::Vector2d& target, int iterations, Eigen::Vector2d* p) const;
};

}  // namespace rotoscan::geometry
