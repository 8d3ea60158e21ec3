#include "rotoscan/geometry/dlt.h"

#include <random>

#include <gtest/gtest.h>

#include "rotoscan/geometry/rigid.h"
#include "testing/testing.h"

namespace rotoscan::geometry {
namespace {

using rotoscan::testing::EigenNear;
using ::testing::HasSubstr;

// The paper's calibration object (Fig. 6): two orthogonal planes, y = 0 and z = 0, with a 10 mm grid.
std::vector<Eigen::Vector3d> PaperObjectPoints() {
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 8; ++i) {
    for (int j = 1; j < 7; ++j) {
      points.emplace_back(10.0 * i, 0.0, 10.0 * j);  // x-z face
      points.emplace_back(10.0 * i, 10.0 * j, 0.0);  // x-y face
    }
  }
  return points;
}

struct Scene {
  Eigen::Matrix3d K;
  Eigen::Isometry3d cam_from_object;
  ProjectionMatrix projection;
};

Scene MakeScene() {
  Scene s;
  s.K << 1250.0, 0.0, 652.0, 0.0, 1246.0, 471.0, 0.0, 0.0, 1.0;
  // Object 300 mm in front of the camera, seen obliquely so that both faces show.
  s.cam_from_object = Eigen::Translation3d(-30, 20, 300) *
                      Eigen::AngleAxisd(DegToRad(-120), Eigen::Vector3d(1, 0.2, 0.1).normalized());
  s.projection = s.K * s.cam_from_object.matrix().topRows<3>();
  return s;
}

std::vector<Eigen::Vector2d> Project(const ProjectionMatrix& p, const std::vector<Eigen::Vector3d>& points,
                                     double noise_px, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_px);
  std::vector<Eigen::Vector2d> pixels;
  for (const auto& x : points) {
    pixels.push_back(ProjectWithMatrix(p, x) +
                     (noise_px > 0 ? Eigen::Vector2d(noise(rng), noise(rng)) : Eigen::Vector2d::Zero()));
  }
  return pixels;
}

TEST(DltTest, RecoversExactProjectionAndDecomposes) {
  const Scene s = MakeScene();
  const auto points = PaperObjectPoints();
  for (const auto& x : points) ASSERT_GT((s.cam_from_object * x).z(), 0);
  const auto estimate = EstimateProjectionDlt(points, Project(s.projection, points, 0.0, 1));
  ASSERT_TRUE(estimate.ok()) << estimate.status().ToString();
  EXPECT_LT(estimate->rms_px, 1e-8);
  // Same matrix up to the (positive) scale fixed by the unit third row.
  const ProjectionMatrix expected = s.projection / s.projection.block<1, 3>(2, 0).norm();
  EXPECT_THAT(estimate->projection, EigenNear(expected, 1e-8 * expected.norm()));

  const auto decomposition = DecomposeProjection(estimate->projection);
  ASSERT_TRUE(decomposition.ok()) << decomposition.status().ToString();
  EXPECT_THAT(decomposition->K, EigenNear(s.K, 1e-6));
  EXPECT_THAT(decomposition->cam_from_object.linear(), EigenNear(s.cam_from_object.linear(), 1e-9));
  EXPECT_THAT(decomposition->cam_from_object.translation(), EigenNear(s.cam_from_object.translation(), 1e-6));
}

TEST(DltTest, NoisyPixelsGiveCloseIntrinsics) {
  // 0.2 px noise on 96 points: focal length within 1 %, principal point within 5 px, pose within 1 mm.
  const Scene s = MakeScene();
  const auto points = PaperObjectPoints();
  const auto estimate = EstimateProjectionDlt(points, Project(s.projection, points, 0.2, 7));
  ASSERT_TRUE(estimate.ok());
  EXPECT_GT(estimate->rms_px, 0.1);
  EXPECT_LT(estimate->rms_px, 0.3);
  const auto d = DecomposeProjection(estimate->projection);
  ASSERT_TRUE(d.ok());
  EXPECT_NEAR(d->K(0, 0), s.K(0, 0), 0.01 * s.K(0, 0));
  EXPECT_NEAR(d->K(1, 1), s.K(1, 1), 0.01 * s.K(1, 1));
  EXPECT_NEAR(d->K(0, 2), s.K(0, 2), 5.0);
  EXPECT_NEAR(d->K(1, 2), s.K(1, 2), 5.0);
  EXPECT_NEAR(d->K(0, 1), 0.0, 0.01 * s.K(0, 0));
  EXPECT_THAT(d->cam_from_object.translation(), EigenNear(s.cam_from_object.translation(), 3.0));
}

