// Cleaning a scanned cloud before meshing: statistical outlier removal and voxel thinning.
//
// Statistical outlier removal (as in PCL's StatisticalOutlierRemoval and Open3D's remove_statistical_
// outliers, here over a grid): each point's mean distance to its `neighbours` nearest points, searched
// within `radius_mm` (a neighbour missing there counts as `radius_mm`, so a lone stray point scores the
// radius); over the whole cloud the mean m and standard deviation s of those; a point goes when its mean
// distance exceeds m + std_ratio * s, unless it is no sparser than the points around it (below). A scan's
// surface points have neighbours along their laser line a fraction of a millimetre apart; stray points
// (glints, reflections, the table's edge) have none.
//
// Sparse is not stray: where the laser lines cross the surface at a grazing angle (between the legs of an
// animal, inside a slot) consecutive lines and rows land far apart on the surface, and every point there
// scores above the whole cloud's m + std_ratio * s although it lies on the surface (on the demo's Spot, 2 %
// of the points, as accurate as the rest: median 0.011 mm from the true surface, and 1.5 % of the whole
// surface's coverage lost with them). So a point over the threshold is kept when at least half of its
// `neighbours` were found within `radius_mm` and its mean distance is at most `local_ratio` x the median of
// theirs (a density-relative test, as the local outlier factor of Breunig et al., SIGMOD 2000): its
// neighbourhood is sampled as sparsely as itself. A stray point off the surface is far from the surface
// points around it (their own distances are small) or has no neighbours at all, and still goes; one inside a
// sparsely scanned region, as far from the surface points as they are from each other, stays.
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
  double local_ratio = 1.5;    // over the threshold, kept if no sparser than this x its neighbours' (0: off)
  double thin_voxel_mm = 0.0;  // 0: no thinning
  int threads = 2;             // 0: all cores
  // kInvalidArgument naming the field (NaN fails too).
  Status Check() const;
};

struct FilterSummary {
  size_t input = 0;
  size_t outliers = 0;              // removed as outliers
  size_t kept_sparse = 0;           // over the threshold but kept as sparse as around them (local_ratio)
  double outlier_threshold_mm = 0;  // mean neighbour distance above which a point went
  size_t thinned = 0;               // removed by the thinning
  size_t output = 0;
};

// The cleaned cloud: outliers removed first, then thinning. Points keep their order; the camera path is
// kept. `summary` may be null.
Result<PointCloud> FilterCloud(const PointCloud& cloud, const FilterOptions& options,
                               FilterSummary* summary = nullptr);

}  // namespace rotoscan::cloud
