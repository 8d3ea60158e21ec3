#include "rotoscan/laser/triangulate.h"

#include <algorithm>
#include <cmath>

#include "rotoscan/core/check.h"

namespace rotoscan::laser {

Triangulator::Triangulator(const geometry::CameraModel& camera) : camera_(camera) {
  const Status status = camera_.Validate();
  ROTOSCAN_CHECK(status.ok()) << status.ToString();
  distorted_ = camera_.HasDistortion();
  if (!distorted_) return;
  // Nodes at columns (k - 2) * kColumnStep, k = 0 .. nodes_per_row_ - 1: two before column 0 and enough
  // after width - 1 that every column in [-0.5, width - 0.5] has its four cubic taps.
  nodes_per_row_ = static_cast<int>(std::floor((camera_.width - 0.5 + 2 * kColumnStep) / kColumnStep)) + 3;
  normalized_.resize(static_cast<size_t>(nodes_per_row_) * camera_.height * 2);
  for (int r = 0; r < camera_.height; ++r) {
    float* out = normalized_.data() + static_cast<size_t>(r) * nodes_per_row_ * 2;
    // Each node starts from its left neighbour's answer shifted by one node step: one or two
    // Gauss-Newton steps instead of the full iteration.
    Eigen::Vector2d n = camera_.Undistort(Eigen::Vector2d(-2.0 * kColumnStep, r));
    for (int k = 0; k < nodes_per_row_; ++k) {
      if (k > 0) {
        n = camera_.Undistort(Eigen::Vector2d((k - 2.0) * kColumnStep, r),
                              n + Eigen::Vector2d(kColumnStep / camera_.fx, 0.0));
      }
      out[2 * k] = static_cast<float>(n.x());
      out[2 * k + 1] = static_cast<float>(n.y());
    }
  }
}

const float* Triangulator::TableEntry(double column, int row) const {
  const double u = (std::clamp(column, -0.5, camera_.width - 0.5) + 2 * kColumnStep) / kColumnStep;
  return normalized_.data() + (static_cast<size_t>(row) * nodes_per_row_ + static_cast<size_t>(u) - 1) * 2;
}

inline Eigen::Vector3d Triangulator::RayUnchecked(double column, int row) const {
  if (!distorted_) {
    return Eigen::Vector3d((column - camera_.cx) / camera_.fx, (row - camera_.cy) / camera_.fy, 1.0);
  }
  // Cubic (4-point Lagrange) interpolation between the nodes of the row: exact for a cubic, so its error
  // is of the order of the lens map's fourth derivative times kColumnStep^4 / 24, less than the float
  // storage's ~3e-5 px for the lenses of the tests (triangulate_test.cc measures it).
  const double u = (std::clamp(column, -0.5, camera_.width - 0.5) + 2 * kColumnStep) / kColumnStep;
  const int g = static_cast<int>(u);  // the node at or left of the column
  const double t = u - g;
  const double w0 = -t * (t - 1) * (t - 2) / 6, w1 = (t + 1) * (t - 1) * (t - 2) / 2;
  const double w2 = -(t + 1) * t * (t - 2) / 2, w3 = (t + 1) * t * (t - 1) / 6;
  const float* p = normalized_.data() + (static_cast<size_t>(row) * nodes_per_row_ + g - 1) * 2;
  return Eigen::Vector3d(w0 * p[0] + w1 * p[2] + w2 * p[4] + w3 * p[6],
                         w0 * p[1] + w1 * p[3] + w2 * p[5] + w3 * p[7], 1.0);
}

Eigen::Vector3d Triangulator::Ray(double column, int row) const {
  ROTOSCAN_CHECK(row >= 0 && row < camera_.height) << "row " << row;
  return RayUnchecked(column, row);
}

std::optional<Eigen::Vector3d> Triangulator::PointInCam(const geometry::Plane& plane_in_cam, double column,
                                                        int row) const {
  const Eigen::Vector3d ray = Ray(column, row);  // (Triangulate repeats this without the row check)
  const double denominator = plane_in_cam.normal.dot(ray);
  if (std::abs(denominator) < 1e-12) return std::nullopt;
  const double t = -plane_in_cam.offset / denominator;
  if (!(t > 0)) return std::nullopt;
  return Eigen::Vector3d(t * ray);
}

void Triangulator::Triangulate(const Line& line, const geometry::Plane& plane_in_cam,
                               std::vector<Eigen::Vector3d>* points_in_cam, std::vector<int>* kept) const {
  ROTOSCAN_CHECK(points_in_cam != nullptr && kept != nullptr);
  const size_t count = line.points.size();
  // Every point is written at the next free place and that place taken only when the point is valid: no
  // branch on the data per point, and no capacity check (outputs sized to the upper bound, then cut).
  points_in_cam->resize(count);
  kept->resize(count);
  Eigen::Vector3d* out_points = points_in_cam->data();
  int* out_kept = kept->data();
  size_t out = 0;
  // The table (1.3 MB at 1288x964) is read one row apart per point: fetching the entry a few points
  // ahead overlaps the cache misses.
  constexpr size_t kPrefetchAhead = 8;
  for (size_t i = 0; i < count; ++i) {
    if (distorted_ && i + kPrefetchAhead < count) {
      const LinePoint& ahead = line.points[i + kPrefetchAhead];
      if (ahead.row >= 0 && ahead.row < camera_.height) __builtin_prefetch(TableEntry(ahead.column, ahead.row));
    }
    const LinePoint& p = line.points[i];
    if (p.row < 0 || p.row >= camera_.height) continue;
    // PointInCam, inlined.
    const Eigen::Vector3d ray = RayUnchecked(p.column, p.row);
    const double denominator = plane_in_cam.normal.dot(ray);
    const double t = -plane_in_cam.offset / denominator;
    out_points[out] = t * ray;
    out_kept[out] = static_cast<int>(i);
    out += std::abs(denominator) >= 1e-12 && t > 0;
  }
  points_in_cam->resize(out);
  kept->resize(out);
}

}  // namespace rotoscan::laser
