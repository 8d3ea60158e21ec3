// A cloud's points bucketed by grid cell (private to the library: cloud's merge.cc and filter.cc, pipeline's
// evaluate.cc).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <type_traits>
#include <unordered_map>
#include <utility>
#include <vector>

#include "rotoscan/cloud/cloud.h"

namespace rotoscan::cloud::internal {

// Points bucketed by cell: indices sorted by cell key, and the range of each key.
class CellIndex {
 public:
  CellIndex(const PointCloud& cloud, const std::vector<uint32_t>& subset, double cell) : cell_(cell) {
    entries_.reserve(subset.size());
    for (uint32_t i : subset) entries_.push_back({Key(cloud.points[i].position_in_table), i});
    std::sort(entries_.begin(), entries_.end());
    ranges_.reserve(entries_.size() / 2 + 1);
    for (size_t k = 0; k < entries_.size();) {
      size_t e = k;
      while (e < entries_.size() && entries_[e].first == entries_[k].first) ++e;
      ranges_[entries_[k].first] = {k, e};
      k = e;
    }
  }
  uint64_t Key(const Eigen::Vector3f& p, int dx = 0, int dy = 0, int dz = 0) const {
    auto c = [&](float v, int d) {
      // Clamped before the conversion: a point at 1e30 mm (an absurd calibration) must not overflow it.
      const double cell = std::max(-1e15, std::min(1e15, std::floor(static_cast<double>(v) / cell_)));
      return static_cast<uint64_t>(static_cast<int64_t>(cell) + d + (1 << 20)) & 0x1FFFFF;
    };
    return c(p.x(), dx) | (c(p.y(), dy) << 21) | (c(p.z(), dz) << 42);
  }
  // Calls f(index) for every point in the 3 x 3 x 3 cells around p's (so every point within one cell of p).
  // When f returns bool, false stops the search.
  template <typename F>
  void ForEachNear(const Eigen::Vector3f& p, F f) const {
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          auto it = ranges_.find(Key(p, dx, dy, dz));
          if (it == ranges_.end()) continue;
          for (size_t k = it->second.first; k < it->second.second; ++k) {
            if constexpr (std::is_same_v<decltype(f(uint32_t{})), bool>) {
              if (!f(entries_[k].second)) return;
            } else {
              f(entries_[k].second);
            }
          }
        }
  }

 private:
  double cell_;
  std::vector<std::pair<uint64_t, uint32_t>> entries_;
  std::unordered_map<uint64_t, std::pair<size_t, size_t>> ranges_;
};

}  // namespace rotoscan::cloud::internal
