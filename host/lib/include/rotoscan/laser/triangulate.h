// Triangulation of extracted laser points: the ray through the sub-pixel line centre (distortion removed)
// intersected with the laser plane, both in the camera frame (paper §3.2; the plane is eq. 5). The paper's
// own closed form (eq. 6, geometry/dlt.h TriangulateWithPlane) with the 3x4 matrix is the same thing when
// the lens has no distortion (tested in host/tests/laser/triangulate_test.cc); this form also removes
// distortion, which eq. 6 cannot.
//
// Speed: undistortion is iterative, so the Triangulator tabulates the normalised coordinates (x/z, y/z)
// once, on every row at every kColumnStep-th column, and interpolates along the row with a cubic;
// extracted points always sit on integer rows. The table is 1.3 MB at 1288x964 (a per-pixel table was
// 10 MB: a cache miss per point, and 8x the set-up time). The error is < 5e-5 px for the lenses of the
// tests, most of it the float storage (triangulate_test.cc, TableInterpolationErrorIsNegligible).
#pragma once

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "rotoscan/geometry/camera.h"
#include "rotoscan/geometry/plane.h"
#include "rotoscan/laser/extract.h"

namespace rotoscan::laser {

class Triangulator {
 public:
  // `camera` must pass Validate().
  explicit Triangulator(const geometry::CameraModel& camera);

  const geometry::CameraModel& camera() const { return camera_; }

  // Ray direction (z = 1) in the camera frame through (column, row); row must be an integer row of the
  // image and column in [-0.5, width - 0.5] (clamped to the table's range).
  Eigen::Vector3d Ray(double column, int row) const;

  // The point where that ray meets `plane_in_cam` (mm, camera frame), or nullopt if the ray is parallel to
  // the plane or meets it behind the camera.
  std::optional<Eigen::Vector3d> PointInCam(const geometry::Plane& plane_in_cam, double column,
                                            int row) const;

  // All points of `line`; `points_in_cam[i]` belongs to `line.points[kept[i]]`. Clears both outputs.
  void Triangulate(const Line& line, const geometry::Plane& plane_in_cam,
                   std::vector<Eigen::Vector3d>* points_in_cam, std::vector<int>* kept) const;

 private:
  static constexpr int kColumnStep = 8;  // px between the table's nodes along a row

  Eigen::Vector3d RayUnchecked(double column, int row) const;  // Ray without the row check
  // The table's first value for the cubic through `column` on `row` (for prefetching; column clamped).
  const float* TableEntry(double column, int row) const;

  geometry::CameraModel camera_;
  bool distorted_ = false;
  int nodes_per_row_ = 0;
  std::vector<float> normalized_;  // per row and node: x/z, y/z (only when distorted)
};

}  // namespace rotoscan::laser
