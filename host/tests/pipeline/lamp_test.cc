// Lamp calibration from a white sphere (pipeline/lamp.h) against the renderer's own lamp, and the lamp's
// place in calib.yaml (geometry/rig.h).
#include "rotoscan/pipeline/lamp.h"

#include <algorithm>
#include <cmath>

#include <gtest/gtest.h>

#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"
#include "testing/testing.h"

namespace rotoscan::pipeline {
namespace {

// data/scenes/lamp-sphere.json (a 20 mm white sphere under the default lamp: ambient 0.3, diffuse 1 from
// (0.3, -1, -1) in the camera frame), 4 steps, with the true rig. Measured: direction 0.005° off,
// diffuse/ambient 3.327 against 3.333 (the lamp.h fit over ~560,000 pixels).
TEST(LampTest, CalibratedFromAWhiteSphereMatchesTheRenderersLamp) {
  testing::ScratchDir dir;
  auto scene = sim::LoadScene(testing::DataPath("scenes/lamp-sphere.json"));
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  sim::SimulateOptions simulate;
  simulate.out = dir / "sphere";
  simulate.steps = 4;
  simulate.step_deg = 90;
  ASSERT_TRUE(sim::Simulate(*scene, simulate, nullptr).ok());
  auto lamp = CalibrateLamp(dir / "sphere", scene->rig, {});
  ASSERT_TRUE(lamp.ok()) << lamp.status().ToString();
  const Eigen::Vector3d truth = scene->diffuse / scene->ambient * scene->light_direction_in_cam.normalized();
  const double off_deg = geometry::RadToDeg(
      std::acos(std::clamp(lamp->lamp_in_cam.normalized().dot(truth.normalized()), -1.0, 1.0)));
  EXPECT_LT(off_deg, 0.5) << lamp->lamp_in_cam.transpose();
  EXPECT_NEAR(lamp->lamp_in_cam.norm(), truth.norm(), 0.03 * truth.norm());
  EXPECT_NEAR(lamp->sphere_radius_mm, 20.0, 0.05);
  EXPECT_LT((lamp->sphere_centre_in_table - Eigen::Vector3d(0, 0, 20)).norm(), 0.1);
  EXPECT_EQ(lamp->frames, 4);

  // Into calib.yaml: the other keys (here a report's) kept, an earlier lamp replaced, read back by the rig.
  const std::filesystem::path calib = dir / "calib.yaml";
  ASSERT_TRUE(geometry::WriteRigYaml(calib, scene->rig).ok());
  auto text = ReadFile(calib);
  ASSERT_TRUE(text.ok());
  ASSERT_TRUE(WriteFileAtomically(calib, *text + "report_rms_px: 0.25\n").ok());
  auto before = geometry::ReadRigYaml(calib);
  ASSERT_TRUE(before.ok());
  EXPECT_FALSE(before->lamp_in_cam.has_value()) << "a file without the key has no lamp";
  ASSERT_TRUE(WriteLampIntoCalibration(calib, Eigen::Vector3d(1, 2, 3)).ok());
  ASSERT_TRUE(WriteLampIntoCalibration(calib, lamp->lamp_in_cam).ok());
  auto after = geometry::ReadRigYaml(calib);
  ASSERT_TRUE(after.ok()) << after.status().ToString();
  ASSERT_TRUE(after->lamp_in_cam.has_value());
  EXPECT_THAT(*after->lamp_in_cam, testing::EigenNear(lamp->lamp_in_cam, 1e-12));
  auto final_text = ReadFile(calib);
  ASSERT_TRUE(final_text.ok());
  EXPECT_NE(final_text->find("report_rms_px: 0.25"), std::string::npos);
  EXPECT_EQ(final_text->find("lamp:"), final_text->rfind("lamp:")) << "one lamp key";
  EXPECT_FALSE(WriteLampIntoCalibration(calib, Eigen::Vector3d(NAN, 0, 0)).ok());
  EXPECT_FALSE(WriteLampIntoCalibration(dir / "missing.yaml", Eigen::Vector3d(1, 0, 0)).ok());
  geometry::Rig bad = scene->rig;
  bad.lamp_in_cam = Eigen::Vector3d(INFINITY, 0, 0);
  EXPECT_FALSE(bad.Validate().ok());

  LampCalibrationOptions options;
  options.max_frames = 0;
  EXPECT_EQ(CalibrateLamp(dir / "sphere", scene->rig, options).status().code(), StatusCode::kInvalidArgument);
}

// A scan without a sphere (a box) is refused with a message that names what is needed.
TEST(LampTest, NoSphereIsAClearError) {
  testing::ScratchDir dir;
  auto scene = sim::ParseScene(
      R"({"preset": "machine_vision", "objects": [{"type": "box", "size_mm": [30, 30, 30]}]})", ".",
      "box.json");
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  sim::SimulateOptions simulate;
  simulate.out = dir / "box";
  simulate.steps = 2;
  simulate.step_deg = 45;
  simulate.truth = false;
  ASSERT_TRUE(sim::Simulate(*scene, simulate, nullptr).ok());
  auto lamp = CalibrateLamp(dir / "box", scene->rig, {});
  ASSERT_FALSE(lamp.ok());
  EXPECT_EQ(lamp.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(lamp.status().message().find("sphere"), std::string::npos) << lamp.status().ToString();
}

}  // namespace
}  // namespace rotoscan::pipeline
