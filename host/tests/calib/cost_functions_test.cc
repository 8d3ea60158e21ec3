// Each cost function's automatic derivatives against central numeric differentiation of the same functor.
#include <memory>
#include <vector>

#include <ceres/numeric_diff_cost_function.h>
#include <gtest/gtest.h>

#include "calib/cost_functions/axis_gauge.h"
#include "calib/cost_functions/corner_reprojection.h"
#include "calib/cost_functions/laser_on_target.h"
#include "calib/cost_functions/scanned_point.h"
#include "calib/cost_functions/table_angle_prior.h"
#include "calib/cost_functions/table_model.h"
#include "rotoscan/geometry/camera.h"

namespace rotoscan::calib::internal {
namespace {

// Evaluates both cost functions at `parameters` and compares residuals and every Jacobian entry:
// |auto - numeric| <= tolerance * max(1, |auto|).
void ExpectSameDerivatives(const ceres::CostFunction& automatic, const ceres::CostFunction& numeric,
                           const std::vector<std::vector<double>>& parameters, double tolerance) {
  const int num_residuals = automatic.num_residuals();
  ASSERT_EQ(num_residuals, numeric.num_residuals());
  const auto& sizes = automatic.parameter_block_sizes();
  ASSERT_EQ(sizes.size(), parameters.size());
  std::vector<const double*> blocks;
  for (const auto& p : parameters) blocks.push_back(p.data());
  std::vector<double> r_auto(num_residuals), r_num(num_residuals);
  std::vector<std::vector<double>> j_auto(sizes.size()), j_num(sizes.size());
  std::vector<double*> jp_auto, jp_num;
  for (std::size_t b = 0; b < sizes.size(); ++b) {
    j_auto[b].resize(num_residuals * sizes[b]);
    j_num[b].resize(num_residuals * sizes[b]);
    jp_auto.push_back(j_auto[b].data());
    jp_num.push_back(j_num[b].data());
  }
  ASSERT_TRUE(automatic.Evaluate(blocks.data(), r_auto.data(), jp_auto.data()));
  ASSERT_TRUE(numeric.Evaluate(blocks.data(), r_num.data(), jp_num.data()));
  for (int i = 0; i < num_residuals; ++i)
    EXPECT_NEAR(r_auto[i], r_num[i], 1e-12 * std::max(1.0, std::abs(r_auto[i])));
  double largest = 0.0;
  for (std::size_t b = 0; b < sizes.size(); ++b) {
    for (std::size_t k = 0; k < j_auto[b].size(); ++k) {
      largest = std::max(largest, std::abs(j_auto[b][k]));
      EXPECT_NEAR(j_auto[b][k], j_num[b][k], tolerance * std::max(1.0, std::abs(j_auto[b][k])))
          << "block " << b << " entry " << k;
    }
  }
  EXPECT_GT(largest, 0.0);  // the test must be able to fail: derivatives are not all zero
}

// A rig with distortion, a target 300 mm away turned by 6 degrees (scale 1.003) about a tilted axis.
const std::vector<double> kIntrinsics = {1400.0, 1398.0, 645.0, 478.0};
const std::vector<double> kDistortion = {-0.08, 0.05, 0.0005, -0.0003, 0.01};
const std::vector<double> kPose = {0.1, -0.3, 0.05, -40.0, 20.0, 310.0};
const std::vector<double> kAxisDirection = {0.02, -0.97, -0.25};
const std::vector<double> kAxisPoint = {5.0, 60.0, 320.0};
const std::vector<double> kAngleScale = {1.003};
const std::vector<double> kAngleOffset = {-0.012};  // the table slipped 0.7 degree

TEST(CostFunctionsTest, CornerReprojectionDerivatives) {
  const Eigen::Vector3d corner(24.0, 36.0, 0.0);
  const Eigen::Vector2d pixel(500.0, 420.0);
  std::unique_ptr<ceres::CostFunction> automatic(CornerReprojectionCost::Create(corner, pixel, 0.105, 0.1));
  ceres::NumericDiffCostFunction<CornerReprojectionCost, ceres::RIDDERS, 2, 4, 5, 6, 3, 3, 1, 1> numeric(
      new CornerReprojectionCost(corner, pixel, 0.105, 0.1));
  ExpectSameDerivatives(
      *automatic, numeric,
      {kIntrinsics, kDistortion, kPose, kAxisDirection, kAxisPoint, kAngleScale, kAngleOffset}, 1e-6);
}

TEST(CostFunctionsTest, LaserOnTargetDerivatives) {
  const Eigen::Vector2d pixel(700.0, 300.0);
  const std::vector<double> normal = {0.9, 0.05, 0.4};
  const std::vector<double> offset = {-80.0};
  std::unique_ptr<ceres::CostFunction> automatic(LaserOnTargetCost::Create(pixel, 0.07, 0.05));
  ceres::NumericDiffCostFunction<LaserOnTargetCost, ceres::RIDDERS, 1, 4, 5, 6, 3, 3, 1, 1, 3, 1> numeric(
      new LaserOnTargetCost(pixel, 0.07, 0.05));
  ExpectSameDerivatives(*automatic, numeric,
                        {kIntrinsics, kDistortion, kPose, kAxisDirection, kAxisPoint, kAngleScale,
                         kAngleOffset, normal, offset},
                        1e-6);
}

// The same on a target plane that does not pass through the target origin (a face of the paper's object).
TEST(CostFunctionsTest, LaserOnObjectFaceDerivatives) {
  const Eigen::Vector2d pixel(650.0, 500.0);
  const Eigen::Vector4d face(0.28, 0.0, 0.96, -12.0);  // tilted, 12 mm from the target origin
  const std::vector<double> normal = {0.9, 0.05, 0.4};
  const std::vector<double> offset = {-80.0};
  std::unique_ptr<ceres::CostFunction> automatic(LaserOnTargetCost::Create(pixel, -0.2, 0.05, face));
  ceres::NumericDiffCostFunction<LaserOnTargetCost, ceres::RIDDERS, 1, 4, 5, 6, 3, 3, 1, 1, 3, 1> numeric(
      new LaserOnTargetCost(pixel, -0.2, 0.05, face));
  ExpectSameDerivatives(*automatic, numeric,
                        {kIntrinsics, kDistortion, kPose, kAxisDirection, kAxisPoint, kAngleScale,
                         kAngleOffset, normal, offset},
                        1e-6);
}

TEST(CostFunctionsTest, AxisGaugeDerivatives) {
  std::unique_ptr<ceres::CostFunction> automatic(
      AxisGaugeCost::Create(Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(0, -1, 0.2), 1.0));
  ceres::NumericDiffCostFunction<AxisGaugeCost, ceres::RIDDERS, 1, 3> numeric(
      new AxisGaugeCost(Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(0, -1, 0.2), 1.0));
  ExpectSameDerivatives(*automatic, numeric, {kAxisPoint}, 1e-8);
}

TEST(CostFunctionsTest, TableAnglePriorDerivatives) {
  std::unique_ptr<ceres::CostFunction> automatic(TableAnglePriorCost::Create(0.0087));
  ceres::NumericDiffCostFunction<TableAnglePriorCost, ceres::RIDDERS, 1, 1> numeric(
      new TableAnglePriorCost(0.0087));
  ExpectSameDerivatives(*automatic, numeric, {kAngleOffset}, 1e-8);
  // The residual is the offset in sigmas.
  const double* parameters[] = {kAngleOffset.data()};
  double residual = 0.0;
  ASSERT_TRUE(automatic->Evaluate(parameters, &residual, nullptr));
  EXPECT_NEAR(residual, -0.012 / 0.0087, 1e-12);
}

TEST(CostFunctionsTest, ScannedPointDerivatives) {
  const std::vector<double> normal = {0.9, 0.05, 0.4};
  const std::vector<double> offset = {-80.0};
  std::unique_ptr<ceres::CostFunction> automatic(ScannedPoint::Create(Eigen::Vector2d(700.0, 300.0), 2.1));
  ceres::NumericDiffCostFunction<ScannedPoint, ceres::RIDDERS, 3, 4, 5, 3, 1, 3, 3> numeric(
      new ScannedPoint(Eigen::Vector2d(700.0, 300.0), 2.1));
  ExpectSameDerivatives(*automatic, numeric,
                        {kIntrinsics, kDistortion, normal, offset, kAxisDirection, kAxisPoint}, 1e-6);
}

// A pixel of a point on the laser plane triangulates back onto that point (eq. 6), and turning the table
// back (eq. 7) puts it where the same table point was at angle 0.
TEST(CostFunctionsTest, ScannedPointIsTheTriangulatedPointTurnedBack) {
  const Eigen::Vector3d normal = Eigen::Vector3d(0.9, 0.05, 0.4).normalized();
  const double offset = -80.0;
  Eigen::Vector3d on_plane(10.0, -20.0, 0.0);
  on_plane.z() = (-offset - normal.x() * on_plane.x() - normal.y() * on_plane.y()) / normal.z();
  double pixel[2];
  geometry::ProjectToPixel(kIntrinsics.data(), kDistortion.data(), on_plane.data(), pixel);
  const Eigen::Vector3d a =
      Eigen::Vector3d(kAxisDirection[0], kAxisDirection[1], kAxisDirection[2]).normalized();
  const Eigen::Vector3d c(kAxisPoint[0], kAxisPoint[1], kAxisPoint[2]);
  const double angle = 0.8;
  const Eigen::Vector3d expected = c + Eigen::AngleAxisd(-angle, a) * (on_plane - c);
  const ScannedPoint functor(Eigen::Vector2d(pixel[0], pixel[1]), angle);
  double out[3];
  ASSERT_TRUE(functor(kIntrinsics.data(), kDistortion.data(), normal.data(), &offset, kAxisDirection.data(),
                      kAxisPoint.data(), out));
  EXPECT_NEAR(out[0], expected.x(), 1e-9);
  EXPECT_NEAR(out[1], expected.y(), 1e-9);
  EXPECT_NEAR(out[2], expected.z(), 1e-9);
}

TEST(CostFunctionsTest, UndistortInvertsTheCameraModel) {
  // The Newton undistortion must invert geometry::DistortNormalized (the projection of camera.h).
  const double point[3] = {-60.0, 45.0, 300.0};
  double pixel[2];
  geometry::ProjectToPixel(kIntrinsics.data(), kDistortion.data(), point, pixel);
  double x = 0, y = 0;
  UndistortPixel(kIntrinsics.data(), kDistortion.data(), pixel[0], pixel[1], &x, &y);
  EXPECT_NEAR(x, -0.2, 1e-12);
  EXPECT_NEAR(y, 0.15, 1e-12);
}

TEST(CostFunctionsTest, TableModelTurnsAboutTheAxis) {
  // A point on the axis does not move; a quarter turn (scale 0.5 times a commanded pi) keeps the distance.
  const double pose[6] = {0, 0, 0, 0, 0, 0};
  const double direction[3] = {0, -1, 0};
  const double axis_point[3] = {0, 50, 300};
  const double angle_scale[1] = {0.5};
  const double no_offset[1] = {0.0};
  const double on_axis[3] = {0, 10, 300};
  double out[3];
  TargetPointInCam(pose, direction, axis_point, angle_scale, no_offset, M_PI, on_axis, out);
  EXPECT_NEAR(out[0], 0, 1e-12);
  EXPECT_NEAR(out[1], 10, 1e-12);
  EXPECT_NEAR(out[2], 300, 1e-12);
  const double off_axis[3] = {30, 50, 300};
  TargetPointInCam(pose, direction, axis_point, angle_scale, no_offset, M_PI, off_axis, out);
  // Right-handed about -y: +x goes to +z.
  EXPECT_NEAR(out[0], 0, 1e-12);
  EXPECT_NEAR(out[2], 330, 1e-12);
  // An offset adds to the modelled angle: a commanded 0 with an offset of a quarter turn is the same.
  const double zero_scale[1] = {0.0};
  const double quarter[1] = {M_PI / 2};
  TargetPointInCam(pose, direction, axis_point, zero_scale, quarter, 1.0, off_axis, out);
  EXPECT_NEAR(out[0], 0, 1e-12);
  EXPECT_NEAR(out[2], 330, 1e-12);
}

}  // namespace
}  // namespace rotoscan::calib::internal
