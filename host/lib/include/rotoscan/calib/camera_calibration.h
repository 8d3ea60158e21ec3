// Camera intrinsics with lens distortion from checkerboard images (beyond the paper, which neglects
// distortion for its 20 degree lens). Corners: cv::findChessboardCorners + cv::cornerSubPix; intrinsics:
// cv::calibrateCamera (Zhang's method + Levenberg-Marquardt), which is also the initial value of the joint
// refinement (calib/refine.h).
//
// Frames and units: the board's frame has its origin at the first inner corner, x along the columns, y
// along the rows, z = 0 on the board; mm. Pixels as in geometry/camera.h.
#pragma once

#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"
#include "rotoscan/geometry/camera.h"

namespace rotoscan::calib {

struct CheckerboardPattern {
  int cols = 0;            // inner corners per row
  int rows = 0;            // inner corners per column
  double square_mm = 0.0;  // side of one square
  Status Check() const;
  // The inner corners in the board frame, row by row (OpenCV's order).
  std::vector<Eigen::Vector3d> CornersInTarget() const;
};

// Parses "COLSxROWS" (e.g. "9x6"); kInvalidArgument otherwise.
Result<CheckerboardPattern> ParsePattern(const std::string& text, double square_mm);

// The inner corners of the board in an 8-bit grey or BGR image, sub-pixel, in OpenCV's order; kNotFound
// when the whole board is not visible.
Result<std::vector<Eigen::Vector2d>> DetectCheckerboard(const cv::Mat& image,
                                                        const CheckerboardPattern& pattern);

struct CameraCalibrationOptions {
  CheckerboardPattern pattern;
  int min_views = 6;              // fewer views with the board found is an error saying what to capture
  bool fix_aspect_ratio = false;  // fx = fy (OpenCV's CALIB_FIX_ASPECT_RATIO)
  bool zero_tangential = false;   // p1 = p2 = 0
  Status Check() const;
};

struct CameraCalibration {
  geometry::CameraModel camera;
  double rms_px = 0.0;                  // reprojection RMS over all corners
  std::vector<std::string> views;       // image file names where the board was found
  std::vector<double> per_view_rms_px;  // same order as `views`
  std::vector<std::string> rejected;    // images without the board (or unreadable), with the reason
  std::vector<Eigen::Isometry3d> cam_from_target;           // per view
  std::vector<std::vector<Eigen::Vector2d>> corner_pixels;  // per view
  std::array<double, 4> intrinsics_std{};                   // fx fy cx cy, pixels (1 sigma)
  std::array<double, 5> distortion_std{};                   // k1 k2 p1 p2 k3
};

// From views already detected (all images of one size). kInvalidArgument when fewer than
// options.min_views; kNotConverged when OpenCV fails.
Result<CameraCalibration> CalibrateCamera(const std::vector<std::vector<Eigen::Vector2d>>& corner_pixels,
                                          const std::vector<std::string>& view_names, int image_width,
                                          int image_height, const CameraCalibrationOptions& options);

// Every image (png, jpg, jpeg, bmp, tif, tiff; sorted by name) in `directory`. Errors name the directory and
// say what to capture: empty or missing directory, no readable image, images of different sizes, the board
// found in too few images.
Result<CameraCalibration> CalibrateCameraFromDirectory(const std::filesystem::path& directory,
                                                       const CameraCalibrationOptions& options,
                                                       Progress* progress = nullptr);

// camera.yaml (OpenCV FileStorage YAML, atomic): image_width, image_height, K, distortion (the calib.yaml
// keys of geometry/rig.h), then rms_px, per_view_rms_px, views, intrinsics_std, distortion_std.
Status WriteCameraYaml(const std::filesystem::path& path, const CameraCalibration& calibration);
// Its camera model back (image_width, image_height, K, distortion; the other keys are information), through
// geometry/yaml.h's one YAML reader: kNotFound, kCorruptData or kInvalidArgument, never an exception or a
// hang. ParseCameraYaml: the same from text (`name` for messages).
Result<geometry::CameraModel> ReadCameraYaml(const std::filesystem::path& path);
Result<geometry::CameraModel> ParseCameraYaml(const std::string& text, const std::string& name);

}  // namespace rotoscan::calib
