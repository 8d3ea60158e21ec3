#include "capture_hil_rig.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <string>
#include <thread>
#include <utility>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/capture/clock.h"
#include "rotoscan/device/client.h"
#include "rotoscan/pipeline/process.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::capture::testing {

namespace fs = std::filesystem;

Eigen::Vector3d HilSphereCentre() {
  return {12.0, 0.0, 20.0};
}

void WriteHilScene(const fs::path& path) {
  std::ofstream(path) << R"({"camera": {"width": 256, "height": 192, "hfov_deg": 20},
      "objects": [{"type": "sphere", "radius_mm": 20, "position_mm": [12, 0, 0], "color": [0.8, 0.8, 0.8]}]})";
}

HilRig OpenHilRig(const fs::path& scene_path, RigTruth* truth, int reconnect_ms, const std::string& board_spec,
                  const std::vector<std::string>& camera_options) {
  HilRig rig;
  rig.context.scene_path = scene_path.string();
  rig.context.truth = truth;
  rig.context.options = {"steps_per_rev=" + std::to_string(kHilStepsPerRev),
                         "reconnect_ms=" + std::to_string(reconnect_ms)};
  auto board = OpenBoard(board_spec, &rig.context);
  EXPECT_TRUE(board.ok()) << board.status().ToString();
  if (!board.ok()) return rig;
  rig.board = std::move(board).value();
  rig.context.board = rig.board.get();
  rig.context.options = camera_options;
  auto camera = OpenCamera("virtual", rig.context);
  EXPECT_TRUE(camera.ok()) << camera.status().ToString();
  if (camera.ok()) rig.camera = std::move(camera).value();
  return rig;
}

ScanOptions HilScanOptions(int steps, const fs::path& scene_path, RigTruth* truth, int* checked,
                           std::function<void(const CapturedFrame&)> then, const std::string& created_by) {
  ScanOptions o;
  o.steps = steps;
  o.timing = Timing::kTriggered;
  o.frame_rate_hz = 30.0;
  o.header.kind = bundle::BundleKind::kScan;
  o.header.created_by = created_by;
  auto scene = sim::LoadScene(scene_path);
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  o.header.camera.name = "virtual";
  if (scene.ok()) o.header.camera.model = scene.value().rig.camera;
  o.header.camera.laser_exposure_us = 2000;
  o.header.camera.natural_exposure_us = 20000;
  o.on_frame = [truth, checked, then = std::move(then)](const CapturedFrame& c) {
    const int64_t start = c.frame->exposure_start_us;
    const int64_t end = c.frame->ExposureEndUs();
    EXPECT_TRUE(truth->LaserSwitches(start, end).empty())
        << "step " << c.step << " " << bundle::LaserStateName(c.laser) << " exposed across a laser switch";
    double left = 0, right = 0;
    truth->LaserFractions(start, end, &left, &right);
    EXPECT_EQ(left, c.laser == bundle::LaserState::kLeft ? 1.0 : 0.0) << "step " << c.step;
    EXPECT_EQ(right, c.laser == bundle::LaserState::kRight ? 1.0 : 0.0) << "step " << c.step;
    EXPECT_NEAR(truth->TableAngleAt(start), c.table_angle_rad, 1e-9) << "step " << c.step;
    EXPECT_NEAR(truth->TableAngleAt(end), c.table_angle_rad, 1e-9) << "step " << c.step;
    ++*checked;
    if (then) then(c);
    return Status::Ok();
  };
  return o;
}

void CheckHilBundleAndCloud(const fs::path& bundle_dir, const fs::path& scene_path, int steps) {
  auto bundle = bundle::ReadBundle(bundle_dir);
  ASSERT_TRUE(bundle.ok()) << bundle.status().ToString();
  std::map<std::pair<int, int>, int> count;
  for (const auto& f : bundle.value().frames) ++count[{f.step, static_cast<int>(f.laser)}];
  EXPECT_EQ(count.size(), static_cast<size_t>(steps * 4));
  for (const auto& [key, n] : count) EXPECT_EQ(n, 1) << "step " << key.first << " laser " << key.second;
  auto scene = sim::LoadScene(scene_path);
  ASSERT_TRUE(scene.ok());
  auto processed = pipeline::ProcessBundle(bundle_dir, scene.value().rig, pipeline::ProcessOptions{});
  ASSERT_TRUE(processed.ok()) << processed.status().ToString();
  const auto& cloud = processed.value().cloud;
  ASSERT_GT(cloud.size(), static_cast<size_t>(steps * 25));
  const Eigen::Vector3d centre = HilSphereCentre();
  double sum2 = 0.0, worst = 0.0;
  for (const auto& point : cloud.points) {
    const double d = std::abs((point.position_in_table.cast<double>() - centre).norm() - kHilSphereRadiusMm);
    sum2 += d * d;
    worst = std::max(worst, d);
  }
  const double rms = std::sqrt(sum2 / static_cast<double>(cloud.size()));
  std::printf("cloud: %zu points, %.4f mm RMS from the true sphere, worst %.3f mm\n", cloud.size(), rms,
              worst);
  EXPECT_LT(rms, kHilRmsToleranceMm);
  EXPECT_LT(worst, kHilWorstToleranceMm);
}

