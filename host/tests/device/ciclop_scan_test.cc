// Issue 13's Ciclop test: the horus-fw dialect over a pseudo-terminal (FakeCiclop, real time, real termios)
// with the virtual camera free-running at 30 frames/s with a rolling shutter, through capture::RunScan,
// ending in a cloud. Checked against the fake board's own record of when the lasers switched and where the
// table was: no frame written was exposed (any row) across a laser switch or while the table turned, and
// the cloud lies on the true surface (an off-axis sphere, so a frame taken at the wrong table angle would
// put its points off it). The same with faults: a lost "ok", the board unplugged for 300 ms mid-scan and a
// frame the camera dropped, ending in a complete bundle.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include "fake_ciclop.h"
#include "fake_ciclop_truth.h"
#include "rotoscan/bundle/bundle.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/capture/scan.h"
#include "rotoscan/capture/virtual_rig.h"
#include "rotoscan/pipeline/process.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::capture {
namespace {

namespace fs = std::filesystem;
using device::testing::FakeCiclop;
using device::testing::FakeCiclopTruth;
using device::testing::FakeCiclopOptions;

constexpr double kRadPerDeg = M_PI / 180.0;

void CiclopScan(bool faults) {
  const fs::path dir = fs::temp_directory_path() /
                       ("rotoscan_ciclop_scan_" + std::to_string(::getpid()) + (faults ? "_faults" : ""));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const fs::path scene_path = dir / "scene.json";
  const Eigen::Vector3d centre(12.0, 0.0, 20.0);  // a sphere rests on its position (sim/mesh.cc)
  const double radius = 20.0;
  std::ofstream(scene_path) << R"({"camera": {"width": 256, "height": 192, "hfov_deg": 20},
    "objects": [{"type": "sphere", "radius_mm": 20, "position_mm": [12, 0, 0], "color": [0.8, 0.8, 0.8]}]})";

  FakeCiclopOptions fake_options;  // horus-fw's defaults: 176 steps/deg, 180 deg/s, 180 deg/s^2
  fake_options.link_path = (dir / "ttyUSB0").string();
  FakeCiclop fake(fake_options);
  ASSERT_TRUE(fake.Start()) << fake.error();
  FakeCiclopTruth truth(&fake);

  OpenContext context;
  context.scene_path = scene_path.string();
  context.truth = &truth;
  context.options = {"rolling=1", "ok_timeout_ms=2000"};
  if (faults) context.options.push_back("drop=25");  // the camera loses its frame 25  // no lost "ok" here: only a bound on a failure
  auto board = OpenBoard("ciclop:" + fake_options.link_path, &context);
  ASSERT_TRUE(board.ok()) << board.status().ToString();
  context.board = board.value().get();
  auto camera = OpenCamera("virtual", context);
  ASSERT_TRUE(camera.ok()) << camera.status().ToString();
  ASSERT_TRUE(camera.value()->capabilities().rolling_shutter);

  auto scene = sim::LoadScene(scene_path);
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  ScanOptions o;
  o.steps = 4;
  o.step_deg = 4.0;  // 0.3 s moves on horus-fw's defaults
  o.timing = Timing::kFreeRunning;
  o.frame_rate_hz = 30.0;
  o.header.kind = bundle::BundleKind::kScan;
  o.header.created_by = "ciclop_scan_test";
  o.header.camera.name = "virtual";
  o.header.camera.model = scene.value().rig.camera;
  o.header.camera.laser_exposure_us = 2000;
  o.header.camera.natural_exposure_us = 20000;
  int checked = 0;
  bool lost_ok = false, unplugged = false;
  std::thread replug;
  o.on_frame = [&](const CapturedFrame& c) {
    if (faults && c.step == 1 && !lost_ok) {
      lost_ok = true;
      fake.LoseOks(1);
    }
    if (faults && c.step == 2 && !unplugged) {
      unplugged = true;
      fake.Unplug();
      replug = std::thread([&fake] {
        std::this_thread::sleep_for(std::chrono::milliseconds(300));  // the injected unplug
        fake.Replug();
      });
    }
    const int64_t start = c.frame->exposure_start_us;
    const int64_t end = c.frame->ExposureEndUs();
    const auto switches = truth.LaserSwitches(start, end);
    EXPECT_TRUE(switches.empty()) << "step " << c.step << " " << bundle::LaserStateName(c.laser)
                                  << " exposed across a laser switch";
    double left = 0, right = 0;
    truth.LaserFractions(start, end, &left, &right);
    EXPECT_EQ(left, c.laser == bundle::LaserState::kLeft ? 1.0 : 0.0) << "step " << c.step;
    EXPECT_EQ(right, c.laser == bundle::LaserState::kRight ? 1.0 : 0.0) << "step " << c.step;
    // The table stood still at the step's angle for the whole exposure.
    EXPECT_NEAR(truth.TableAngleAt(start), c.table_angle_rad, 0.5 / 176.0 * kRadPerDeg) << "step " << c.step;
    EXPECT_NEAR(truth.TableAngleAt(end), c.table_angle_rad, 0.5 / 176.0 * kRadPerDeg) << "step " << c.step;
    ++checked;
    return Status::Ok();
  };
  auto summary = RunScan(*board.value(), *camera.value(), *context.clock, dir / "b", o, nullptr);
  if (replug.joinable()) replug.join();
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  std::printf("%s\n", summary.value().Summary().c_str());
  EXPECT_EQ(checked, 16);
  EXPECT_EQ(summary.value().frames_used, 16);
  EXPECT_EQ(unplugged, faults);
  if (faults) {
    EXPECT_GE(summary.value().frames_dropped, 1);
  }
  EXPECT_GE(fake.moves().size(), 3u);  // steps 1..3 (step 0 is where the table stands)
  if (!faults) {
    EXPECT_LE(fake.moves().size(), 4u);  // none repeated
  }
  EXPECT_FALSE(fake.LaserAt(1, MonotonicNowUs()));
  EXPECT_FALSE(fake.LaserAt(2, MonotonicNowUs()));

  // The cloud, with the true rig: every point on the sphere.
  auto processed = pipeline::ProcessBundle(dir / "b", scene.value().rig, pipeline::ProcessOptions{});
  ASSERT_TRUE(processed.ok()) << processed.status().ToString();
  const auto& cloud = processed.value().cloud;
  ASSERT_GT(cloud.size(), 120u);
  double sum2 = 0.0;
  double worst = 0.0;
  for (const auto& point : cloud.points) {
    const Eigen::Vector3d p = point.position_in_table.cast<double>();
    const double d = std::abs((p - centre).norm() - radius);
    sum2 += d * d;
    worst = std::max(worst, d);
  }
  const double rms = std::sqrt(sum2 / static_cast<double>(cloud.size()));
  std::printf("cloud: %zu points, %.4f mm RMS from the true sphere, worst %.3f mm\n", cloud.size(), rms, worst);
  EXPECT_LT(rms, 0.1);
  EXPECT_LT(worst, 1.0);
  board.value().reset();
  fs::remove_all(dir);
}

TEST(CiclopScan, FreeRunningRollingShutterOverAPtyEndsInACloudOnTheSurface) { CiclopScan(false); }

TEST(CiclopScan, LostOkUnplugAndDroppedFrameEndInACompleteBundle) { CiclopScan(true); }

}  // namespace
}  // namespace rotoscan::capture
