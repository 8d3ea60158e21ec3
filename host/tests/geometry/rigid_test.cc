#include "rotoscan/geometry/rigid.h"

#include <gtest/gtest.h>

#include "rotoscan/core/status.h"
#include "testing/testing.h"

namespace rotoscan::geometry {
namespace {

using rotoscan::testing::EigenNear;

TEST(RigidTest, RotationAboutZAxisIsEquation7) {
  // Eq. 7: rotate (x - x_r, y - y_r, z) by theta about z; here expressed about the axis through (x_r, y_r).
  const double xr = 12, yr = -4, theta = 0.7;
  const Eigen::Isometry3d t = RotationAboutAxis({xr, yr, 0}, Eigen::Vector3d::UnitZ(), theta);
  const Eigen::Vector3d p(30, 5, 8);
  const Eigen::Vector3d expected(std::cos(theta) * (p.x() - xr) - std::sin(theta) * (p.y() - yr) + xr,
                                 std::sin(theta) * (p.x() - xr) + std::cos(theta) * (p.y() - yr) + yr, p.z());
  EXPECT_THAT(t * p, EigenNear(expected, 1e-12));
}

TEST(RigidTest, PointsOnTheAxisStay) {
  const Eigen::Vector3d point(1, 2, 3), direction(0.1, -0.2, 1.0);
  const Eigen::Isometry3d t = RotationAboutAxis(point, direction, 1.1);
  EXPECT_THAT(t * (point + 40 * direction), EigenNear(point + 40 * direction, 1e-12));
}

TEST(RigidTest, FrameFromOriginAndZ) {
  const Eigen::Isometry3d cam_from_table = FrameFromOriginAndZ({0, 40, 300}, {0, -1, 0.05});
  EXPECT_NEAR(cam_from_table.linear().determinant(), 1.0, 1e-12);
  EXPECT_THAT(cam_from_table * Eigen::Vector3d::Zero(), EigenNear(Eigen::Vector3d(0, 40, 300), 1e-12));
  EXPECT_THAT(Eigen::Vector3d(cam_from_table.linear().col(2)),
              EigenNear(Eigen::Vector3d(0, -1, 0.05).normalized(), 1e-12));
  EXPECT_THROW(FrameFromOriginAndZ({0, 0, 0}, {1, 0, 0}, {2, 0, 0}), PreconditionError);
}

}  // namespace
}  // namespace rotoscan::geometry
