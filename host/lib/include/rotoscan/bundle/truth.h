// Ground truth that the virtual scanner writes beside a bundle, under truth/, and readers for it so that
// calibration and processing can be checked against it:
//
//   truth/rig.yaml          the exact rig (geometry::WriteRigYaml / ReadRigYaml, calib.yaml keys)
//   truth/object.ply        the scene's object meshes in the table frame (binary little-endian PLY:
//                           vertex float x y z (mm) + uchar red green blue, face list uchar/int
//                           vertex_indices); the table top itself is not included
//   truth/lines/<stem>.csv  one per laser frame (<stem> = frame file name without directory and
//                           extension, e.g. s0012_left): the true sub-pixel centre of the laser line for
//                           every image row where it is visible (seen by the camera and not shadowed from
//                           the laser), one line per crossing (a row may have several):
//                             # rotoscan line truth 1
//                             row,column,x_cam,y_cam,z_cam,x_world,y_world,z_world,object
//                           row = integer image row (pixel centre), column = sub-pixel column where the
//                           distorted projection of (laser plane ∩ surface) crosses that row, the 3D point
//                           in the camera frame and in the world frame (= table frame at angle 0), mm, and
//                           object = 0 for the table top, 1.. for the scene's objects in order.
//   truth/poses.csv         calibration bundles: cam_from_target for every (pose, step):
//                             pose,step,r00,r01,r02,r10,r11,r12,r20,r21,r22,tx,ty,tz   (mm)
//   truth/table_angles.csv  bundles with a table (scan, calibration on the table): the commanded table
//                           angle (the one in bundle.json) and the true one of every (pose, step); they
//                           differ when the virtual table slips (sim/simulate.h):
//                             pose,step,commanded_deg,true_deg
//   truth/placement.csv     scans: where this placement put the object (bundle.h "placement"), as
//                           table_from_reference: the reference frame is the table frame of placement 0,
//                           so the true transform that aligns placement k's cloud onto placement 0's is
//                           table_from_reference(0) * table_from_reference(k)^-1:
//                             # rotoscan placement 1 (table_from_reference, mm)
//                             placement,r00,r01,r02,r10,r11,r12,r20,r21,r22,tx,ty,tz
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/core/status.h"

namespace rotoscan::bundle {

inline constexpr std::size_t kMaxTruthMeshVertices = 50'000'000;
inline constexpr std::size_t kMaxTruthMeshFaces = 100'000'000;

struct TruthMesh {
  std::vector<Eigen::Vector3f> vertices;              // table frame, mm
  std::vector<std::array<uint8_t, 3>> colors;         // per vertex RGB (empty or same size as vertices)
  std::vector<Eigen::Vector3i> faces;                 // indices into vertices
};

struct LinePoint {
  int row = 0;                                               // image row, px
  double column = 0.0;                                       // sub-pixel column of the true line, px
  Eigen::Vector3d point_in_cam = Eigen::Vector3d::Zero();    // the surface point, camera frame, mm
  Eigen::Vector3d point_in_world = Eigen::Vector3d::Zero();  // the same in the world frame, mm
  int object = 0;                                            // 0: table top, 1..: scene objects
};

struct TargetPose {
  int pose = 0;
  int step = 0;
  Eigen::Isometry3d cam_from_target = Eigen::Isometry3d::Identity();  // mm
};

struct TableAngle {
  int pose = -1;
  int step = 0;
  double commanded_rad = 0.0;  // the angle the bundle records
  double true_rad = 0.0;       // the angle the table stood at (a slipping table)
};

struct PlacementTruth {
  int placement = 0;
  Eigen::Isometry3d table_from_reference = Eigen::Isometry3d::Identity();
};

// Binary little-endian PLY with vertex colors. The reader also accepts ASCII PLY and bounds all counts.
Status WritePlyMesh(const std::filesystem::path& path, const TruthMesh& mesh);  // atomic
Result<TruthMesh> ReadPlyMesh(const std::filesystem::path& path);

// truth/lines/<stem>.csv of a frame record.
std::filesystem::path LineTruthPath(const std::filesystem::path& bundle_dir, const FrameRecord& frame);
Status WriteLineTruth(const std::filesystem::path& path, const std::vector<LinePoint>& points);  // atomic
Result<std::vector<LinePoint>> ReadLineTruth(const std::filesystem::path& path);

Status WriteTargetPoses(const std::filesystem::path& path, const std::vector<TargetPose>& poses);  // atomic
Result<std::vector<TargetPose>> ReadTargetPoses(const std::filesystem::path& path);

Status WriteTableAngles(const std::filesystem::path& path, const std::vector<TableAngle>& angles);  // atomic
Result<std::vector<TableAngle>> ReadTableAngles(const std::filesystem::path& path);

Status WritePlacementTruth(const std::filesystem::path& path, const PlacementTruth& placement);  // atomic
Result<PlacementTruth> ReadPlacementTruth(const std::filesystem::path& path);

// Convenience for a read bundle: the line truth of one frame / truth/rig.yaml path / truth/object.ply.
Result<std::vector<LinePoint>> ReadLineTruth(const Bundle& bundle, const FrameRecord& frame);
inline std::filesystem::path TruthRigPath(const std::filesystem::path& bundle_dir) {
  return bundle_dir / "truth" / "rig.yaml";
}
inline std::filesystem::path TruthMeshPath(const std::filesystem::path& bundle_dir) {
  return bundle_dir / "truth" / "object.ply";
}
inline std::filesystem::path TruthPosesPath(const std::filesystem::path& bundle_dir) {
  return bundle_dir / "truth" / "poses.csv";
}
inline std::filesystem::path TruthPlacementPath(const std::filesystem::path& bundle_dir) {
  return bundle_dir / "truth" / "placement.csv";
}
inline std::filesystem::path TruthTableAnglesPath(const std::filesystem::path& bundle_dir) {
  return bundle_dir / "truth" / "table_angles.csv";
}

}  // namespace rotoscan::bundle
