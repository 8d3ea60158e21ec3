#include "rotoscan/laser/triangulate.h"

#include <cstdio>
#include <random>

#include <gtest/gtest.h>

#include "rotoscan/geometry/dlt.h"
#include "testing/testing.h"

namespace rotoscan::laser {
namespace {

using rotoscan::testing::EigenNear;

geometry::CameraModel SmallCamera(bool distorted) {
  geometry::CameraModel camera = geometry::CameraModel::FromFieldOfView(160, 120, 50.0);
  if (distorted) camera.distortion = {-0.25, 0.08, 0.001, -0.0015, 0.0};
  return camera;
}

geometry::Plane LeftLaser() {
  // A laser 200 mm left of the camera whose vertical fan crosses the optical axis 300 mm away.
  return geometry::Plane::FromPointNormal(Eigen::Vector3d(-200, 0, 0), Eigen::Vector3d(300, 0, -200));
}

TEST(TriangulateTest, PointLiesOnPlaneAndProjectsBack) {
  for (bool distorted : {false, true}) {
    const geometry::CameraModel camera = SmallCamera(distorted);
    Triangulator triangulator(camera);
    const geometry::Plane plane = LeftLaser();
    std::mt19937 rng(1);
    std::uniform_real_distribution<double> column(0.0, 159.0);
    for (int row = 0; row < 120; row += 7) {
      const double c = column(rng);
      const auto point = triangulator.PointInCam(plane, c, row);
      ASSERT_TRUE(point.has_value());
      EXPECT_NEAR(plane.SignedDistance(*point), 0.0, 1e-9);
      EXPECT_GT(point->z(), 0.0);
      // Back through the full camera model: the table interpolation stays far below 1e-3 px.
      EXPECT_THAT(camera.Project(*point), EigenNear(Eigen::Vector2d(c, row), 1e-3)) << distorted;
      // And the ray agrees with the exact (iterative) undistortion.
      EXPECT_THAT(triangulator.Ray(c, row), EigenNear(camera.PixelToRay(Eigen::Vector2d(c, row)), 1e-5));
    }
  }
}

// The table's interpolation error at full size, on a wide strongly distorted lens and on the narrow lens
// of the rig: every 0.1 px along rows spread over the image, against the exact (iterative) undistortion.
TEST(TriangulateTest, TableInterpolationErrorIsNegligible) {
  for (double fov : {20.0, 60.0}) {
    geometry::CameraModel camera = geometry::CameraModel::FromFieldOfView(1288, 964, fov);
    camera.distortion = {fov > 30 ? -0.3 : -0.2, 0.1, 0.001, -0.0015, 0.0};
    const Triangulator triangulator(camera);
    double worst_px = 0;
    for (int row : {0, 1, 137, 482, 700, 963}) {
      for (double c = -0.5; c <= 1287.5; c += 0.1) {
        const Eigen::Vector3d error = triangulator.Ray(c, row) - camera.PixelToRay(Eigen::Vector2d(c, row));
        worst_px = std::max(worst_px, std::max(std::abs(error.x()) * camera.fx, std::abs(error.y()) * camera.fy));
      }
    }
    // Float storage alone is ~1e-5 px at these focal lengths; the cubic adds less.
    EXPECT_LT(worst_px, 5e-5) << "fov " << fov;
    std::printf("table interpolation, %.0f deg lens: worst %.2g px\n", fov, worst_px);
  }
}

TEST(TriangulateTest, ParallelOrBehindGivesNothing) {
  Triangulator triangulator(SmallCamera(false));
  // A plane through the camera centre containing the optical axis: rays are in it or parallel.
  const geometry::Plane through =
      geometry::Plane::FromPointNormal(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d::UnitY());
  EXPECT_FALSE(triangulator.PointInCam(through, 80, 60).has_value());
  // A plane behind the camera.
  const geometry::Plane behind =
      geometry::Plane::FromPointNormal(Eigen::Vector3d(0, 0, -50), Eigen::Vector3d::UnitZ());
  EXPECT_FALSE(triangulator.PointInCam(behind, 80, 60).has_value());
  EXPECT_THROW(triangulator.Ray(10, 500), PreconditionError);
}

TEST(TriangulateTest, PaperEq6AgreesWithRayPlaneWithoutDistortion) {
  const geometry::CameraModel camera = SmallCamera(false);
  Triangulator triangulator(camera);
  // Reference frame of the paper: an object frame with cam_from_object = [R | t].
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(15, -20, 300);
  Eigen::Matrix<double, 3, 4> Rt;
  Rt << R, t;
  const Eigen::Matrix<double, 3, 4> T = camera.K() * Rt;  // eq. 3
  const geometry::Plane plane_in_cam = LeftLaser();
  // The plane in the object frame: n_o = R^T n, d_o = d + n . t.
  geometry::Plane plane_in_object;
  plane_in_object.normal = R.transpose() * plane_in_cam.normal;
  plane_in_object.offset = plane_in_cam.offset + plane_in_cam.normal.dot(t);
  for (double col : {10.5, 80.0, 150.25}) {
    for (int row : {5, 60, 110}) {
      const auto in_cam = triangulator.PointInCam(plane_in_cam, col, row);
      const auto in_object = geometry::TriangulateWithPlane(T, plane_in_object, Eigen::Vector2d(col, row));
      ASSERT_TRUE(in_cam.has_value());
      ASSERT_TRUE(in_object.ok()) << in_object.status().ToString();
      EXPECT_THAT(Eigen::Vector3d(R * *in_object + t), EigenNear(*in_cam, 1e-7));
    }
  }
}

TEST(TriangulateTest, TriangulateLineKeepsIndices) {
  Triangulator triangulator(SmallCamera(true));
  Line line;
  line.points.push_back({3, 40.5f, 100, 5, 1, 0});
  line.points.push_back({400, 40.5f, 100, 5, 1, 0});  // outside the image: skipped
  line.points.push_back({50, 90.25f, 100, 5, 1, 0});
  std::vector<Eigen::Vector3d> points;
  std::vector<int> kept;
  triangulator.Triangulate(line, LeftLaser(), &points, &kept);
  ASSERT_EQ(points.size(), 2u);
  EXPECT_EQ(kept, (std::vector<int>{0, 2}));
}

// Triangulate runs 4 points per turn with AVX2 where the CPU has it: every path gives PointInCam's point to
// the bit, keeps the same indices, and drops the same points (rows outside the image, either sign, and rays
// that meet the plane behind the camera), also in a tail shorter than 4 and at the table's column clamp.
TEST(TriangulateTest, EveryVectorPathGivesPointInCamToTheBit) {
  for (bool distorted : {true, false}) {
    SCOPED_TRACE(distorted ? "distorted" : "pinhole");
    const geometry::CameraModel camera = SmallCamera(distorted);
    Triangulator triangulator(camera);
    // A plane through the image's middle, tilted so that its left part lies behind the camera.
    const geometry::Plane plane =
        geometry::Plane::FromPointNormal(Eigen::Vector3d(0, 0, 300), Eigen::Vector3d(1, 0, -0.05));
    std::mt19937 random(7);
    std::uniform_real_distribution<float> column(-3.0f, camera.width + 2.0f);
    std::uniform_int_distribution<int> row(-3, camera.height + 2);
    for (size_t count : {0u, 1u, 3u, 4u, 7u, 64u, 1001u}) {
      Line line;
      for (size_t i = 0; i < count; ++i) line.points.push_back({row(random), column(random), 100, 5, 1, 0});
      std::vector<int> expected_kept;
      std::vector<Eigen::Vector3d> expected;
      for (size_t i = 0; i < count; ++i) {
        const LinePoint& p = line.points[i];
        if (p.row < 0 || p.row >= camera.height) continue;
        const auto point = triangulator.PointInCam(plane, p.column, p.row);
        if (!point) continue;
        expected.push_back(*point);
        expected_kept.push_back(static_cast<int>(i));
      }
      if (count == 1001) {  // the case exercises every kind of point
        EXPECT_GT(expected.size(), count / 4);
        EXPECT_LT(expected.size(), count * 3 / 4);
      }
      for (bool avx2 : {true, false}) {
        SCOPED_TRACE(avx2 ? "AVX2 allowed" : "scalar");
        internal::AllowVectorExtensions(avx2, avx2);
        std::vector<Eigen::Vector3d> points{Eigen::Vector3d(1, 2, 3)};
        std::vector<int> kept{42};
        triangulator.Triangulate(line, plane, &points, &kept);
        internal::AllowVectorExtensions(true, true);
        ASSERT_EQ(kept, expected_kept) << count;
        ASSERT_EQ(points.size(), expected.size());
        for (size_t k = 0; k < points.size(); ++k) {
          for (int axis = 0; axis < 3; ++axis) {
            ASSERT_EQ(points[k][axis], expected[k][axis]) << "point " << k << " axis " << axis << " of " << count;
          }
        }
      }
    }
  }
}

}  // namespace
}  // namespace rotoscan::laser
