#include "opencv_calibration.h"

#include <algorithm>
#include <charconv>
#include <cctype>
#include <cmath>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rotoscan/core/check.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/geometry/image_file.h"

namespace rotoscan::calib::internal {

bool IsImageFile(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".bmp" || ext == ".tif" || ext == ".tiff";
}

Eigen::Isometry3d PoseFromRvecTvec(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat r;
  cv::Rodrigues(rvec, r);
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) pose.linear()(i, j) = r.at<double>(i, j);
    pose.translation()(i) = tvec.at<double>(i);
  }
  return pose;
}

Result<CameraCalibration> CalibrateCorrespondences(
    const std::vector<std::vector<Eigen::Vector3d>>& corners_in_target,
    const std::vector<std::vector<Eigen::Vector2d>>& corner_pixels,
    const std::vector<std::string>& view_names, int image_width, int image_height, bool fix_aspect_ratio,
    bool zero_tangential) {
  const int views = static_cast<int>(corner_pixels.size());
  ROTOSCAN_CHECK(corners_in_target.size() == corner_pixels.size() &&
                 view_names.size() == corner_pixels.size());
  std::vector<std::vector<cv::Point3f>> object_points(static_cast<size_t>(views));
  std::vector<std::vector<cv::Point2f>> image_points(static_cast<size_t>(views));
  for (int v = 0; v < views; ++v) {
    const auto& target = corners_in_target[static_cast<size_t>(v)];
    const auto& pixels = corner_pixels[static_cast<size_t>(v)];
    ROTOSCAN_CHECK(pixels.size() == target.size() && pixels.size() >= 4)
        << "view " << v << ": " << pixels.size() << " pixels, " << target.size() << " corners";
    for (std::size_t i = 0; i < pixels.size(); ++i) {
      object_points[static_cast<size_t>(v)].emplace_back(static_cast<float>(target[i].x()),
                                                         static_cast<float>(target[i].y()),
                                                         static_cast<float>(target[i].z()));
      image_points[static_cast<size_t>(v)].emplace_back(static_cast<float>(pixels[i].x()),
                                                        static_cast<float>(pixels[i].y()));
    }
  }
  int flags = 0;
  if (fix_aspect_ratio) flags |= cv::CALIB_FIX_ASPECT_RATIO;
  if (zero_tangential) flags |= cv::CALIB_ZERO_TANGENT_DIST;
  cv::Mat k = cv::Mat::eye(3, 3, CV_64F);
  cv::Mat dist = cv::Mat::zeros(5, 1, CV_64F);
  std::vector<cv::Mat> rvecs, tvecs;
  cv::Mat std_intrinsics, std_extrinsics, per_view;
  double rms = 0.0;
  try {
    rms = cv::calibrateCamera(object_points, image_points, cv::Size(image_width, image_height), k, dist,
                              rvecs, tvecs, std_intrinsics, std_extrinsics, per_view, flags,
                              cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
  } catch (const cv::Exception& e) {
    return NotConvergedError("camera calibration failed: " + e.msg);
  }
  CameraCalibration out;
  out.camera.width = image_width;
  out.camera.height = image_height;
  out.camera.fx = k.at<double>(0, 0);
  out.camera.fy = k.at<double>(1, 1);
  out.camera.cx = k.at<double>(0, 2);
  out.camera.cy = k.at<double>(1, 2);
  for (int i = 0; i < 5; ++i) out.camera.distortion[static_cast<size_t>(i)] = dist.at<double>(i);
  if (!out.camera.Validate().ok() || !std::isfinite(rms)) {
    return NotConvergedError("camera calibration gave an invalid camera: " +
                             out.camera.Validate().ToString());
  }
  out.rms_px = rms;
  out.views = view_names;
  out.corner_pixels = corner_pixels;
  for (int v = 0; v < views; ++v) {
    out.per_view_rms_px.push_back(per_view.at<double>(v));
    out.cam_from_target.push_back(
        PoseFromRvecTvec(rvecs[static_cast<size_t>(v)], tvecs[static_cast<size_t>(v)]));
  }
  for (int i = 0; i < 4; ++i) out.intrinsics_std[static_cast<size_t>(i)] = std_intrinsics.at<double>(i);
  for (int i = 0; i < 5; ++i) out.distortion_std[static_cast<size_t>(i)] = std_intrinsics.at<double>(4 + i);
  return out;
}

bool ParseColsByRows(const std::string& text, int* cols, int* rows) {
  const char* const end = text.data() + text.size();
  const char* p = text.data();
  auto number = [&](int* value) {
    if (p == end || !std::isdigit(static_cast<unsigned char>(*p))) return false;  // no sign, no space
    const std::from_chars_result r = std::from_chars(p, end, *value);
    if (r.ec != std::errc()) return false;  // result_out_of_range: "4294967305" is not 9
    p = r.ptr;
    return true;
  };
  if (!number(cols) || p == end || (*p != 'x' && *p != 'X')) return false;
  ++p;
  return number(rows) && p == end;
}

Result<ImageFolder> ReadImageFolder(
    const std::filesystem::path& directory, const std::string& target, int min_views,
    const std::string& progress_label, Progress* progress,
    const std::function<Status(const cv::Mat& gray, const std::string& name)>& detect) {
  std::error_code ec;
  if (!std::filesystem::is_directory(directory, ec)) {
    return NotFoundError("image directory " + directory.string() + " does not exist");
  }
  std::vector<std::filesystem::path> files;
  for (const auto& entry : std::filesystem::directory_iterator(directory, ec)) {
    if (entry.is_regular_file() && IsImageFile(entry.path())) files.push_back(entry.path());
  }
  if (ec) return IoError("cannot list " + directory.string() + ": " + ec.message());
  std::sort(files.begin(), files.end());
  if (files.empty()) {
    return NotFoundError("no images (png, jpg, bmp, tif) in " + directory.string() + ": capture at least " +
                         std::to_string(min_views) + " views of the " + target);
  }
  ImageFolder folder;
  folder.files = static_cast<int>(files.size());
  ProgressScope scope(progress, progress_label, files.size());
  for (const auto& file : files) {
    if (scope.Cancelled()) return CancelledError("camera calibration cancelled");
    scope.Advance();
    // An unreadable file (a header declaring more pixels than allowed too) is skipped; the decoder's
    // messages come back in the status, never on stderr.
    Result<cv::Mat> decoded = geometry::ReadImageFile(file, geometry::ImageRead::kGray);
    cv::Mat image = decoded.ok() ? *decoded : cv::Mat();
    const std::string name = file.filename().string();
    if (image.empty()) {
      folder.rejected.push_back(name + ": unreadable image");
      ROTOSCAN_LOG(kWarning) << name << ": unreadable image, skipped";
      continue;
    }
    ++folder.readable;
    if (folder.width == 0) {
      folder.width = image.cols;
      folder.height = image.rows;
    } else if (image.cols != folder.width || image.rows != folder.height) {
      return InvalidArgumentError(name + " is " + std::to_string(image.cols) + "x" +
                                  std::to_string(image.rows) + " but the first image is " +
                                  std::to_string(folder.width) + "x" + std::to_string(folder.height) +
                                  ": all views must come from the same camera mode");
    }
    const Status found = detect(image, name);
    if (!found.ok()) {
      folder.rejected.push_back(name + ": " + found.message());
      ROTOSCAN_LOG(kInfo) << name << ": " << found.message();
    }
  }
  if (folder.readable == 0) {
    return CorruptDataError("none of the " + std::to_string(files.size()) + " image files in " +
                            directory.string() + " could be read");
  }
  return folder;
}

}  // namespace rotoscan::calib::internal
