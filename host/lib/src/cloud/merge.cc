#include "rotoscan/cloud/merge.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "cell_index.h"
#include "rotoscan/core/check.h"

namespace rotoscan::cloud {
namespace {
using internal::CellIndex;

void SplitByLaser(const PointCloud& cloud, std::vector<uint32_t>* left, std::vector<uint32_t>* right) {
  ROTOSCAN_CHECK(cloud.size() < (size_t{1} << 32)) << "cloud too large";
  for (size_t i = 0; i < cloud.size(); ++i) {
    (cloud.points[i].laser == 0 ? left : right)->push_back(static_cast<uint32_t>(i));
  }
}

}  // namespace

Status MergeOptions::Check() const {
  if (!(voxel_mm > 0 && std::isfinite(voxel_mm))) return InvalidArgumentError("merge: voxel_mm must be > 0");
  if (!(overlap_radius_mm > 0 && std::isfinite(overlap_radius_mm))) {
    return InvalidArgumentError("merge: overlap_radius_mm must be > 0");
  }
  return Status::Ok();
}

LaserDisagreement MeasureLaserDisagreement(const PointCloud& cloud, double overlap_radius_mm) {
  ROTOSCAN_CHECK(overlap_radius_mm > 0);
  std::vector<uint32_t> left, right;
  SplitByLaser(cloud, &left, &right);
  return MeasureDisagreement(cloud, left, right, overlap_radius_mm);
}

LaserDisagreement MeasureDisagreement(const PointCloud& cloud, const std::vector<uint32_t>& left,
                                      const std::vector<uint32_t>& right, double overlap_radius_mm) {
  ROTOSCAN_CHECK(overlap_radius_mm > 0);
  LaserDisagreement result;
  if (left.empty() || right.empty()) return result;
  const CellIndex index(cloud, right, overlap_radius_mm);
  const float r2 = static_cast<float>(overlap_radius_mm * overlap_radius_mm);
  std::vector<double> signed_distances;
  double unsigned_sum = 0;
  size_t unsigned_count = 0;
  double color_sum = 0, color_abs_sum = 0;
  for (uint32_t i : left) {
    const CloudPoint& p = cloud.points[i];
    float best = r2;
    int64_t nearest = -1;
    index.ForEachNear(p.position_in_table, [&](uint32_t j) {
      const float d2 = (cloud.points[j].position_in_table - p.position_in_table).squaredNorm();
      if (d2 <= best) {
        best = d2;
        nearest = j;
      }
    });
    if (nearest < 0) continue;
    const CloudPoint& q = cloud.points[static_cast<size_t>(nearest)];
    const double color = ((q.color[0] + q.color[1] + q.color[2]) - (p.color[0] + p.color[1] + p.color[2])) / 3.0;
    color_sum += color;
    color_abs_sum += std::abs(color);
    const Eigen::Vector3f delta = q.position_in_table - p.position_in_table;
    if (p.normal.squaredNorm() > 0.5f) {
      signed_distances.push_back(p.normal.normalized().dot(delta));
    } else {
      unsigned_sum += delta.norm();
      ++unsigned_count;
    }
  }
  result.pairs = signed_distances.size() + unsigned_count;
  if (unsigned_count > 0) result.mean_unsigned_mm = unsigned_sum / unsigned_count;
  if (result.pairs > 0) {
    result.color_mean_signed = color_sum / static_cast<double>(result.pairs);
    result.color_mean_abs = color_abs_sum / static_cast<double>(result.pairs);
  }
  if (!signed_distances.empty()) {
    double sum = 0, sum2 = 0;
    for (double d : signed_distances) {
      sum += d;
      sum2 += d * d;
    }
    result.mean_signed_mm = sum / signed_distances.size();
    result.rms_mm = std::sqrt(sum2 / signed_distances.size());
    for (double& d : signed_distances) d = std::abs(d);
    auto mid = signed_distances.begin() + static_cast<std::ptrdiff_t>(signed_distances.size() / 2);
    std::nth_element(signed_distances.begin(), mid, signed_distances.end());
    result.median_abs_mm = *mid;
  }
  return result;
}

PointCloud MergeLasers(const PointCloud& cloud, const MergeOptions& options, MergeReport* report) {
  const Status status = options.Check();
  ROTOSCAN_CHECK(status.ok()) << status.ToString();
  MergeReport local;
  MergeReport& r = report != nullptr ? *report : local;
  r = MergeReport{};
  std::vector<uint32_t> left, right;
  SplitByLaser(cloud, &left, &right);
  r.left_in = left.size();
  r.right_in = right.size();
  // Summed quality of each laser per voxel.
  const CellIndex grid(cloud, {}, options.voxel_mm);
  std::unordered_map<uint64_t, std::pair<double, double>> quality;
  quality.reserve(cloud.size() / 4 + 1);
  for (const CloudPoint& p : cloud.points) {
    auto& q = quality[grid.Key(p.position_in_table)];
    (p.laser == 0 ? q.first : q.second) += std::max(1e-3f, p.quality);
  }
  for (const auto& [key, q] : quality) {
    if (q.first > 0 && q.second > 0) ++r.shared_voxels;
  }
  // The owner of a voxel is the laser with more quality over the voxel and its 26 neighbours, so that a
  // surface lying across voxel borders gets the same owner on both sides.
  auto owner_of = [&](const Eigen::Vector3f& position) {
    double sum_left = 0, sum_right = 0;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          auto it = quality.find(grid.Key(position, dx, dy, dz));
          if (it == quality.end()) continue;
          sum_left += it->second.first;
          sum_right += it->second.second;
        }
    return sum_left >= sum_right ? 0 : 1;
  };
  std::unordered_map<uint64_t, int> owner;
  owner.reserve(quality.size());
  // A point is dropped when the other laser owns its voxel and has a point within the overlap radius:
  // there the surface is already represented by the other laser.
  const CellIndex near_left(cloud, left, options.overlap_radius_mm);
  const CellIndex near_right(cloud, right, options.overlap_radius_mm);
  const float r2 = static_cast<float>(options.overlap_radius_mm * options.overlap_radius_mm);
  PointCloud merged;
  merged.points.reserve(cloud.size());
  for (const CloudPoint& p : cloud.points) {
    const uint64_t key = grid.Key(p.position_in_table);
    auto it = owner.find(key);
    if (it == owner.end()) it = owner.emplace(key, owner_of(p.position_in_table)).first;
    bool drop = false;
    if (it->second != p.laser) {
      const CellIndex& other = p.laser == 0 ? near_right : near_left;
      other.ForEachNear(p.position_in_table, [&](uint32_t j) {
        if ((cloud.points[j].position_in_table - p.position_in_table).squaredNorm() <= r2) drop = true;
      });
    }
    if (drop) continue;
    merged.points.push_back(p);
    (p.laser == 0 ? r.left_out : r.right_out) += 1;
  }
  r.disagreement = MeasureLaserDisagreement(cloud, options.overlap_radius_mm);
  return merged;
}

}  // namespace rotoscan::cloud
