#include "rotoscan/geometry/camera.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <Eigen/LU>

#include "rotoscan/core/check.h"

namespace rotoscan::geometry {

CameraModel CameraModel::FromFieldOfView(int width, int height, double horizontal_fov_deg) {
  ROTOSCAN_CHECK(width > 0 && height > 0) << "size " << width << "x" << height;
  ROTOSCAN_CHECK(horizontal_fov_deg > 0 && horizontal_fov_deg < 179) << "fov " << horizontal_fov_deg;
  CameraModel camera;
  camera.width = width;
  camera.height = height;
  camera.fx = camera.fy = 0.5 * width / std::tan(0.5 * horizontal_fov_deg * M_PI / 180.0);
  camera.cx = 0.5 * (width - 1);
  camera.cy = 0.5 * (height - 1);
  return camera;
}

Status CameraModel::Validate() const {
  if (width <= 0 || height <= 0) {
    return InvalidArgumentError("camera image size must be positive, got " + std::to_string(width) + "x" +
                                std::to_string(height));
  }
  for (double v : {fx, fy, cx, cy}) {
    if (!std::isfinite(v)) return InvalidArgumentError("camera intrinsics must be finite");
  }
  if (fx <= 0 || fy <= 0) return InvalidArgumentError("camera focal lengths fx, fy must be > 0");
  for (double k : distortion) {
    if (!std::isfinite(k)) return InvalidArgumentError("camera distortion coefficients must be finite");
  }
  return Status::Ok();
}

Status CameraModel::CheckInvertible() const {
  ROTOSCAN_RETURN_IF_ERROR(Validate());
  if (!HasDistortion()) return Status::Ok();
  // The inverse fails first where the distortion is strongest, at the border: walk it (one pixel outside
  // the image, as the renderer's ray grid does) and a coarse grid inside, every few pixels.
  auto bad = [&](double x, double y) {
    const Eigen::Vector2d pixel(x, y);
    const Eigen::Vector2d n = Undistort(pixel);
    if (!n.allFinite()) return true;
    const Eigen::Vector2d back = Project(Eigen::Vector3d(n.x(), n.y(), 1.0));
    return !back.allFinite() || (back - pixel).norm() > 1e-3;
  };
  const int step = std::max(1, std::min(width, height) / 64);
  for (int y = -1; y <= height; y += (y < 0 || y + step > height) ? 1 : step) {
    const bool edge_row = y < 0 || y >= height - 1;
    for (int x = -1; x <= width; x += (edge_row || x < 0 || x + step > width) ? 1 : step) {
      if (bad(x, y)) {
        return InvalidArgumentError("the lens distortion cannot be inverted at pixel (" + std::to_string(x) +
                                    ", " + std::to_string(y) +
                                    "): the field of view is too wide for these distortion coefficients");
      }
    }
  }
  return Status::Ok();
}

Eigen::Matrix3d CameraModel::K() const {
  Eigen::Matrix3d k;
  k << fx, 0, cx, 0, fy, cy, 0, 0, 1;
  return k;
}

bool CameraModel::HasDistortion() const {
  for (double k : distortion) {
    if (k != 0.0) return true;
  }
  return false;
}

Eigen::Vector2d CameraModel::Project(const Eigen::Vector3d& point_in_cam) const {
  const std::array<double, 4> intrinsics = Intrinsics();
  Eigen::Vector2d pixel;
  ProjectToPixel(intrinsics.data(), distortion.data(), point_in_cam.data(), pixel.data());
  return pixel;
}

Eigen::Vector2d CameraModel::Undistort(const Eigen::Vector2d& pixel) const {
  Eigen::Vector2d target((pixel.x() - cx) / fx, (pixel.y() - cy) / fy);
  if (!HasDistortion()) return target;
  // Fixed-point iteration (as OpenCV's undistortPoints) gets close; Gauss-Newton with a numeric Jacobian
  // then makes it exact.
  Eigen::Vector2d p = target;
  for (int i = 0; i < 20; ++i) {
    double xd, yd;
    DistortNormalized(distortion.data(), p.x(), p.y(), &xd, &yd);
    p += target - Eigen::Vector2d(xd, yd);
  }
  PolishUndistorted(target, 5, &p);
  return p;
}

bool CameraModel::PolishUndistorted(const Eigen::Vector2d& target, int iterations, Eigen::Vector2d* p) const {
  for (int i = 0; i < iterations; ++i) {
    double xd, yd;
    DistortNormalized(distortion.data(), p->x(), p->y(), &xd, &yd);
    const Eigen::Vector2d residual(xd - target.x(), yd - target.y());
    if (residual.norm() < 1e-15) return true;
    constexpr double h = 1e-7;
    Eigen::Matrix2d jacobian;
    for (int c = 0; c < 2; ++c) {
      Eigen::Vector2d q = *p;
      q[c] += h;
      double xh, yh;
      DistortNormalized(distortion.data(), q.x(), q.y(), &xh, &yh);
      jacobian.col(c) = (Eigen::Vector2d(xh, yh) - Eigen::Vector2d(xd, yd)) / h;
    }
    *p -= jacobian.lu().solve(residual);
  }
  double xd, yd;
  DistortNormalized(distortion.data(), p->x(), p->y(), &xd, &yd);
  return (Eigen::Vector2d(xd, yd) - target).norm() < 1e-13;
}

Eigen::Vector2d CameraModel::Undistort(const Eigen::Vector2d& pixel, const Eigen::Vector2d& guess) const {
  const Eigen::Vector2d target((pixel.x() - cx) / fx, (pixel.y() - cy) / fy);
  if (!HasDistortion()) return target;
  Eigen::Vector2d p = guess;
  if (p.allFinite() && PolishUndistorted(target, 4, &p)) return p;
  return Undistort(pixel);
}

Eigen::Vector3d CameraModel::PixelToRay(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d n = Undistort(pixel);
  return Eigen::Vector3d(n.x(), n.y(), 1.0);
}

bool CameraModel::IsInside(const Eigen::Vector2d& pixel, double margin) const {
  return pixel.x() >= -0.5 + margin && pixel.y() >= -0.5 + margin && pixel.x() <= width - 0.5 - margin &&
         pixel.y() <= height - 0.5 - margin;
}

}  // namespace rotoscan::geometry
