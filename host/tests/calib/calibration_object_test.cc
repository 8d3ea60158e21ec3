#include "rotoscan/calib/calibration_object.h"

#include <cmath>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "rotoscan/geometry/camera.h"
#include "rotoscan/geometry/rigid.h"

namespace rotoscan::calib {
namespace {

using geometry::DegToRad;
using ::testing::HasSubstr;

// A synthetic picture of the paper's object (60 mm faces, 10 mm squares): each face drawn by a homography
// from a finely sampled texture, the left face brighter than the right (they face the light differently),
// on a dark background, slightly blurred. The camera looks slightly down at the object, whose opening
// faces it, turned by `turn_deg` about its fold.
struct Picture {
  cv::Mat image;
  geometry::CameraModel camera;
  Eigen::Isometry3d cam_from_target = Eigen::Isometry3d::Identity();
};

Picture Draw(double turn_deg, bool right_face = true) {
  Picture p;
  p.camera.width = 680;
  p.camera.height = 500;
  p.camera.fx = p.camera.fy = 2000;
  p.camera.cx = 342;
  p.camera.cy = 247;
  // Target frame: z up the fold, faces y = 0 (x >= 0) and x = 0 (y >= 0); the opening (the +x +y
  // quadrant) faces the camera.
  const Eigen::Matrix3d cam_from_table =
      (Eigen::AngleAxisd(DegToRad(10.0), Eigen::Vector3d::UnitX()) *
       Eigen::Matrix3d((Eigen::Matrix3d() << 1, 0, 0, 0, 0, -1, 0, 1, 0).finished()));
  const Eigen::Matrix3d table_from_target =
      Eigen::AngleAxisd(DegToRad(-135.0 + turn_deg), Eigen::Vector3d::UnitZ()).toRotationMatrix();
  p.cam_from_target.linear() = cam_from_table * table_from_target;
  // The middle of the opening 330 mm in front of the camera.
  p.cam_from_target.translation() =
      Eigen::Vector3d(0, 0, 330) - p.cam_from_target.linear() * Eigen::Vector3d(15, 15, 30);

  const double kPxPerMm = 12.0, kFace = 60.0, kSquare = 10.0;
  const int texture_size = static_cast<int>(kFace * kPxPerMm);
  cv::Mat texture(texture_size, texture_size, CV_32F);
  for (int r = 0; r < texture_size; ++r) {
    for (int c = 0; c < texture_size; ++c) {
      const int i = static_cast<int>((c + 0.5) / kPxPerMm / kSquare);
      const int j = static_cast<int>((r + 0.5) / kPxPerMm / kSquare);
      texture.at<float>(r, c) = (i + j) % 2 == 1 ? 1.0f : 0.0f;
    }
  }
  cv::Mat image(p.camera.height, p.camera.width, CV_32F, cv::Scalar(8.0));
  for (int face = 0; face < (right_face ? 2 : 1); ++face) {
    // Texture pixel (c, r) -> (u, z) = (c, r) / kPxPerMm -> target point -> pixel.
    const Eigen::Vector3d along = face == 0 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    Eigen::Matrix3d k;
    k << p.camera.fx, 0, p.camera.cx, 0, p.camera.fy, p.camera.cy, 0, 0, 1;
    Eigen::Matrix3d h;
    h.col(0) = k * p.cam_from_target.linear() * along / kPxPerMm;
    h.col(1) = k * p.cam_from_target.linear() * Eigen::Vector3d::UnitZ() / kPxPerMm;
    // Texture pixel centres sit at (c + 0.5, r + 0.5) / kPxPerMm on the face.
    h.col(2) = h.col(0) * 0.5 + h.col(1) * 0.5 + k * p.cam_from_target.translation();
    cv::Mat h_cv(3, 3, CV_64F);
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) h_cv.at<double>(r, c) = h(r, c);
    }
    cv::Mat warped, mask;
    cv::warpPerspective(texture, warped, h_cv, image.size(), cv::INTER_AREA);
    cv::warpPerspective(cv::Mat(texture.size(), CV_32F, cv::Scalar(1.0)), mask, h_cv, image.size(),
                        cv::INTER_LINEAR);
    const double white = face == 0 ? 210.0 : 140.0, black = face == 0 ? 20.0 : 14.0;
    cv::Mat shaded = warped * (white - black) + black;
    image = image.mul(1.0 - mask) + shaded.mul(mask);
  }
  cv::GaussianBlur(image, image, cv::Size(0, 0), 0.7);
  image.convertTo(p.image, CV_8U);
  return p;
}