TEST(DltTest, NegatedMatrixDecomposesToTheSameCamera) {
  const Scene s = MakeScene();
  const auto d = DecomposeProjection(-2.5 * s.projection);
  ASSERT_TRUE(d.ok());
  EXPECT_THAT(d->K, EigenNear(s.K, 1e-9));
  EXPECT_THAT(d->cam_from_object.translation(), EigenNear(s.cam_from_object.translation(), 1e-9));
}

TEST(DltTest, RejectsTooFewPoints) {
  const Scene s = MakeScene();
  auto points = PaperObjectPoints();
  points.resize(5);
  const auto estimate = EstimateProjectionDlt(points, Project(s.projection, points, 0.0, 1));
  ASSERT_FALSE(estimate.ok());
  EXPECT_EQ(estimate.status().code(), StatusCode::kInvalidArgument);
  EXPECT_THAT(estimate.status().message(), HasSubstr("at least 6"));
}

TEST(DltTest, RejectsCoplanarAndCollinearPoints) {
  const Scene s = MakeScene();
  std::vector<Eigen::Vector3d> plane, line;
  for (const auto& x : PaperObjectPoints()) {
    if (x.z() == 0.0) plane.push_back(x);
    if (x.z() == 0.0 && x.y() == 10.0) line.push_back(x);
  }
  for (const auto* points : {&plane, &line}) {
    const auto estimate = EstimateProjectionDlt(*points, Project(s.projection, *points, 0.0, 1));
    ASSERT_FALSE(estimate.ok());
    EXPECT_THAT(estimate.status().message(), HasSubstr("coplanar"));
  }
}

TEST(DltTest, RejectsNonFiniteInputAndSingularMatrix) {
  const Scene s = MakeScene();
  auto points = PaperObjectPoints();
  auto pixels = Project(s.projection, points, 0.0, 1);
  pixels[3].x() = std::nan("");
  EXPECT_FALSE(EstimateProjectionDlt(points, pixels).ok());
  EXPECT_THROW((void)EstimateProjectionDlt(points, std::vector<Eigen::Vector2d>(3)), PreconditionError);
  ProjectionMatrix singular = s.projection;
  singular.col(2) = singular.col(0);
  EXPECT_EQ(DecomposeProjection(singular).status().code(), StatusCode::kInvalidArgument);
}

// A known homography (a board's plane seen obliquely, in pixels, mapped back to mm) from exact points, and
// the same from pixels with 0.1 px noise to within what that noise allows.
TEST(DltTest, HomographyRecoversAKnownPlaneMapping) {
  Eigen::Matrix3d truth;
  truth << 0.21, -0.03, -40.0, 0.02, 0.19, -25.0, 1e-4, -5e-5, 1.0;
  std::vector<Eigen::Vector2d> pixels, mm;
  for (int i = 0; i < 9; ++i) {
    for (int j = 0; j < 6; ++j) {
      const Eigen::Vector2d pixel(200.0 + 60.0 * i + 3.0 * j, 150.0 + 55.0 * j - 2.0 * i);
      pixels.push_back(pixel);
      mm.push_back((truth * pixel.homogeneous()).hnormalized());
    }
  }
  Result<Eigen::Matrix3d> h = EstimateHomographyDlt(pixels, mm);
  ASSERT_TRUE(h.ok()) << h.status().ToString();
  for (size_t k = 0; k < pixels.size(); ++k) {
    EXPECT_THAT(((*h) * pixels[k].homogeneous()).hnormalized(), EigenNear(mm[k], 1e-9)) << k;
  }
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.1);
  std::vector<Eigen::Vector2d> noisy = pixels;
  for (auto& p : noisy) p += Eigen::Vector2d(noise(rng), noise(rng));
  h = EstimateHomographyDlt(noisy, mm);
  ASSERT_TRUE(h.ok()) << h.status().ToString();
  double worst = 0.0;
  for (size_t k = 0; k < pixels.size(); ++k) {
    worst = std::max(worst, (((*h) * pixels[k].homogeneous()).hnormalized() - mm[k]).norm());
  }
  EXPECT_LT(worst, 0.1);  // mm: 0.1 px is about 0.02 mm at this scale; the fit averages 54 points
}

