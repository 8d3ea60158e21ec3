#include "rotoscan/calib/camera_calibration.h"

#include "opencv_calibration.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <string>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/persistence.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rotoscan/core/check.h"
#include "rotoscan/core/file.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/geometry/yaml.h"

namespace rotoscan::calib {

Status CheckerboardPattern::Check() const {
  if (cols < 3 || rows < 3) {
    return InvalidArgumentError("checkerboard pattern must have at least 3x3 inner corners, got " +
                                std::to_string(cols) + "x" + std::to_string(rows));
  }
  if (cols == rows) {
    return InvalidArgumentError("checkerboard pattern " + std::to_string(cols) + "x" + std::to_string(rows) +
                                " is square: its orientation is ambiguous; use a board with cols != rows");
  }
  if (!(square_mm > 0) || !std::isfinite(square_mm))
    return InvalidArgumentError("square size must be > 0 mm");
  return Status::Ok();
}

std::vector<Eigen::Vector3d> CheckerboardPattern::CornersInTarget() const {
  std::vector<Eigen::Vector3d> corners;
  corners.reserve(static_cast<std::size_t>(cols) * rows);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) corners.emplace_back(c * square_mm, r * square_mm, 0.0);
  }
  return corners;
}

Result<CheckerboardPattern> ParsePattern(const std::string& text, double square_mm) {
  CheckerboardPattern pattern;
  pattern.square_mm = square_mm;
  if (!internal::ParseColsByRows(text, &pattern.cols, &pattern.rows)) {
    return InvalidArgumentError("pattern '" + text + "' is not COLSxROWS (inner corners, e.g. 9x6)");
  }
  ROTOSCAN_RETURN_IF_ERROR(pattern.Check());
  return pattern;
}

Status CameraCalibrationOptions::Check() const {
  ROTOSCAN_RETURN_IF_ERROR(pattern.Check());
  if (min_views < 3) return InvalidArgumentError("min_views must be >= 3");
  return Status::Ok();
}

Result<std::vector<Eigen::Vector2d>> DetectCheckerboard(const cv::Mat& image,
                                                        const CheckerboardPattern& pattern) {
  ROTOSCAN_RETURN_IF_ERROR(pattern.Check());
  if (image.empty()) return InvalidArgumentError("empty image");
  if (image.depth() != CV_8U || (image.channels() != 1 && image.channels() != 3)) {
    return InvalidArgumentError("checkerboard detection needs an 8-bit grey or BGR image");
  }
  cv::Mat gray;
  if (image.channels() == 3) {
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  } else {
    gray = image;
  }
  std::vector<cv::Point2f> corners;
  const cv::Size size(pattern.cols, pattern.rows);
  if (!cv::findChessboardCorners(gray, size, corners,
                                 cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE)) {
    return NotFoundError("checkerboard " + std::to_string(pattern.cols) + "x" + std::to_string(pattern.rows) +
                         " not found (the whole board must be visible)");
  }
  cv::cornerSubPix(gray, corners, cv::Size(11, 11), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-3));
  std::vector<Eigen::Vector2d> out;
  out.reserve(corners.size());
  for (const auto& c : corners) out.emplace_back(c.x, c.y);
  return out;
}

Result<CameraCalibration> CalibrateCamera(const std::vector<std::vector<Eigen::Vector2d>>& corner_pixels,
                                          const std::vector<std::string>& view_names, int image_width,
                                          int image_height, const CameraCalibrationOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  ROTOSCAN_CHECK_EQ(corner_pixels.size(), view_names.size());
  ROTOSCAN_CHECK(image_width > 0 && image_height > 0) << "image size " << image_width << "x" << image_height;
  const int views = static_cast<int>(corner_pixels.size());
  if (views < options.min_views) {
    return InvalidArgumentError(
        "target found in only " + std::to_string(views) +
        " images: need >= " + std::to_string(options.min_views) +
        " (capture the whole board at different tilts and positions across the image)");
  }
  for (const auto& pixels : corner_pixels)
    ROTOSCAN_CHECK_EQ(pixels.size(), options.pattern.CornersInTarget().size());
  const std::vector<std::vector<Eigen::Vector3d>> corners_in_target(corner_pixels.size(),
                                                                    options.pattern.CornersInTarget());
  return internal::CalibrateCorrespondences(corners_in_target, corner_pixels, view_names, image_width,
                                            image_height, options.fix_aspect_ratio, options.zero_tangential);
}

