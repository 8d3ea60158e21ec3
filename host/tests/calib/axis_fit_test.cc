#include "rotoscan/calib/axis_fit.h"

#include <random>

#include <gtest/gtest.h>

#include "rotoscan/geometry/rigid.h"
#include "testing/testing.h"

namespace rotoscan::calib {
namespace {

using rotoscan::testing::EigenNear;
using ::testing::HasSubstr;

// A table axis in the camera frame: 300 mm ahead, 60 mm down, tilted 2 degrees.
const Eigen::Vector3d kAxisPoint(5, 60, 300);
const Eigen::Vector3d kAxisDirection =
    Eigen::AngleAxisd(geometry::DegToRad(2.0), Eigen::Vector3d::UnitX()) * Eigen::Vector3d(0, -1, 0);

double DistanceToTrueAxis(const Eigen::Vector3d& p) {
  const Eigen::Vector3d off = p - kAxisPoint;
  return (off - kAxisDirection.dot(off) * kAxisDirection).norm();
}
double AngleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return geometry::RadToDeg(std::acos(std::min(1.0, std::abs(a.dot(b)))));
}

TEST(CircleFitTest, Equation15RecoversCentre) {
  std::vector<Eigen::Vector2d> points;
  for (int i = 0; i < 12; ++i) {
    const double a = 0.2 * i;  // an arc of 2.2 rad
    points.emplace_back(30 + 45 * std::cos(a), -12 + 45 * std::sin(a));
  }
  const auto fit = FitCircle2d(points);
  ASSERT_TRUE(fit.ok());
  EXPECT_THAT(fit->centre, EigenNear(Eigen::Vector2d(30, -12), 1e-9));
  EXPECT_NEAR(fit->radius, 45, 1e-9);
  EXPECT_LT(fit->rms, 1e-9);
}

TEST(CircleFitTest, RejectsCollinearAndTooFew) {
  EXPECT_THAT(FitCircle2d({{0, 0}, {1, 1}}).status().message(), HasSubstr("at least 3"));
  EXPECT_THAT(FitCircle2d({{0, 0}, {1, 1}, {2, 2}, {3, 3}}).status().message(), HasSubstr("collinear"));
}

// Corners of a target at `radius` and `height` on the table, seen at `steps` table angles.
std::vector<Eigen::Vector3d> Track(double radius, double height, double phase, int steps, double noise_mm,
                                   std::mt19937* rng) {
  std::normal_distribution<double> noise(0.0, noise_mm);
  const Eigen::Vector3d u = kAxisDirection.unitOrthogonal();
  const Eigen::Vector3d start = kAxisPoint + height * kAxisDirection + radius * u;
  std::vector<Eigen::Vector3d> out;
  for (int i = 0; i < steps; ++i) {
    const Eigen::Vector3d p =
        geometry::RotationAboutAxis(kAxisPoint, kAxisDirection, phase + geometry::DegToRad(10.0 * i)) * start;
    out.push_back(p + (noise_mm > 0 ? Eigen::Vector3d(noise(*rng), noise(*rng), noise(*rng))
                                    : Eigen::Vector3d::Zero()));
  }
  return out;
}

TEST(AxisFitTest, FromTracksWithNoise) {
  // 12 corners over 90 degrees of table rotation, 0.02 mm noise: axis within 0.05 mm and 0.05 degrees.
  std::mt19937 rng(11);
  std::vector<std::vector<Eigen::Vector3d>> tracks;
  for (int k = 0; k < 12; ++k) tracks.push_back(Track(30.0 + 5 * k, 2.0 * k, 0.3 * k, 10, 0.02, &rng));
  const auto fit = FitAxisFromTracks(tracks);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  EXPECT_LT(AngleDeg(fit->direction, kAxisDirection), 0.05);
  EXPECT_LT(DistanceToTrueAxis(fit->point), 0.05);
  // The residual reflects the noise: 0.02 mm per coordinate is ~0.035 mm in 3D, plus the centres' spread.
  EXPECT_LT(fit->rms_mm, 0.1);
  EXPECT_GT(fit->rms_mm, 0.02);
}

TEST(AxisFitTest, FromPosesExact) {
  const Eigen::Isometry3d cam_from_target0 =
      Eigen::Translation3d(20, 40, 280) * Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized());
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < 6; ++i) {
    poses.push_back(geometry::RotationAboutAxis(kAxisPoint, kAxisDirection, geometry::DegToRad(7.5 * i)) *
                    cam_from_target0);
  }
  const auto fit = FitAxisFromPoses(poses);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  EXPECT_THAT(fit->direction, EigenNear(kAxisDirection, 1e-9));  // oriented by the turn
  EXPECT_LT(DistanceToTrueAxis(fit->point), 1e-9);
  EXPECT_NEAR(fit->mean_step_rad, geometry::DegToRad(7.5), 1e-12);
  EXPECT_LT(fit->rms_mm, 1e-9);
}

TEST(AxisFitTest, FromPosesRejectsNoTurn) {
  const Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  EXPECT_THAT(FitAxisFromPoses({pose}).status().message(), HasSubstr("at least 2"));
  EXPECT_THAT(FitAxisFromPoses({pose, pose, pose}).status().message(), HasSubstr("did not turn"));
}

TEST(AxisFitTest, FromTracksRejectsDegenerateTrack) {
  std::mt19937 rng(1);
  std::vector<std::vector<Eigen::Vector3d>> tracks = {Track(40, 0, 0, 5, 0, &rng), {{0, 0, 1}, {0, 0, 2}}};
  EXPECT_THAT(FitAxisFromTracks(tracks).status().message(), HasSubstr("track 1"));
  EXPECT_FALSE(FitAxisFromTracks({}).ok());
}

}  // namespace
}  // namespace rotoscan::calib
