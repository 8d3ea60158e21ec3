#include "rotoscan/geometry/rig.h"

#include <cmath>
#include <string>

#include <opencv2/core.hpp>

#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/geometry/yaml.h"

namespace rotoscan::geometry {

const char* LaserName(LaserId id) {
  return id == LaserId::kLeft ? "left" : "right";
}

namespace {

bool IsFinite(const Eigen::Vector3d& v) {
  return v.allFinite();
}

// Farther than any turntable rig: a calibration with such a value is corrupt (and overflows downstream).
constexpr double kMaxRigDistanceMm = 1e5;

Status ValidatePlane(const Plane& plane, const char* name) {
  if (!IsFinite(plane.normal) || !std::isfinite(plane.offset)) {
    return InvalidArgumentError(std::string(name) + " must be finite");
  }
  if (std::abs(plane.offset) > kMaxRigDistanceMm) {
    return InvalidArgumentError(std::string(name) + " offset " + std::to_string(plane.offset) +
                                " mm is beyond any turntable scanner (more than 100 m from the camera)");
  }
  if (std::abs(plane.normal.norm() - 1.0) > 1e-6) {
    return InvalidArgumentError(std::string(name) + " normal must have unit length, has " +
                                std::to_string(plane.normal.norm()));
  }
  return Status::Ok();
}

cv::Mat ToMat(const Eigen::Vector3d& v) {
  return (cv::Mat_<double>(3, 1) << v.x(), v.y(), v.z());
}

// Reads an n x 1 (or 1 x n) double matrix under `key`; names the key in every error.
Result<cv::Mat> ReadVector(const cv::FileNode& root, const char* key, int n) {
  const cv::FileNode node = root[key];
  if (node.empty()) return InvalidArgumentError(std::string("missing key '") + key + "'");
  cv::Mat m;
  try {
    // OpenCV allocates rows x cols as declared before it reads the data: bound them first (a fuzzed
    // 'rows' made it allocate 16 GB). Every matrix here is a small vector.
    if (node.isMap()) {
      const cv::FileNode rows = node["rows"], cols = node["cols"];
      if (!rows.isInt() || !cols.isInt() || static_cast<int>(rows) < 1 || static_cast<int>(cols) < 1 ||
          static_cast<int>(rows) > n || static_cast<int>(cols) > n) {
        return InvalidArgumentError(std::string("key '") + key + "' must be a matrix of " + std::to_string(n) +
                                    " numbers (its rows and cols are missing, not integers or too large)");
      }
    }
    node >> m;
  } catch (const cv::Exception& e) {
    return InvalidArgumentError(std::string("key '") + key + "' is not a matrix: " + e.msg);
  }
  if (m.empty() || static_cast<int>(m.total()) != n || m.channels() != 1) {
    return InvalidArgumentError(std::string("key '") + key + "' must hold " + std::to_string(n) + " numbers");
  }
  m.convertTo(m, CV_64F);
  return m.reshape(1, n);
}

}  // namespace

Status Rig::Validate() const {
  ROTOSCAN_RETURN_IF_ERROR(camera.Validate());
  ROTOSCAN_RETURN_IF_ERROR(ValidatePlane(laser_plane[0], "laser_left_plane"));
  ROTOSCAN_RETURN_IF_ERROR(ValidatePlane(laser_plane[1], "laser_right_plane"));
  if (!IsFinite(axis_point_in_cam)) return InvalidArgumentError("axis_point must be finite");
  if (axis_point_in_cam.norm() > kMaxRigDistanceMm) {
    return InvalidArgumentError("axis_point is " + std::to_string(axis_point_in_cam.norm()) +
                                " mm from the camera: beyond any turntable scanner (more than 100 m)");
  }
  if (!IsFinite(axis_direction_in_cam) || std::abs(axis_direction_in_cam.norm() - 1.0) > 1e-6) {
    return InvalidArgumentError("axis_direction must be a finite unit vector");
  }
  if (!std::isfinite(step_angle_rad) || std::abs(step_angle_rad) > DegToRad(360.0)) {
    return InvalidArgumentError("step_angle_deg must be finite and within one turn");
  }
  if (lamp_in_cam && (!IsFinite(*lamp_in_cam) || lamp_in_cam->norm() > 1e3)) {
    return InvalidArgumentError("lamp must be finite and below 1000 (direction times diffuse / ambient)");
  }
  return Status::Ok();
}

Eigen::Isometry3d Rig::CamFromTable() const {
  // x hint: the camera's x axis, unless the axis is (nearly) along it.
  Eigen::Vector3d hint = Eigen::Vector3d::UnitX();
  if (std::abs(axis_direction_in_cam.normalized().dot(hint)) > 0.9) hint = Eigen::Vector3d::UnitZ();
  return FrameFromOriginAndZ(axis_point_in_cam, axis_direction_in_cam, hint);
}

Eigen::Isometry3d Rig::WorldFromCamAtAngle(double table_angle) const {
  // A point fixed on the table, seen in the camera frame at angle theta, is the world point rotated by
  // +theta about the axis: point_in_cam = R(theta) * cam_from_world * point_in_world. Invert.
  const Eigen::Isometry3d cam_from_table = CamFromTable();
  const Eigen::Isometry3d turn = RotationAboutAxis(axis_point_in_cam, axis_direction_in_cam, table_angle);
  return cam_from_table.inverse() * turn.inverse();
}

void WriteRigNodes(cv::FileStorage& storage, const Rig& rig) {
  const CameraModel& c = rig.camera;
  storage << "image_width" << c.width << "image_height" << c.height;
  storage << "K" << (cv::Mat_<double>(3, 3) << c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
  storage << "distortion" << cv::Mat(5, 1, CV_64F, const_cast<double*>(c.distortion.data())).clone();
  // The paper's 3x4 matrix (eq. 3) with the camera frame as the reference frame: K [I | 0].
  storage << "P" << (cv::Mat_<double>(3, 4) << c.fx, 0, c.cx, 0, 0, c.fy, c.cy, 0, 0, 0, 1, 0);
  for (int i = 0; i < 2; ++i) {
    const Plane& plane = rig.laser_plane[i];
    storage << (i == 0 ? "laser_left_plane" : "laser_right_plane")
            << (cv::Mat_<double>(4, 1) << plane.normal.x(), plane.normal.y(), plane.normal.z(), plane.offset);
  }
  storage << "axis_point" << ToMat(rig.axis_point_in_cam);
  storage << "axis_direction" << ToMat(rig.axis_direction_in_cam);
  storage << "step_angle_deg" << RadToDeg(rig.step_angle_rad);
  if (rig.lamp_in_cam) storage << "lamp" << ToMat(*rig.lamp_in_cam);
}

Result<CameraModel> ReadCameraNodes(const cv::FileNode& root) {
  CameraModel camera;
  if (root["image_width"].empty() || root["image_height"].empty()) {
    return InvalidArgumentError("missing key 'image_width' or 'image_height'");
  }
  camera.width = static_cast<int>(root["image_width"]);
  camera.height = static_cast<int>(root["image_height"]);
  ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat k, ReadVector(root, "K", 9));
  camera.fx = k.at<double>(0);
  camera.cx = k.at<double>(2);
  camera.fy = k.at<double>(4);
  camera.cy = k.at<double>(5);
  ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat dist, ReadVector(root, "distortion", 5));
  for (int i = 0; i < 5; ++i) camera.distortion[i] = dist.at<double>(i);
  return camera;
}

