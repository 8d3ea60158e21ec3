#include "rotoscan/geometry/plane.h"

#include <cmath>

#include "rotoscan/core/check.h"

namespace rotoscan::geometry {

Plane Plane::FromPointNormal(const Eigen::Vector3d& point, const Eigen::Vector3d& normal) {
  ROTOSCAN_CHECK(normal.norm() > 0) << "plane normal must be non-zero";
  Plane plane;
  plane.normal = normal.normalized();
  plane.offset = -plane.normal.dot(point);
  return plane;
}

Plane Plane::FromPaperCoefficients(const Eigen::Vector3d& c) {
  const double norm = c.norm();
  ROTOSCAN_CHECK(norm > 0) << "paper plane coefficients must be non-zero";
  Plane plane;
  plane.normal = c / norm;
  plane.offset = 1.0 / norm;
  return plane;
}

Eigen::Vector3d Plane::PaperCoefficients() const {
  ROTOSCAN_CHECK(std::abs(offset) > 1e-12) << "a plane through the origin has no eq. 5 form";
  return normal / offset;
}

std::optional<double> Plane::IntersectRay(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                                          double eps) const {
  const double denom = normal.dot(direction);
  if (std::abs(denom) < eps) return std::nullopt;
  return -(normal.dot(origin) + offset) / denom;
}

Plane Plane::Canonical() const {
  if (offset >= 0) return *this;
  Plane flipped;
  flipped.normal = -normal;
  flipped.offset = -offset;
  return flipped;
}

}  // namespace rotoscan::geometry