TEST(DltTest, HomographyRejectsDegenerateInput) {
  const std::vector<Eigen::Vector2d> square{{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  EXPECT_TRUE(EstimateHomographyDlt(square, square).ok());
  EXPECT_EQ(EstimateHomographyDlt({{0, 0}, {1, 0}, {1, 1}}, {{0, 0}, {1, 0}, {1, 1}}).status().code(),
            StatusCode::kInvalidArgument);
  const std::vector<Eigen::Vector2d> line{{0, 0}, {1, 1}, {2, 2}, {3, 3}, {4, 4}};
  EXPECT_EQ(EstimateHomographyDlt(line, line).status().code(), StatusCode::kInvalidArgument);
  const std::vector<Eigen::Vector2d> same(4, Eigen::Vector2d(5, 5));
  EXPECT_EQ(EstimateHomographyDlt(same, square).status().code(), StatusCode::kInvalidArgument);
  std::vector<Eigen::Vector2d> bad = square;
  bad[2].y() = std::nan("");
  EXPECT_EQ(EstimateHomographyDlt(bad, square).status().code(), StatusCode::kInvalidArgument);
  EXPECT_THROW((void)EstimateHomographyDlt(square, line), PreconditionError);
}

TEST(DltTest, TriangulatesWithPlaneAsEquation6) {
  const Scene s = MakeScene();
  // A laser plane in the object frame, and points on it.
  const Plane plane = Plane::FromPointNormal({20, 15, 10}, Eigen::Vector3d(1, 0.1, 0.3));
  const Eigen::Vector3d u = plane.normal.cross(Eigen::Vector3d::UnitY()).normalized();
  const Eigen::Vector3d v = plane.normal.cross(u);
  for (double a : {-20.0, 0.0, 15.0}) {
    for (double b : {-10.0, 5.0, 30.0}) {
      const Eigen::Vector3d x = Eigen::Vector3d(20, 15, 10) + a * u + b * v;
      const auto back = TriangulateWithPlane(s.projection, plane, ProjectWithMatrix(s.projection, x));
      ASSERT_TRUE(back.ok());
      EXPECT_THAT(*back, EigenNear(x, 1e-9));
      // The paper's own form (c . X + 1 = 0) gives the same point.
      const auto paper =
          TriangulateWithPlane(s.projection, Plane::FromPaperCoefficients(plane.PaperCoefficients()),
                               ProjectWithMatrix(s.projection, x));
      ASSERT_TRUE(paper.ok());
      EXPECT_THAT(*paper, EigenNear(x, 1e-9));
    }
  }
}

TEST(DltTest, TriangulationRefusesRayParallelToPlane) {
  const Scene s = MakeScene();
  // A plane containing the ray of pixel (600, 500): eq. 6 has no unique solution.
  const Eigen::Vector3d centre = s.cam_from_object.inverse().translation();
  const Eigen::Vector3d ray =
      s.cam_from_object.linear().transpose() * (s.K.inverse() * Eigen::Vector3d(600, 500, 1));
  const Plane plane =
      Plane::FromPointNormal(centre + 100 * Eigen::Vector3d::UnitX(), ray.cross(Eigen::Vector3d::UnitX()));
  const auto result = TriangulateWithPlane(s.projection, plane, {600, 500});
  EXPECT_FALSE(result.ok());
}

}  // namespace
}  // namespace rotoscan::geometry