Result<Rig> ReadRigNodes(const cv::FileNode& root) {
  Rig rig;
  ROTOSCAN_ASSIGN_OR_RETURN(rig.camera, ReadCameraNodes(root));
  for (int i = 0; i < 2; ++i) {
    ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat plane,
                              ReadVector(root, i == 0 ? "laser_left_plane" : "laser_right_plane", 4));
    rig.laser_plane[i].normal =
        Eigen::Vector3d(plane.at<double>(0), plane.at<double>(1), plane.at<double>(2));
    rig.laser_plane[i].offset = plane.at<double>(3);
  }
  ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat point, ReadVector(root, "axis_point", 3));
  ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat direction, ReadVector(root, "axis_direction", 3));
  rig.axis_point_in_cam = Eigen::Vector3d(point.at<double>(0), point.at<double>(1), point.at<double>(2));
  rig.axis_direction_in_cam =
      Eigen::Vector3d(direction.at<double>(0), direction.at<double>(1), direction.at<double>(2));
  if (root["step_angle_deg"].empty()) return InvalidArgumentError("missing key 'step_angle_deg'");
  rig.step_angle_rad = DegToRad(static_cast<double>(root["step_angle_deg"]));
  if (!root["lamp"].empty()) {
    ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat lamp, ReadVector(root, "lamp", 3));
    rig.lamp_in_cam = Eigen::Vector3d(lamp.at<double>(0), lamp.at<double>(1), lamp.at<double>(2));
  }
  ROTOSCAN_RETURN_IF_ERROR(rig.Validate());
  return rig;
}

Status WriteRigYaml(const std::filesystem::path& path, const Rig& rig) {
  ROTOSCAN_RETURN_IF_ERROR(rig.Validate().WithContext("refusing to write " + path.string()));
  // Written to memory first: FileStorage does not report a failed write (a full disk).
  std::string text;
  try {
    cv::FileStorage storage(".yaml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY |
                                  cv::FileStorage::FORMAT_YAML);
    if (!storage.isOpened()) return InternalError("cannot start the YAML of " + path.string());
    WriteRigNodes(storage, rig);
    text = storage.releaseAndGetString();
  } catch (const cv::Exception& e) {
    return IoError("writing " + path.string() + ": " + e.msg);
  }
  return WriteFileAtomically(path, text);
}

Result<Rig> ParseRigYaml(const std::string& text, const std::string& name) {
  Rig rig;
  ROTOSCAN_RETURN_IF_ERROR(ReadYamlText(text, name, [&](const cv::FileNode& root) -> Status {
    ROTOSCAN_ASSIGN_OR_RETURN(rig, ReadRigNodes(root));
    return Status::Ok();
  }));
  return rig;
}

Result<Rig> ReadRigYaml(const std::filesystem::path& path) {
  Rig rig;
  ROTOSCAN_RETURN_IF_ERROR(ReadYamlFile(path, "calibration file", [&](const cv::FileNode& root) -> Status {
    ROTOSCAN_ASSIGN_OR_RETURN(rig, ReadRigNodes(root));
    return Status::Ok();
  }));
  return rig;
}

}  // namespace rotoscan::geometry
