// Cleaning a scanned cloud before meshing: statistical outlier removal and voxel thinning.
//
// Statistical outlier removal (as in PCL's StatisticalOutlierRemoval and Open3D's remove_statistical_
// outliers, here over a grid): each point's mean distance to its `neighbours` nearest points, searched
// within `radius_mm` (a neighbour missing there counts as `radius_mm`, so a lone stray point scores the
// radius); over the whole cloud the mean m and standard deviation s of those; a point goes when its mean
// distance exceeds m + std_ratio * s. A scan's surface points have neighbours along their laser line a
// fraction of a millimetre apart; stray points (glints, reflections, the table's edge) have none.
//
// Voxel thinning: one point per cube of `voxel_mm` (the one of highest quality, so that its laser, table
// step and normal stay its own: meshing uses them). Off by default.
#pragma once

#include <cstddef>

#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/status.h"

namespace rotoscan::cloud {

struct FilterOptions {
  bool remove_outliers = true;
  int neighbours = 8;
  double std_ratio = 3.0;
  double radius_mm = 1.0;      // the neighbour search's reach
  double thin_voxel_mm = 0.0;  // 0: no thinning
  int threads = 2;             // 0: all cores
  // kInvalidArgument naming the field (NaN fails too).
  Status Check() const;
};

struct FilterSummary {
  size_t input = 0;
  size_t outliers = 0;              // removed as outliers
  double outlier_threshold_mm = 0;  // mean neighbour distance above which a point went
  size_t thinned = 0;               // removed by the thinning
  size_t output = 0;
};

// The cleaned cloud: outliers removed first, then thinning. Points keep their order; the camera path is
// kept. `summary` may be null.
Result<PointCloud> FilterCloud(const PointCloud& cloud, const FilterOptions& options,
                               FilterSummary* summary = nullptr);

}  // namespace rotoscan::cloud
