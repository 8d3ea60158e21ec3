// Private to the calib module: what the checkerboard (camera_calibration.cc) and ChArUco (charuco.cc)
// camera calibrations share: OpenCV's calibrateCamera on known correspondences and its result unpacked
// into a CameraCalibration, the pose conversion, and which files are images.
#pragma once

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/core/progress.h"
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
    const std::vector<std::vector<Eigen::Vector2d>>& corner_pixels,
    const std::vector<std::string>& view_names, int image_width, int image_height, bool fix_aspect_ratio,
    bool zero_tangential);

// The images of a calibration folder, as both camera calibrations read them: every image file of
// `directory` (sorted by name), read as 8-bit gray, all of one size, handed with its file name to
// `detect`, which keeps what it found and returns OK, or returns why the target is not in that image (the
// image is then listed in `rejected`). Errors: no such directory, a listing failure, no image files (the
// message asks for `min_views` views of `target`), images of different sizes, none readable, cancelled.
struct ImageFolder {
  int width = 0, height = 0;
  int files = 0, readable = 0;
  std::vector<std::string> rejected;  // "name: reason"
};
// "COLSxROWS" (or "COLSXROWS") as two positive ints; false on anything else, an overflow included.
bool ParseColsByRows(const std::string& text, int* cols, int* rows);

Result<ImageFolder> ReadImageFolder(
    const std::filesystem::path& directory, const std::string& target, int min_views,
    const std::string& progress_label, Progress* progress,
    const std::function<Status(const cv::Mat& gray, const std::string& name)>& detect);

}  // namespace rotoscan::calib::internal
