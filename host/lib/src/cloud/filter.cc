#include "rotoscan/cloud/filter.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <thread>
#include <unordered_map>
#include <vector>

#include "cell_index.h"

namespace rotoscan::cloud {
namespace {

// Runs body(begin, end) over [0, n) in `threads` contiguous parts.
template <typename Body>
void ParallelFor(size_t n, int threads, const Body& body) {
  const size_t parts = std::min<size_t>(static_cast<size_t>(threads), std::max<size_t>(1, n / 4096));
  std::vector<std::thread> workers;
  for (size_t p = 1; p < parts; ++p)
    workers.emplace_back([&, p] { body(n * p / parts, n * (p + 1) / parts); });
  body(size_t{0}, n / parts);
  for (std::thread& w : workers) w.join();
}

}  // namespace

Status FilterOptions::Check() const {
  if (neighbours < 1 || neighbours > 100) return InvalidArgumentError("outlier neighbours must be 1..100");
  if (!(std_ratio > 0 && std_ratio <= 100))
    return InvalidArgumentError("outlier std ratio must be in (0, 100]");
  if (!(radius_mm >= 0.01 && radius_mm <= 100))
    return InvalidArgumentError("outlier radius must be 0.01..100 mm");
  if (!(local_ratio >= 0 && local_ratio <= 100))
    return InvalidArgumentError("outlier local ratio must be 0 (off) or in (0, 100]");
  if (!(thin_voxel_mm == 0 || (thin_voxel_mm >= 0.01 && thin_voxel_mm <= 100)))
    return InvalidArgumentError("thinning voxel must be 0 (off) or 0.01..100 mm");
  if (threads < 0 || threads > 256) return InvalidArgumentError("threads must be 0..256");
  return Status::Ok();
}

Result<PointCloud> FilterCloud(const PointCloud& cloud, const FilterOptions& options,
                               FilterSummary* summary) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  if (cloud.size() >= (size_t{1} << 32)) return InvalidArgumentError("cloud too large (2^32 points or more)");
  for (size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.points[i].position_in_table.allFinite())
      return InvalidArgumentError("cloud point #" + std::to_string(i) + " is not finite");
  }
  const int threads = options.threads > 0
                          ? options.threads
                          : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  FilterSummary local;
  FilterSummary& s = summary != nullptr ? *summary : local;
  s = FilterSummary{};
  s.input = cloud.size();
  PointCloud out;
  out.scan = cloud.scan;

  std::vector<uint32_t> kept;
  kept.reserve(cloud.size());
  if (options.remove_outliers && cloud.size() > static_cast<size_t>(options.neighbours)) {
    std::vector<uint32_t> all(cloud.size());
    std::iota(all.begin(), all.end(), uint32_t{0});
    const internal::CellIndex grid(cloud, all, options.radius_mm);
    const auto k = static_cast<size_t>(options.neighbours);
    const float r = static_cast<float>(options.radius_mm);
    // The k nearest other points within the radius of point i, nearest first: (squared distance, index).
    auto nearest = [&](size_t i, std::vector<std::pair<float, uint32_t>>* near) {
      const Eigen::Vector3f& p = cloud.points[i].position_in_table;
      near->clear();
      grid.ForEachNear(p, [&](uint32_t j) {
        if (j == i) return;
        const float e = (cloud.points[j].position_in_table - p).squaredNorm();
        if (e <= r * r) near->emplace_back(e, j);
      });
      const size_t found = std::min(k, near->size());
      std::partial_sort(near->begin(), near->begin() + static_cast<std::ptrdiff_t>(found), near->end());
      near->resize(found);
    };
    std::vector<float> mean(cloud.size());
    ParallelFor(cloud.size(), threads, [&](size_t begin, size_t end) {
      std::vector<std::pair<float, uint32_t>> near;
      for (size_t i = begin; i < end; ++i) {
        nearest(i, &near);
        float sum = static_cast<float>(k - near.size()) * r;
        for (const auto& [e, j] : near) sum += std::sqrt(e);
        mean[i] = sum / static_cast<float>(k);
      }
    });
    double m = 0, m2 = 0;
    for (float v : mean) m += v;
    m /= static_cast<double>(mean.size());
    for (float v : mean) m2 += (v - m) * (v - m);
    const double sd = std::sqrt(m2 / static_cast<double>(mean.size()));
    s.outlier_threshold_mm = m + options.std_ratio * sd;
    // Over the threshold but no sparser than its neighbours (filter.h): at least half of `neighbours` found
    // within the radius, and its mean distance at most local_ratio x the median of theirs.
    auto as_sparse_as_around = [&](size_t i) {
      if (options.local_ratio <= 0) return false;
      std::vector<std::pair<float, uint32_t>> near;
      nearest(i, &near);
      if (2 * near.size() < k) return false;
      std::vector<float> theirs(near.size());
      for (size_t n = 0; n < near.size(); ++n) theirs[n] = mean[near[n].second];
      std::nth_element(theirs.begin(), theirs.begin() + static_cast<std::ptrdiff_t>(theirs.size() / 2), theirs.end());
      return mean[i] <= options.local_ratio * theirs[theirs.size() / 2];
    };
    for (size_t i = 0; i < cloud.size(); ++i) {
      if (mean[i] <= s.outlier_threshold_mm) {
        kept.push_back(static_cast<uint32_t>(i));
      } else if (as_sparse_as_around(i)) {
        kept.push_back(static_cast<uint32_t>(i));
        ++s.kept_sparse;
      }
    }
    s.outliers = cloud.size() - kept.size();
  } else {
    for (size_t i = 0; i < cloud.size(); ++i) kept.push_back(static_cast<uint32_t>(i));
  }

  if (options.thin_voxel_mm > 0) {
    // The best point of each voxel, then the kept ones in their original order (the index only keys).
    const internal::CellIndex cells(cloud, {}, options.thin_voxel_mm);
    std::unordered_map<uint64_t, uint32_t> best;
    best.reserve(kept.size() / 2 + 1);
    for (uint32_t i : kept) {
      auto [it, inserted] = best.emplace(cells.Key(cloud.points[i].position_in_table), i);
      if (!inserted && cloud.points[i].quality > cloud.points[it->second].quality) it->second = i;
    }
    std::vector<uint32_t> thinned;
    thinned.reserve(best.size());
    for (const auto& [key, i] : best) thinned.push_back(i);
    std::sort(thinned.begin(), thinned.end());
    s.thinned = kept.size() - thinned.size();
    kept.swap(thinned);
  }
  out.points.reserve(kept.size());
  for (uint32_t i : kept) out.points.push_back(cloud.points[i]);
  s.output = out.size();
  return out;
}

}  // namespace rotoscan::cloud