void ExpectReconnectWindowError(const Status& status, int reconnect_ms) {
  ASSERT_FALSE(status.ok());
  std::printf("the scan stopped: %s\n", status.ToString().c_str());
  EXPECT_EQ(status.code(), StatusCode::kDeviceError) << status.ToString();
  EXPECT_NE(status.message().find(std::to_string(reconnect_ms) + " ms"), std::string::npos)
      << status.ToString();
}

void ExpectLaserSafetyAfterUnplug(RigTruth& truth, int64_t unplugged_at) {
  const int64_t timeout_us = device::MotionConfig{}.laser_timeout_ms * 1000LL;
  // The board's own laser timeout runs in real time: one wait until it has passed (with 0.3 s to spare).
  const int64_t wait_us = unplugged_at + timeout_us + 300'000 - MonotonicNowUs();
  if (wait_us > 0) std::this_thread::sleep_for(std::chrono::microseconds(wait_us));
  const int64_t now = MonotonicNowUs();
  double left = 1.0, right = 1.0;
  truth.LaserFractions(now - 1000, now, &left, &right);
  EXPECT_EQ(left, 0.0) << "left laser still on";
  EXPECT_EQ(right, 0.0) << "right laser still on";
  // The unplug comes from the frame hook, so it lags the board by the host's writing: on a loaded machine
  // the board's program had already ended (or its laser safety had stopped it during a long write), and
  // with no switch since the unplug the lasers, off now, were off then. Otherwise the last switch after it
  // is the safety's, on time.
  const auto switches = truth.LaserSwitches(unplugged_at, now);
  if (switches.empty()) return;
  EXPECT_LE(switches.back(), unplugged_at + timeout_us + 200'000) << "lasers went off late";
}

void RunUnplugBeyondTheReconnectWindow(const UnplugBeyondRig& u) {
  auto context = [&u] { return u.context ? " / " + u.context() : std::string(); };
  const fs::path out = u.dir / "b";
  int64_t unplugged_at = 0;
  {
    HilRig rig = u.open();
    ASSERT_NE(rig.camera, nullptr);
    *u.on_frame = [&](const CapturedFrame& c) {
      if (c.step == 6 && unplugged_at == 0) {
        unplugged_at = MonotonicNowUs();
        u.unplug();
      }
    };
    auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, out, u.options(), nullptr);
    ExpectReconnectWindowError(summary.status(), 1000);
  }
  *u.on_frame = nullptr;
  EXPECT_TRUE(fs::exists(u.dir / "b.partial"));
  EXPECT_FALSE(fs::exists(out));
  // The host could not reach the board: the board's laser safety turned the lasers off after its timeout
  // (MotionConfig::laser_timeout_ms, which the `usb` backend sets) of silence, on the pins.
  ExpectLaserSafetyAfterUnplug(*u.truth, unplugged_at);

  u.replug();
  HilRig rig = u.open();
  ASSERT_NE(rig.camera, nullptr);
  ScanOptions o = u.options();
  o.resume = true;
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, out, o, nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString() << context();
  std::printf("resumed: %s\n", summary.value().Summary().c_str());
  EXPECT_GE(summary.value().steps_resumed, 5);
  EXPECT_LT(summary.value().steps_resumed, u.steps);
  rig.board.reset();
  CheckHilBundleAndCloud(out, u.scene_path, u.steps);
  if (u.context) {
    EXPECT_EQ(u.context(), "");
  }
}

}  // namespace rotoscan::capture::testing
