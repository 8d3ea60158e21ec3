#include "opencv_calibration.h"

#include <algorithm>
#include <cctype>
#include <cmath>

#include <opencv2/calib3d.hpp>

#include "rotoscan/core/check.h"

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

}  // namespace rotoscan::calib::internal