Result<CameraCalibration> CalibrateCameraFromDirectory(const std::filesystem::path& directory,
                                                       const CameraCalibrationOptions& options,
                                                       Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  std::vector<std::vector<Eigen::Vector2d>> corners;
  std::vector<std::string> names;
  ROTOSCAN_ASSIGN_OR_RETURN(
      const internal::ImageFolder folder,
      internal::ReadImageFolder(directory, "checkerboard", options.min_views, "checkerboard", progress,
                                [&](const cv::Mat& gray, const std::string& name) -> Status {
                                  Result<std::vector<Eigen::Vector2d>> found =
                                      DetectCheckerboard(gray, options.pattern);
                                  if (!found.ok()) return found.status();
                                  corners.push_back(std::move(found).value());
                                  names.push_back(name);
                                  return Status::Ok();
                                }));
  if (static_cast<int>(corners.size()) < options.min_views) {
    return InvalidArgumentError(
        "target found in only " + std::to_string(corners.size()) + " of " + std::to_string(folder.files) +
        " images in " + directory.string() + ": need >= " + std::to_string(options.min_views) +
        " (check --pattern " + std::to_string(options.pattern.cols) + "x" +
        std::to_string(options.pattern.rows) +
        " counts inner corners, and capture the whole board, sharp, at different tilts)");
  }
  Result<CameraCalibration> result = CalibrateCamera(corners, names, folder.width, folder.height, options);
  if (result.ok()) result->rejected = folder.rejected;
  return result;
}

Status WriteCameraYaml(const std::filesystem::path& path, const CameraCalibration& calibration) {
  ROTOSCAN_RETURN_IF_ERROR(calibration.camera.Validate().WithContext("refusing to write " + path.string()));
  // Written to memory first: FileStorage does not report a failed write (a full disk).
  std::string text;
  try {
    cv::FileStorage fs(".yaml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY |
                                  cv::FileStorage::FORMAT_YAML);
    if (!fs.isOpened()) return InternalError("cannot start the YAML of " + path.string());
    const geometry::CameraModel& c = calibration.camera;
    fs << "image_width" << c.width << "image_height" << c.height;
    fs << "K" << (cv::Mat_<double>(3, 3) << c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
    fs << "distortion" << cv::Mat(std::vector<double>(c.distortion.begin(), c.distortion.end()), true);
    fs << "rms_px" << calibration.rms_px;
    fs << "per_view_rms_px" << cv::Mat(calibration.per_view_rms_px, true);
    fs << "views"
       << "[";
    for (const auto& v : calibration.views) fs << v;
    fs << "]";
    fs << "intrinsics_std"
       << cv::Mat(std::vector<double>(calibration.intrinsics_std.begin(), calibration.intrinsics_std.end()),
                  true);
    fs << "distortion_std"
       << cv::Mat(std::vector<double>(calibration.distortion_std.begin(), calibration.distortion_std.end()),
                  true);
    text = fs.releaseAndGetString();
  } catch (const cv::Exception& e) {
    return IoError("writing " + path.string() + ": " + e.msg);
  }
  return WriteFileAtomically(path, text);
}

namespace {

Status ReadValidCamera(const cv::FileNode& root, geometry::CameraModel* camera) {
  ROTOSCAN_ASSIGN_OR_RETURN(*camera, geometry::ReadCameraNodes(root));
  return camera->Validate();
}

}  // namespace

Result<geometry::CameraModel> ReadCameraYaml(const std::filesystem::path& path) {
  geometry::CameraModel camera;
  ROTOSCAN_RETURN_IF_ERROR(geometry::ReadYamlFile(
      path, "camera file", [&](const cv::FileNode& root) { return ReadValidCamera(root, &camera); }));
  return camera;
}

Result<geometry::CameraModel> ParseCameraYaml(const std::string& text, const std::string& name) {
  geometry::CameraModel camera;
  ROTOSCAN_RETURN_IF_ERROR(
      geometry::ReadYamlText(text, name, [&](const cv::FileNode& root) { return ReadValidCamera(root, &camera); }));
  return camera;
}

}  // namespace rotoscan::calib
