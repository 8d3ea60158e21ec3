// The colored point cloud of a scan and its file, cloud.ply (DESIGN.md "Files"): binary little-endian
// PLY, one vertex per point with x y z (float, mm, table frame), nx ny nz (float, unit, zero when
// unknown), red green blue (uchar), laser (uchar: 0 left, 1 right), step (int: table step index) and
// quality (float, 0..1), and in merged clouds of several placements (pipeline/placements.h) placement
// (uchar: the index of the scan the point came from; absent means 0). Two optional header comments say where
// the camera was (ScanGeometry): `comment rotoscan camera_at_step0 X Y Z` (mm, table frame) and `comment
// rotoscan step_deg S`; a merged cloud adds one per placement: `comment rotoscan placement K camera_at_step0
// X Y Z step_deg S merged_from_table M00 M01 M02 M03 M10 ... M23` (its camera path in its own table frame and
// its pose in the merged frame, the top 3 x 4 of the matrix row by row). A malformed camera comment is
// ignored (no path).
//
// The reader is hardened (STYLE.md §9): every count read from the file is bounded by the bytes that are
// really there before anything is allocated, a truncated or malformed file is kCorruptData naming the
// file, and unknown properties are skipped. It reads binary_little_endian and ascii PLY vertex data
// with any scalar property types (so clouds from other tools load too); x, y, z are required.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rotoscan/core/status.h"

namespace rotoscan::cloud {

struct CloudPoint {
  Eigen::Vector3f position_in_table = Eigen::Vector3f::Zero();  // mm
  Eigen::Vector3f normal = Eigen::Vector3f::Zero();             // unit, or zero when unknown
  std::array<uint8_t, 3> color{};                               // red, green, blue
  uint8_t laser = 0;                                            // geometry::LaserId as a number
  int32_t step = 0;                                             // table step index
  float quality = 0;                                            // 0..1
  uint8_t placement = 0;  // which placement's scan (pipeline/placements.h), 0 in a single scan
};

// Where the camera was when each point was seen: the table frame's z is the rotation axis, so the camera
// at table step s is `camera_at_step0` turned by s * step_rad about z (a point's sensor ray runs from it to
// the camera). Meshing weights and orients by it; unknown for clouds from other tools.
struct ScanGeometry {
  bool known = false;
  Eigen::Vector3d camera_at_step0 = Eigen::Vector3d::Zero();  // mm, table frame
  double step_rad = 0.0;                                      // signed turn per step index
  Eigen::Vector3d CameraAtStep(int step) const;
  // A merged cloud of several placements (pipeline/placements.h), indexed by CloudPoint::placement: each
  // scan's camera path in its own table frame and where that frame lies in the merged one (placement 0's
  // is the identity, and camera_at_step0 / step_rad above are its own). Empty for one scan.
  struct Placement {
    Eigen::Vector3d camera_at_step0 = Eigen::Vector3d::Zero();
    double step_rad = 0.0;
    Eigen::Isometry3d merged_from_table = Eigen::Isometry3d::Identity();
  };
  std::vector<Placement> placements;
  // The camera of a point of `placement` seen at table step `step`, in the cloud's frame (CameraAtStep when
  // the cloud has no placements or not that one).
  Eigen::Vector3d CameraAt(int placement, int step) const;
};

struct PointCloud {
  std::vector<CloudPoint> points;
  ScanGeometry scan;
  size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
};

// Writes `cloud` to `path` atomically (never a partial file).
Status WritePly(const std::filesystem::path& path, const PointCloud& cloud);
// The bytes WritePly writes, for tests and streaming.
std::string EncodePly(const PointCloud& cloud);

struct PlyReadOptions {
  size_t max_points = size_t{1} << 28;  // refuse files claiming more vertices than this
  size_t max_file_bytes = size_t{1} << 33;
};
Result<PointCloud> ReadPly(const std::filesystem::path& path, const PlyReadOptions& options = {});
// Decodes PLY bytes; `name` is used in error messages.
Result<PointCloud> DecodePly(const std::string& bytes, const std::string& name,
                             const PlyReadOptions& options = {});

}  // namespace rotoscan::cloud
