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
  normalized_.resize(static_cast<size_t>(camera_.width) * camera_.height * 2);
  for (int r = 0; r < camera_.height; ++r) {
    float* out = normalized_.data() + static_cast<size_t>(r) * camera_.width * 2;
    // Each pixel starts from its left neighbour's answer shifted by one pixel step: one or two
    // Gauss-Newton steps instead of the full iteration (pipeline_bench BM_TriangulatorSetup: 377 -> 152 ms).
    Eigen::Vector2d n = camera_.Undistort(Eigen::Vector2d(0, r));
    for (int c = 0; c < camera_.width; ++c) {
      if (c > 0) n = camera_.Undistort(Eigen::Vector2d(c, r), n + Eigen::Vector2d(1.0 / camera_.fx, 0.0));
      out[2 * c] = static_cast<float>(n.x());
      out[2 * c + 1] = static_cast<float>(n.y());
    }
  }
}

Eigen::Vector3d Triangulator::Ray(double column, int row) const {
  ROTOSCAN_CHECK(row >= 0 && row < camera_.height) << "row " << row;
  if (!distorted_) {
    return Eigen::Vector3d((column - camera_.cx) / camera_.fx, (row - camera_.cy) / camera_.fy, 1.0);
  }
  // Linear interpolation between the two tabulated pixel centres; outside [0, width - 1] the end
  // interval is extrapolated (at most half a pixel).
  const int width = camera_.width;
  int c0 = static_cast<int>(std::floor(column));
  c0 = std::clamp(c0, 0, std::max(0, width - 2));
  const int c1 = std::min(c0 + 1, width - 1);
  const double t = c1 > c0 ? std::clamp(column - c0, -0.5, 1.5) : 0.0;
  const float* p = normalized_.data() + (static_cast<size_t>(row) * width + c0) * 2;
  const float* q = normalized_.data() + (static_cast<size_t>(row) * width + c1) * 2;
  return Eigen::Vector3d(p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]), 1.0);
}

std::optional<Eigen::Vector3d> Triangulator::PointInCam(const geometry::Plane& plane_in_cam, double column,
                                                        int row) const {
  const Eigen::Vector3d ray = Ray(column, row);
  const double denominator = plane_in_cam.normal.dot(ray);
  if (std::abs(denominator) < 1e-12) return std::nullopt;
  const double t = -plane_in_cam.offset / denominator;
  if (!(t > 0)) return std::nullopt;
  return Eigen::Vector3d(t * ray);
}

void Triangulator::Triangulate(const Line& line, const geometry::Plane& plane_in_cam,
                               std::vector<Eigen::Vector3d>* points_in_cam, std::vector<int>* kept) const {
  ROTOSCAN_CHECK(points_in_cam != nullptr && kept != nullptr);
  points_in_cam->clear();
  kept->clear();
  // The undistortion table is 8 bytes x width x height (10 MB at 1288x964) and a line visits one entry
  // per row: a cache miss each (Ray() was 7 % of a frame's time in laser_bench). Fetching the entry a few
  // points ahead overlaps the misses.
  constexpr size_t kPrefetchAhead = 8;
  const size_t count = line.points.size();
  for (size_t i = 0; i < count; ++i) {
    if (distorted_ && i + kPrefetchAhead < count) {
      const LinePoint& ahead = line.points[i + kPrefetchAhead];
      if (ahead.row >= 0 && ahead.row < camera_.height && ahead.column >= 0 && ahead.column < camera_.width) {
        __builtin_prefetch(normalized_.data() +
                           (static_cast<size_t>(ahead.row) * camera_.width + static_cast<size_t>(ahead.column)) * 2);
      }
    }
    const LinePoint& p = line.points[i];
    if (p.row < 0 || p.row >= camera_.height) continue;
    const auto point = PointInCam(plane_in_cam, p.column, p.row);
    if (!point) continue;
    points_in_cam->push_back(*point);
    kept->push_back(static_cast<int>(i));
  }
}

}  // namespace rotoscan::laser
