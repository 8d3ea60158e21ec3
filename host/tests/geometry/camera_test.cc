#include "rotoscan/geometry/camera.h"

#include <gtest/gtest.h>

#include <cmath>

#include "testing/testing.h"

namespace rotoscan::geometry {
namespace {

using rotoscan::testing::EigenNear;

CameraModel PaperCamera() {
  // The paper's rig: 1288x964 sensor, about 20 degrees horizontal field of view (§V).
  return CameraModel::FromFieldOfView(1288, 964, 20.0);
}

TEST(CameraModelTest, FieldOfViewGivesFocalLength) {
  const CameraModel camera = PaperCamera();
  // fx = (w/2) / tan(fov/2) = 644 / tan(10 deg) = 3652.3 px.
  EXPECT_NEAR(camera.fx, 644.0 / std::tan(10.0 * M_PI / 180.0), 1e-9);
  EXPECT_NEAR(camera.cx, 643.5, 1e-12);
  EXPECT_TRUE(camera.Validate().ok());
}

TEST(CameraModelTest, ProjectionWithoutDistortionIsEquation2) {
  const CameraModel camera = PaperCamera();
  const Eigen::Vector3d point_in_cam(12.0, -7.5, 300.0);
  const Eigen::Vector2d expected(camera.fx * 12.0 / 300.0 + camera.cx, camera.fy * -7.5 / 300.0 + camera.cy);
  EXPECT_THAT(camera.Project(point_in_cam), EigenNear(expected, 1e-12));
}

TEST(CameraModelTest, DistortionMatchesOpenCvFormula) {
  CameraModel camera = PaperCamera();
  camera.distortion = {-0.2, 0.1, 0.001, -0.002, 0.05};
  const double x = 0.05, y = -0.03;
  const double r2 = x * x + y * y;
  const double radial = 1 - 0.2 * r2 + 0.1 * r2 * r2 + 0.05 * r2 * r2 * r2;
  const double xd = x * radial + 2 * 0.001 * x * y + -0.002 * (r2 + 2 * x * x);
  const double yd = y * radial + 0.001 * (r2 + 2 * y * y) + 2 * -0.002 * x * y;
  const Eigen::Vector2d expected(camera.fx * xd + camera.cx, camera.fy * yd + camera.cy);
  EXPECT_THAT(camera.Project(Eigen::Vector3d(x * 200, y * 200, 200)), EigenNear(expected, 1e-9));
}

TEST(CameraModelTest, UndistortInvertsProjectAcrossTheImage) {
  CameraModel camera = PaperCamera();
  camera.distortion = {-0.25, 0.12, 0.0015, -0.001, -0.03};
  double worst = 0;
  for (int row = 0; row < camera.height; row += 60) {
    for (int col = 0; col < camera.width; col += 80) {
      const Eigen::Vector2d pixel(col, row);
      const Eigen::Vector3d ray = camera.PixelToRay(pixel);
      EXPECT_DOUBLE_EQ(ray.z(), 1.0);
      worst = std::max(worst, (camera.Project(ray * 250.0) - pixel).norm());
    }
  }
  EXPECT_LT(worst, 1e-9);
}

// The warm-started form (used to tabulate the whole image) gives the same answer as the full iteration,
// from the neighbouring pixel's answer and from a poor guess alike.
TEST(CameraModelTest, WarmStartedUndistortMatchesTheFullIteration) {
  CameraModel camera = PaperCamera();
  camera.distortion = {-0.25, 0.12, 0.0015, -0.001, -0.03};
  double worst = 0;
  for (int row = 0; row < camera.height; row += 37) {
    Eigen::Vector2d previous = camera.Undistort(Eigen::Vector2d(0, row));
    for (int col = 1; col < camera.width; col += 3) {
      const Eigen::Vector2d pixel(col, row);
      const Eigen::Vector2d full = camera.Undistort(pixel);
      const Eigen::Vector2d warm = camera.Undistort(pixel, previous + Eigen::Vector2d(3.0 / camera.fx, 0.0));
      worst = std::max(worst, (warm - full).norm());
      previous = warm;
    }
  }
  EXPECT_LT(worst * camera.fx, 1e-9);  // in pixels
  const Eigen::Vector2d corner(camera.width - 1.0, camera.height - 1.0);
  EXPECT_THAT(camera.Undistort(corner, Eigen::Vector2d(0.0, 0.0)), EigenNear(camera.Undistort(corner), 1e-12));
  EXPECT_THAT(camera.Undistort(corner, Eigen::Vector2d(std::nan(""), 0.0)),
              EigenNear(camera.Undistort(corner), 1e-12));
}

TEST(CameraModelTest, ValidateNamesTheProblem) {
  CameraModel camera = PaperCamera();
  camera.fx = 0;
  Status s = camera.Validate();
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("focal"), std::string::npos);
  camera = PaperCamera();
  camera.width = 0;
  EXPECT_NE(camera.Validate().message().find("size"), std::string::npos);
  camera = PaperCamera();
  camera.distortion[1] = std::nan("");
  EXPECT_FALSE(camera.Validate().ok());
}

TEST(CameraModelTest, InsideTest) {
  const CameraModel camera = PaperCamera();
  EXPECT_TRUE(camera.IsInside({0, 0}));
  EXPECT_TRUE(camera.IsInside({1287.4, 963.4}));
  EXPECT_FALSE(camera.IsInside({1287.6, 10}));
  EXPECT_FALSE(camera.IsInside({10, -0.6}));
  EXPECT_FALSE(camera.IsInside({5, 5}, 6.0));
}

TEST(CameraModelTest, BadFieldOfViewIsAPreconditionError) {
  EXPECT_THROW(CameraModel::FromFieldOfView(0, 10, 20), PreconditionError);
  EXPECT_THROW(CameraModel::FromFieldOfView(10, 10, 180), PreconditionError);
}

}  // namespace
}  // namespace rotoscan::geometry
