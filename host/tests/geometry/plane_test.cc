#include "rotoscan/geometry/plane.h"

#include <gtest/gtest.h>

#include "rotoscan/core/status.h"
#include "testing/testing.h"

namespace rotoscan::geometry {
namespace {

using rotoscan::testing::EigenNear;

TEST(PlaneTest, PointNormalAndDistance) {
  const Plane plane = Plane::FromPointNormal({0, 0, 300}, {0, 0, 2});
  EXPECT_THAT(plane.normal, EigenNear(Eigen::Vector3d(0, 0, 1), 1e-15));
  EXPECT_DOUBLE_EQ(plane.offset, -300);
  EXPECT_DOUBLE_EQ(plane.SignedDistance({5, 7, 310}), 10);
}

TEST(PlaneTest, PaperCoefficientsRoundTrip) {
  // A laser plane 100 mm to the side of the camera, tilted 30 degrees towards the optical axis.
  const Eigen::Vector3d normal(std::cos(M_PI / 6), 0, std::sin(M_PI / 6));
  const Plane plane = Plane::FromPointNormal({-100, 0, 0}, normal);
  const Eigen::Vector3d c = plane.PaperCoefficients();
  // Eq. 5: c . X + 1 = 0 for points on the plane.
  const Eigen::Vector3d on_plane = Eigen::Vector3d(-100, 0, 0) + 50 * normal.cross(Eigen::Vector3d::UnitY());
  EXPECT_NEAR(c.dot(on_plane) + 1.0, 0.0, 1e-12);
  const Plane back = Plane::FromPaperCoefficients(c);
  EXPECT_NEAR(std::abs(back.normal.dot(plane.normal)), 1.0, 1e-15);
  EXPECT_NEAR(back.SignedDistance(on_plane), 0.0, 1e-12);
}

TEST(PlaneTest, RayIntersection) {
  const Plane plane = Plane::FromPointNormal({0, 0, 300}, {0, 0, 1});
  const auto t = plane.IntersectRay(Eigen::Vector3d::Zero(), Eigen::Vector3d(0.1, 0.2, 1.0));
  ASSERT_TRUE(t.has_value());
  EXPECT_DOUBLE_EQ(*t, 300.0);
  EXPECT_FALSE(plane.IntersectRay(Eigen::Vector3d::Zero(), Eigen::Vector3d(1, 0, 0)).has_value());
}

TEST(PlaneTest, CanonicalSign) {
  const Plane plane = Plane::FromPointNormal({0, 0, 300}, {0, 0, 1});
  const Plane c = plane.Canonical();
  EXPECT_GE(c.offset, 0);
  EXPECT_NEAR(c.SignedDistance({0, 0, 300}), 0, 1e-12);
  EXPECT_THROW(Plane::FromPointNormal({0, 0, 0}, {0, 0, 0}), PreconditionError);
  EXPECT_THROW((void)Plane::FromPointNormal({0, 0, 0}, {0, 0, 1}).PaperCoefficients(), PreconditionError);
}

}  // namespace
}  // namespace rotoscan::geometry
