// The scanner's geometry as one value: what calibration produces, what the virtual scanner renders from
// (its truth), and what processing consumes.
//
// Frames (DESIGN.md "Names and frames"): laser planes and the table axis are in the camera frame, mm.
// The table frame has its origin on the rotation axis at the table top and z up the axis; a point seen at
// table angle theta is brought to the world frame (= table at angle 0) by rotating it by -theta about the
// axis (the table turned by +theta, right hand about axis_direction). The paper's eq. 7 is the special case
// of an axis along the calibration object's z.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/persistence.hpp>

#include "rotoscan/core/status.h"
#include "rotoscan/geometry/camera.h"
#include "rotoscan/geometry/plane.h"

namespace rotoscan::geometry {

enum class LaserId : int { kLeft = 0, kRight = 1 };
const char* LaserName(LaserId id);  // "left" / "right"

struct Rig {
  CameraModel camera;
  Plane laser_plane[2];                             // indexed by LaserId, camera frame
  Eigen::Vector3d axis_point_in_cam{0, 0, 0};       // the table top's centre (a point on the axis), mm
  Eigen::Vector3d axis_direction_in_cam{0, -1, 0};  // unit, pointing up out of the table
  double step_angle_rad = 0.0;                      // table rotation per step, radians (0: unknown)
  // The lamp of the natural frames, when calibrated (pipeline/lamp.h): a far Lambertian lamp fixed to the
  // camera, as the direction towards it (camera frame) times its diffuse / ambient ratio (pipeline/color.h).
  std::optional<Eigen::Vector3d> lamp_in_cam;

  const Plane& laser(LaserId id) const { return laser_plane[static_cast<int>(id)]; }
  Plane& laser(LaserId id) { return laser_plane[static_cast<int>(id)]; }

  // OK, or kInvalidArgument naming the field (camera, non-unit normals, zero axis, ...).
  Status Validate() const;

  // cam_from_table at table angle 0: origin at axis_point_in_cam, z along axis_direction_in_cam, x towards
  // the camera's x as far as possible.
  Eigen::Isometry3d CamFromTable() const;

  // world_from_cam at a table angle (radians): maps a point measured in the camera frame when the table
  // stood at `table_angle` to the world (= table at angle 0) frame.
  Eigen::Isometry3d WorldFromCamAtAngle(double table_angle) const;
};

// calib.yaml: OpenCV FileStorage YAML (readable by any OpenCV user). Keys: image_width, image_height, K
// (3x3), distortion (5x1: k1 k2 p1 p2 k3), laser_left_plane / laser_right_plane (4x1: nx ny nz d, camera
// frame), axis_point (3x1, camera frame, mm), axis_direction (3x1), step_angle_deg, and the DLT matrix P
// (3x4, paper eq. 3: K [I|0] since the camera frame is the reference), and, only when calibrated, lamp (3x1:
// Rig::lamp_in_cam; files without it read as before). Readers ignore unknown keys, so the
// calibration adds its report (WriteRigNodes into its own FileStorage, then its own keys).
Status WriteRigYaml(const std::filesystem::path& path, const Rig& rig);  // atomic
Result<Rig> ReadRigYaml(const std::filesystem::path& path);
// The same from YAML text (`name` for messages): kCorruptData or kInvalidArgument, never an exception
// or a hang (both through geometry/yaml.h, the one YAML reader).
Result<Rig> ParseRigYaml(const std::string& text, const std::string& name);
// The rig's keys (above) into an open FileStorage, and back from its root node.
void WriteRigNodes(cv::FileStorage& storage, const Rig& rig);
Result<Rig> ReadRigNodes(const cv::FileNode& root);
// The camera's keys alone (image_width, image_height, K, distortion: also camera.yaml's).
Result<CameraModel> ReadCameraNodes(const cv::FileNode& root);

}  // namespace rotoscan::geometry
