// The rig calibration on rendered calibration bundles, against the virtual scanner's truth: the table
// checkerboard in the demo's three placements (data/scenes/calibration*.json), rendered with the default
// noise and speckle, turned through kSteps table angles each, then `rotoscan calibrate`'s observations
// (pipeline/calibrate.h), the paper's three steps and the joint refinement. Targets (DESIGN.md, issue 5):
// reprojection RMS <= 0.1 px, focal length within 0.1 %, laser plane normals within 0.05 deg and offsets
// within 0.05 mm, table axis within 0.05 mm and 0.05 deg.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "rotoscan/bundle/truth.h"
#include "rotoscan/calib/rig_calibration.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/pipeline/calibrate.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"
#include "rig_errors.h"
#include "testing/testing.h"

namespace rotoscan::pipeline {
namespace {

using rotoscan::testing::DataPath;
using rotoscan::testing::ScratchDir;

// Table angles per placement (the demo renders 24; 16 keep the test near 40 s on one core, with the axis
// position's standard deviation, 0.031 mm, inside the report's 0.05 mm check, and the axis 0.016 mm from
// the truth).
constexpr int kSteps = 16;

using rotoscan::testing::AxisAngleDeg;
using rotoscan::testing::AxisDistanceMm;
using rotoscan::testing::NormalErrorDeg;
using rotoscan::testing::OffsetErrorMm;

struct Rendered {
  std::vector<std::filesystem::path> bundles;
  geometry::Rig truth;
  calib::CalibrationData data;
};

// Renders the three placements into `dir` and reads their observations as `rotoscan calibrate` does.
void Render(const ScratchDir& dir, Rendered* out) {
  for (const char* name : {"calibration.json", "calibration-2.json", "calibration-3.json"}) {
    Result<sim::Scene> scene = sim::LoadScene(DataPath(std::string("scenes/") + name));
    ASSERT_TRUE(scene.ok()) << scene.status().ToString();
    sim::SimulateOptions options;
    options.out = dir / name;
    options.kind = sim::SimulateKind::kTableCheckerboard;
    options.steps = kSteps;
    const Status simulated = sim::Simulate(*scene, options, nullptr);
    ASSERT_TRUE(simulated.ok()) << simulated.ToString();
    out->bundles.push_back(options.out);
  }
  Result<geometry::Rig> truth = geometry::ReadRigYaml(bundle::TruthRigPath(out->bundles[0]));
  ASSERT_TRUE(truth.ok()) << truth.status().ToString();
  out->truth = *truth;
  Result<calib::CalibrationData> data = ObservationsFromBundles(out->bundles, nullptr);
  ASSERT_TRUE(data.ok()) << data.status().ToString();
  out->data = *data;
}

// One test (rendering is most of its time, and ctest runs each test in its own process).
TEST(RenderedCalibrationTest, ThreePlacementsMeetTheTargetsAgainstTruth) {
  ScratchDir dir;
  Rendered r;
  ASSERT_NO_FATAL_FAILURE(Render(dir, &r));
  const calib::CalibrationData& data = r.data;
  const geometry::Rig& truth = r.truth;
  // The board is found in every view but the most turned ones of the upright placements (where the 4 mm
  // squares are foreshortened most).
  ASSERT_GE(data.target_views.size(), 3u * kSteps - 8u);
  const calib::RigCalibrationOptions options;
  const auto initial = calib::CalibrateThreeStep(data, options);
  ASSERT_TRUE(initial.ok()) << initial.status().ToString();
  const auto refined = calib::RefineRig(data, *initial, options);
  ASSERT_TRUE(refined.ok()) << refined.status().ToString();
  const geometry::Rig& rig = refined->estimate.rig;
  const calib::RigCalibrationSummary& s = refined->summary;
  std::printf("rendered, %d placements x %d steps, joint vs truth: reprojection %.4f px, fx %.4f %%, "
              "normals %.4f / %.4f deg, offsets %.4f / %.4f mm, axis %.4f mm %.4f deg (std %.4f mm), laser "
              "residual %.4f / %.4f mm\n",
              s.placements, kSteps, s.rms_px, 100 * std::abs(rig.camera.fx / truth.camera.fx - 1),
              NormalErrorDeg(rig.laser_plane[0], truth.laser_plane[0]),
              NormalErrorDeg(rig.laser_plane[1], truth.laser_plane[1]),
              OffsetErrorMm(rig.laser_plane[0], truth.laser_plane[0]),
              OffsetErrorMm(rig.laser_plane[1], truth.laser_plane[1]), AxisDistanceMm(rig, truth),
              AxisAngleDeg(rig, truth), s.std_devs.axis_point_mm, s.laser_rms_mm[0], s.laser_rms_mm[1]);
  EXPECT_TRUE(s.converged) << s.termination;
  EXPECT_TRUE(s.passed) << (s.failures.empty() ? "" : s.failures[0]);
  EXPECT_LE(s.rms_px, 0.1);
  EXPECT_NEAR(rig.camera.fx, truth.camera.fx, 0.001 * truth.camera.fx);
  EXPECT_NEAR(rig.camera.fy, truth.camera.fy, 0.001 * truth.camera.fy);
  for (int l = 0; l < 2; ++l) {
    EXPECT_LT(NormalErrorDeg(rig.laser_plane[l], truth.laser_plane[l]), 0.05) << l;
    EXPECT_LT(OffsetErrorMm(rig.laser_plane[l], truth.laser_plane[l]), 0.05) << l;
  }
  EXPECT_LT(AxisDistanceMm(rig, truth), 0.05);
  EXPECT_LT(AxisAngleDeg(rig, truth), 0.05);
  // The table frame's origin on the table top (the bundles carry the target's height above it): the
  // along-axis offset from the true table top. Without the height it was the board's first inner corner,
  // 49 mm up, and a cloud from this rig sat that far from the true mesh.
  EXPECT_TRUE(s.table_origin_on_table_top);
  const Eigen::Vector3d top_off = rig.axis_point_in_cam - truth.axis_point_in_cam;
  EXPECT_LT(std::abs(truth.axis_direction_in_cam.dot(top_off)), 0.1);  // one placement's pose precision
  EXPECT_NEAR(rig.step_angle_rad, truth.step_angle_rad, 1e-5 * truth.step_angle_rad);

  // Regression (the demo's left laser, 0.048 mm plane residual against 0.011 mm for the right): at one table
  // angle the left line ran along a column edge of the checker, where the black/white step under its
  // profile pulled the extracted centre 2.3 px towards the white square. Such pixels are dropped now: with
  // the true rig and the true target poses, every kept laser point lies on its true laser plane to the
  // extraction noise, for both lasers alike.
  std::array<double, 2> sum_sq{};
  std::array<int, 2> count{};
  std::array<double, 2> worst{};
  for (const calib::LaserView& view : data.laser_views) {
    Result<std::vector<bundle::TargetPose>> poses =
        bundle::ReadTargetPoses(bundle::TruthPosesPath(r.bundles[view.placement]));
    ASSERT_TRUE(poses.ok()) << poses.status().ToString();
    const bundle::TargetPose* pose = nullptr;
    for (const auto& p : *poses) {
      if (p.step == view.step) pose = &p;
    }
    ASSERT_NE(pose, nullptr) << view.name;
    const Eigen::Vector3d m = pose->cam_from_target.linear() * view.plane_in_target.head<3>();
    const Eigen::Vector3d o =
        pose->cam_from_target * Eigen::Vector3d(-view.plane_in_target(3) * view.plane_in_target.head<3>());
    const int l = static_cast<int>(view.laser);
    for (const Eigen::Vector2d& pixel : view.pixels) {
      const Eigen::Vector3d ray = truth.camera.PixelToRay(pixel);
      const double d = truth.laser_plane[l].SignedDistance(ray * (m.dot(o) / m.dot(ray)));
      sum_sq[l] += d * d;
      worst[l] = std::max(worst[l], std::abs(d));
      ++count[l];
    }
  }
  for (int l = 0; l < 2; ++l) {
    ASSERT_GT(count[l], 1000) << l;
    const double rms = std::sqrt(sum_sq[l] / count[l]);
    std::printf("laser %d: %d points, %.4f mm RMS (worst %.4f mm) from the true plane\n", l, count[l], rms,
                worst[l]);
    EXPECT_LT(rms, 0.015) << l;
    EXPECT_LT(worst[l], 0.1) << l;
  }
}

}  // namespace
}  // namespace rotoscan::pipeline
