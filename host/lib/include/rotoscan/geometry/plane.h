// A plane n . X + d = 0 with |n| = 1, in whatever frame its user names (laser planes live in the camera
// frame, DESIGN.md "Names and frames"). The paper's form c1 x + c2 y + c3 z + 1 = 0 (eq. 5) is c = n / d.
#pragma once

#include <optional>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace rotoscan::geometry {

struct Plane {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit length
  double offset = 0.0;                                // d, millimetres

  // The plane through `point` with normal `normal` (normalised here; must be non-zero).
  static Plane FromPointNormal(const Eigen::Vector3d& point, const Eigen::Vector3d& normal);
  // From the paper's coefficients (eq. 5): c . X + 1 = 0. c must be non-zero.
  static Plane FromPaperCoefficients(const Eigen::Vector3d& c);
  // The paper's c1..c3 (eq. 5); requires a plane not through the origin (|d| > 0).
  Eigen::Vector3d PaperCoefficients() const;

  // Signed distance (mm, positive on the normal's side) of a point given in the plane's frame (mm).
  double SignedDistance(const Eigen::Vector3d& point) const { return normal.dot(point) + offset; }

  // Where the ray origin + t * direction meets the plane: t, or nullopt when parallel (|n.dir| < eps). The
  // ray in the plane's frame (origin in mm); t in units of |direction| (mm for a unit direction).
  std::optional<double> IntersectRay(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                                     double eps = 1e-12) const;

  // The same plane with the normal flipped so that d >= 0 (a canonical sign for comparisons).
  Plane Canonical() const;
};

}  // namespace rotoscan::geometry
