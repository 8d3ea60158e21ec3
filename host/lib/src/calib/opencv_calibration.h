// Private to the calib module: what the checkerboard (camera_calibration.cc) and ChArUco (charuco.cc)
// camera calibrations share: OpenCV's calibrateCamera on known correspondences and its result unpacked
// into a CameraCalibration, the pose conversion, and which files are images.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/core/status.h"

namespace rotoscan::calib::internal {

// png, jpg, jpeg, bmp, tif, tiff (any case).
bool IsImageFile(const std::filesystem::path& path);

// cam_from_target from OpenCV's rotation vector and translation.
Eigen::Isometry3d PoseFromRvecTvec(const cv::Mat& rvec, const cv::Mat& tvec);

// cv::calibrateCamera on view v's corners_in_target[v][i] (mm, target frame) seen at corner_pixels[v][i]
// (at least 4 per view, both lists the same size). Fills camera, rms_px, views, per_view_rms_px,
// cam_from_target, corner_pixels and the standard deviations. kNotConverged when OpenCV fails or gives an
// invalid camera.
Result<CameraCalibration> CalibrateCorrespondences(
    const std::vector<std::vector<Eigen::Vector3d>>& corners_in_target,
    const std::vector<std::vector<Eigen::Vector2d>>& corner_pixels, const std::vector<std::string>& view_names,
    int image_width, int image_height, bool fix_aspect_ratio, bool zero_tangential);

}  // namespace rotoscan::calib::internal
