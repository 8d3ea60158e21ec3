// The two lasers' clouds in one frame: how far they disagree where both saw the surface, and one cloud
// without duplicate layers.
//
// Disagreement: for every left-laser point with a normal, the nearest right-laser point within
// `overlap_radius_mm`, and the signed distance of that point from the left point's tangent plane. The mean
// of it is the systematic offset between the two shells (a bad laser plane or table axis calibration: the
// "double shell" of bq Horus); the RMS about the mean is the noise. Points without a normal contribute
// their point-to-point distance (unsigned) to a separate figure.
//
// Merge: a voxel grid of `voxel_mm`; each voxel is owned by the laser with the larger summed quality over
// the voxel and its 26 neighbours (so a surface lying across a voxel border gets one owner), and a point is
// dropped when the other laser owns its voxel and has a point within `overlap_radius_mm`. Each region of the
// surface is then represented by one laser, so an offset between the lasers cannot show as two parallel
// layers, and nothing is averaged across lasers (averaging would blur both where they disagree).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "rotoscan/cloud/cloud.h"

namespace rotoscan::cloud {

struct MergeOptions {
  double voxel_mm = 1.0;
  double overlap_radius_mm = 2.0;  // larger than the offsets worth reporting
  Status Check() const;
};

struct LaserDisagreement {
  size_t pairs = 0;           // left points with a right neighbour within the radius
  double mean_signed_mm = 0;  // systematic offset of the right shell along the left normals
  double rms_mm = 0;          // RMS of the signed distances (offset included)
  double median_abs_mm = 0;
  double mean_unsigned_mm = 0;  // point-to-point, for pairs whose left point has no normal
  // Color of the pairs' points: luminance ((r + g + b) / 3, levels of 255), right minus left.
  double color_mean_signed = 0;
  double color_mean_abs = 0;
};

struct MergeReport {
  size_t left_in = 0, right_in = 0;
  size_t left_out = 0, right_out = 0;
  size_t shared_voxels = 0;  // voxels seen by both lasers
  LaserDisagreement disagreement;
};

// Measures the disagreement of the laser-0 and laser-1 points of `cloud`.
LaserDisagreement MeasureLaserDisagreement(const PointCloud& cloud, double overlap_radius_mm);

// The same between any two sets of points of `cloud` (indices; e.g. two placements): `left` plays the
// left laser (its normals), `right` the right laser.
LaserDisagreement MeasureDisagreement(const PointCloud& cloud, const std::vector<uint32_t>& left,
                                      const std::vector<uint32_t>& right, double overlap_radius_mm);

// The merged cloud (points keep their laser id). `report` may be null. Options must pass Check().
PointCloud MergeLasers(const PointCloud& cloud, const MergeOptions& options, MergeReport* report);

}  // namespace rotoscan::cloud
