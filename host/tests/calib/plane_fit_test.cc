#include "rotoscan/calib/plane_fit.h"

#include <random>

#include <gtest/gtest.h>

#include "rotoscan/geometry/rigid.h"
#include "testing/testing.h"

namespace rotoscan::calib {
namespace {

using ::testing::HasSubstr;

// A laser plane as the rig has it: 150 mm to the side, tilted towards the optical axis, 300 mm away.
const geometry::Plane kTruth =
    geometry::Plane::FromPointNormal({0, 0, 300}, Eigen::Vector3d(std::cos(0.5), 0.05, std::sin(0.5)));

std::vector<Eigen::Vector3d> PointsOnPlane(int n, double noise_mm, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> coord(-60.0, 60.0);
  std::normal_distribution<double> noise(0.0, noise_mm);
  const Eigen::Vector3d u = kTruth.normal.unitOrthogonal();
  const Eigen::Vector3d v = kTruth.normal.cross(u);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < n; ++i) {
    points.push_back(Eigen::Vector3d(0, 0, 300) + coord(rng) * u + coord(rng) * v +
                     (noise_mm > 0 ? noise(rng) : 0.0) * kTruth.normal);
  }
  return points;
}

double AngleDeg(const geometry::Plane& a, const geometry::Plane& b) {
  return geometry::RadToDeg(std::acos(std::min(1.0, std::abs(a.normal.dot(b.normal)))));
}
double OffsetError(const geometry::Plane& a, const geometry::Plane& b) {
  return std::abs(a.Canonical().offset - b.Canonical().offset);
}

TEST(PlaneFitTest, AllEstimatorsExactOnNoiselessPoints) {
  const auto points = PointsOnPlane(50, 0.0, 1);
  for (const auto& fit : {FitPlanePaper(points), FitPlaneTotalLeastSquares(points), FitPlaneRobust(points)}) {
    ASSERT_TRUE(fit.ok()) << fit.status().ToString();
    EXPECT_LT(AngleDeg(fit->plane, kTruth), 1e-8);
    EXPECT_LT(OffsetError(fit->plane, kTruth), 1e-8);
    EXPECT_LT(fit->rms_mm, 1e-9);
    EXPECT_EQ(fit->inliers, 50);
  }
}

TEST(PlaneFitTest, TotalLeastSquaresWithNoise) {
  // 2,000 points with 0.05 mm noise over 120 mm: normal within 0.01 deg, offset within 0.01 mm.
  const auto points = PointsOnPlane(2000, 0.05, 2);
  const auto fit = FitPlaneTotalLeastSquares(points);
  ASSERT_TRUE(fit.ok());
  EXPECT_LT(AngleDeg(fit->plane, kTruth), 0.01);
  EXPECT_LT(OffsetError(fit->plane, kTruth), 0.01);
  EXPECT_NEAR(fit->rms_mm, 0.05, 0.005);
}

TEST(PlaneFitTest, RobustFitIgnoresOutliersThatTiltLeastSquares) {
  auto points = PointsOnPlane(1000, 0.05, 3);
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> far(2.0, 30.0);
  for (int i = 0; i < 300; ++i) points[i] += far(rng) * kTruth.normal;  // 30 % gross outliers on one side
  const auto robust = FitPlaneRobust(points);
  ASSERT_TRUE(robust.ok()) << robust.status().ToString();
  EXPECT_LT(AngleDeg(robust->plane, kTruth), 0.02);
  EXPECT_LT(OffsetError(robust->plane, kTruth), 0.02);
  EXPECT_GE(robust->inliers, 690);
  EXPECT_LE(robust->inliers, 710);
  EXPECT_FALSE(robust->inlier_mask[0]);
  // The same data moves the plain fits by millimetres.
  const auto tls = FitPlaneTotalLeastSquares(points);
  ASSERT_TRUE(tls.ok());
  EXPECT_GT(OffsetError(tls->plane, kTruth), 1.0);
}

TEST(PlaneFitTest, RejectsDegenerateInput) {
  EXPECT_THAT(FitPlaneTotalLeastSquares({{0, 0, 1}, {1, 0, 1}}).status().message(), HasSubstr("at least 3"));
  const std::vector<Eigen::Vector3d> line = {{0, 0, 100}, {1, 1, 101}, {2, 2, 102}, {3, 3, 103}};
  EXPECT_THAT(FitPlaneTotalLeastSquares(line).status().message(), HasSubstr("collinear"));
  EXPECT_FALSE(FitPlaneRobust(line).ok());
  EXPECT_FALSE(FitPlanePaper(line).ok());
  // The paper's eq. 12 cannot represent a plane through the origin.
  const std::vector<Eigen::Vector3d> through_origin = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
  EXPECT_FALSE(FitPlanePaper(through_origin).ok());
  RobustPlaneOptions bad;
  bad.inlier_threshold_mm = 0;
  EXPECT_EQ(FitPlaneRobust(PointsOnPlane(10, 0, 1), bad).status().code(), StatusCode::kInvalidArgument);
}

TEST(PlaneFitTest, RobustFitFailsWhenNoPlaneDominates) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> coord(-50, 50);
  std::vector<Eigen::Vector3d> cloud;
  for (int i = 0; i < 200; ++i) cloud.emplace_back(coord(rng), coord(rng), 300 + coord(rng));
  const auto fit = FitPlaneRobust(cloud);
  ASSERT_FALSE(fit.ok());
  EXPECT_EQ(fit.status().code(), StatusCode::kNotConverged);
}

}  // namespace
}  // namespace rotoscan::calib