TEST(CalibrationObjectTest, FindsAndLabelsBothFacesSubPixel) {
  for (double turn : {-8.0}) {
    SCOPED_TRACE(turn);
    const Picture p = Draw(turn);
    Result<CalibrationObjectCorners> found = DetectCalibrationObject(p.image, CalibrationObjectSpec{});
    ASSERT_TRUE(found.ok()) << found.status().ToString();
    ASSERT_EQ(found->corners_in_target.size(), 50u);
    ASSERT_EQ(found->pixels.size(), 50u);
    double sum_sq = 0.0, worst = 0.0;
    for (std::size_t i = 0; i < 50; ++i) {
      const Eigen::Vector3d& x = found->corners_in_target[i];
      EXPECT_EQ(i < 25 ? x.y() : x.x(), 0.0);  // the y = 0 face first
      const double e = (p.camera.Project(p.cam_from_target * x) - found->pixels[i]).norm();
      sum_sq += e * e;
      worst = std::max(worst, e);
    }
    // A wrong label would be off by a whole square (tens of pixels). The errors left (no bias, 0.2 px RMS)
    // are mostly this picture's resampling; rendered frames are measured end to end (calibrate on bundles).
    EXPECT_LT(std::sqrt(sum_sq / 50), 0.3);
    EXPECT_LT(worst, 0.8);
    EXPECT_LT(found->dlt_rms_px, 0.5);
    EXPECT_EQ(found->faces[0].plane_in_target, Eigen::Vector4d(0, 1, 0, 0));
    EXPECT_EQ(found->faces[1].plane_in_target, Eigen::Vector4d(1, 0, 0, 0));
    // The face outline lies half a square inside the face: its first corner projects from (55, 0, 5).
    const Eigen::Vector2d expected = p.camera.Project(p.cam_from_target * Eigen::Vector3d(55, 0, 5));
    double nearest = 1e9;
    for (const auto& q : found->faces[0].outline) nearest = std::min(nearest, (q - expected).norm());
    EXPECT_LT(nearest, 1.0);
  }
}

TEST(CalibrationObjectTest, SaysWhatToCaptureWhenAFaceIsMissing) {
  const Picture p = Draw(0.0, /*right_face=*/false);
  Result<CalibrationObjectCorners> found = DetectCalibrationObject(p.image, CalibrationObjectSpec{});
  ASSERT_FALSE(found.ok());
  EXPECT_EQ(found.status().code(), StatusCode::kNotFound);
  EXPECT_THAT(found.status().message(), HasSubstr("only one face"));
  found = DetectCalibrationObject(cv::Mat(300, 400, CV_8U, cv::Scalar(0)), CalibrationObjectSpec{});
  ASSERT_FALSE(found.ok());
  EXPECT_THAT(found.status().message(), HasSubstr("no face"));
}

TEST(CalibrationObjectTest, RejectsBadImagesAndSpecs) {
  EXPECT_EQ(DetectCalibrationObject(cv::Mat(), CalibrationObjectSpec{}).status().code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(DetectCalibrationObject(cv::Mat(10, 10, CV_32F), CalibrationObjectSpec{}).status().code(),
            StatusCode::kInvalidArgument);
  CalibrationObjectSpec bad;
  bad.corners_per_side = 1;
  EXPECT_EQ(DetectCalibrationObject(cv::Mat(10, 10, CV_8U), bad).status().code(),
            StatusCode::kInvalidArgument);
  bad = CalibrationObjectSpec{};
  bad.square_mm = -1;
  EXPECT_FALSE(bad.Check().ok());
}

}  // namespace
}  // namespace rotoscan::calib
