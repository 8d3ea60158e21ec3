// The capture module in virtual time: the firmware core on the host (sim board) and the virtual scanner
// as the camera. Checked against the simulator's own record of when the lasers switched (its pin-edge
// log: RigTruth), and, through processing, against the true surface of the scanned object.
#include <filesystem>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <set>

#include <unistd.h>

#include <gtest/gtest.h>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/capture/scan.h"
#include "rotoscan/capture/virtual_rig.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/pipeline/evaluate.h"
#include "rotoscan/pipeline/process.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::capture {
namespace {

namespace fs = std::filesystem;

class CaptureTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("rotoscan_capture_" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()) +
            "_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    scene_path_ = dir_ / "scene.json";
    std::ofstream(scene_path_) << R"({"camera": {"width": 256, "height": 192, "hfov_deg": 20},
      "objects": [{"type": "sphere", "radius_mm": 30, "position_mm": [0, 0, 0], "color": [0.8, 0.8, 0.8]}]})";
  }
  void TearDown() override { fs::remove_all(dir_); }

  struct Rig {
    std::unique_ptr<Board> board;
    std::unique_ptr<Camera> camera;
    OpenContext context;
  };
  Rig Open(std::vector<std::string> options) {
    Rig rig;
    rig.context.scene_path = scene_path_.string();
    rig.context.options = std::move(options);
    auto board = OpenBoard("sim", &rig.context);
    EXPECT_TRUE(board.ok()) << board.status().ToString();
    rig.board = std::move(board).value();
    rig.context.board = rig.board.get();
    auto camera = OpenCamera("virtual", rig.context);
    EXPECT_TRUE(camera.ok()) << camera.status().ToString();
    rig.camera = std::move(camera).value();
    return rig;
  }
  ScanOptions Options(int steps) {
    ScanOptions o;
    o.steps = steps;
    o.step_deg = 360.0 / 192;  // 100 motor steps of the sim board
    o.header.kind = bundle::BundleKind::kScan;
    o.header.created_by = "capture_test";
    auto scene = sim::LoadScene(scene_path_);
    o.header.camera.name = "virtual";
    o.header.camera.model = scene.value().rig.camera;
    o.header.camera.laser_exposure_us = 2000;
    o.header.camera.natural_exposure_us = 20000;
    return o;
  }

  fs::path dir_;
  fs::path scene_path_;
};

TEST_F(CaptureTest, FactoryErrors) {
  OpenContext context;
  auto unknown = OpenBoard("nosuch", &context);
  EXPECT_EQ(unknown.status().code(), StatusCode::kInvalidArgument);
  auto camera = OpenCamera("virtual", context);  // no sim board
  EXPECT_EQ(camera.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_EQ(ParseSpec(":x").status().code(), StatusCode::kInvalidArgument);
  const auto spec = ParseSpec("v4l2:/dev/video0").value();
  EXPECT_EQ(spec.backend, "v4l2");
  EXPECT_EQ(spec.argument, "/dev/video0");
  // A backend the project has but this build may lack is kUnimplemented, not "unknown".
  const auto built = BuiltCameraBackends();
  if (std::find(built.begin(), built.end(), "aravis") == built.end()) {
    EXPECT_EQ(OpenCamera("aravis", context).status().code(), StatusCode::kUnimplemented);
  }
}

// Free-running, rolling shutter at 30 frames/s: every frame written was exposed, all rows, inside one laser
// state, by the simulator's own record of the switches.
// The camera delivers each frame 8 ms after its last row (a USB transfer): a change issued on its arrival
// falls inside the next frame's exposure, which must then be refused.
TEST_F(CaptureTest, FreeRunningRollingShutterNoFrameAcrossASwitch) {
  Rig rig = Open({"rolling=1", "latency_ms=8"});
  ASSERT_TRUE(rig.camera->capabilities().rolling_shutter);
  ScanOptions o = Options(6);
  o.timing = Timing::kFreeRunning;
  RigTruth* truth = rig.board->truth();
  int checked = 0;
  o.on_frame = [&](const CapturedFrame& c) {
    const auto switches = truth->LaserSwitches(c.frame->exposure_start_us, c.frame->ExposureEndUs());
    EXPECT_TRUE(switches.empty()) << "step " << c.step << " " << bundle::LaserStateName(c.laser)
                                  << " exposed across a switch at " << switches.front();
    double left = 0, right = 0;
    truth->LaserFractions(c.frame->exposure_start_us, c.frame->ExposureEndUs(), &left, &right);
    EXPECT_EQ(left, c.laser == bundle::LaserState::kLeft ? 1.0 : 0.0);
    EXPECT_EQ(right, c.laser == bundle::LaserState::kRight ? 1.0 : 0.0);
    ++checked;
    return Status::Ok();
  };
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", o, nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(checked, 24);
  EXPECT_EQ(summary.value().frames_used, 24);
  EXPECT_LE(summary.value().elapsed_us, 1.5 * summary.value().frames_time_us) << summary.value().Summary();
  auto bundle = bundle::ReadBundle(dir_ / "b");
  ASSERT_TRUE(bundle.ok()) << bundle.status().ToString();
  EXPECT_EQ(bundle.value().frames.size(), 24u);
  EXPECT_EQ(bundle.value().StepCount(), 6);
}

// The check above can fail: a rolling-shutter frame accepted right after a switch would show it.
TEST_F(CaptureTest, VirtualCameraShowsASwitchRowByRow) {
  Rig rig = Open({"rolling=1", "readout_ms=20"});
  CameraSettings s;
  s.exposure_us = 2000;
  ASSERT_TRUE(rig.camera->Configure(s).ok());
  ASSERT_TRUE(rig.camera->Start().ok());
  auto f0 = rig.camera->NextFrame(1'000'000).value().value();
  // Switch the left laser on in the middle of the next frame's readout.
  rig.context.clock->WaitUntilUs(f0.exposure_start_us + 33'333 + 10'000);
  ASSERT_TRUE(rig.board->SetLasers(kLaserLeft).ok());
  auto f1 = rig.camera->NextFrame(1'000'000).value().value();
  auto f2 = rig.camera->NextFrame(1'000'000).value().value();
  EXPECT_FALSE(rig.board->truth()->LaserSwitches(f1.exposure_start_us, f1.ExposureEndUs()).empty());
  // f2 is lit in every row; f1 only in its lower rows: compare the red of the top and bottom halves.
  auto red_sum = [](const cv::Mat& m, int r0, int r1) {
    double sum = 0;
    for (int r = r0; r < r1; ++r)
      for (int c = 0; c < m.cols; ++c) sum += m.at<cv::Vec3b>(r, c)[2];
    return sum;
  };
  const int h = f1.image.rows;
  const double top_ratio = red_sum(f1.image, 0, h / 4) / red_sum(f2.image, 0, h / 4);
  const double bottom_ratio = red_sum(f1.image, 3 * h / 4, h) / red_sum(f2.image, 3 * h / 4, h);
  EXPECT_LT(top_ratio, bottom_ratio - 0.02);
}

// Hardware-triggered with a dropped frame, an extra frame and lost packets: a complete bundle, every frame
// tied to the right trigger (its laser state and table position from the board's own edge log).
TEST_F(CaptureTest, TriggeredWithFaultsEndsComplete) {
  Rig rig = Open(getenv("NOFAULT") ? std::vector<std::string>{} : std::vector<std::string>{"drop=5", "extra=9", "lose_in_every=23"});
  ScanOptions o = Options(6);
  o.timing = Timing::kTriggered;
  RigTruth* truth = rig.board->truth();
  o.on_frame = [&](const CapturedFrame& c) {
    EXPECT_TRUE(truth->LaserSwitches(c.frame->exposure_start_us, c.frame->ExposureEndUs()).empty());
    double left = 0, right = 0;
    truth->LaserFractions(c.frame->exposure_start_us, c.frame->ExposureEndUs(), &left, &right);
    EXPECT_EQ(left, c.laser == bundle::LaserState::kLeft ? 1.0 : 0.0) << c.step;
    EXPECT_EQ(right, c.laser == bundle::LaserState::kRight ? 1.0 : 0.0) << c.step;
    EXPECT_NEAR(truth->TableAngleAt(c.frame->exposure_start_us), c.table_angle_rad, 1e-9);
    return Status::Ok();
  };
  // The progress bar counts steps and, beside them, every frame the camera delivered (its frames/s).
  ProgressBar bar(ProgressBar::Mode::kNever);
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", o, &bar);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  const auto& s = summary.value();
  EXPECT_EQ(s.frames_used, 24) << s.Summary();
  EXPECT_GE(s.frames_dropped, 1) << s.Summary();
  EXPECT_GE(s.shots_retaken, 1) << s.Summary();
  EXPECT_EQ(bar.done(), 6u);
  EXPECT_EQ(bar.secondary_done(), static_cast<uint64_t>(s.frames_captured));
  EXPECT_GT(bar.secondary_done(), 24u);  // the re-taken shots' frames too
  EXPECT_NE(bar.FormatLine(1.0).find("6/6 steps"), std::string::npos) << bar.FormatLine(1.0);
  auto bundle = bundle::ReadBundle(dir_ / "b");
  ASSERT_TRUE(bundle.ok());
  EXPECT_EQ(bundle.value().frames.size(), 24u);
}

}  // namespace
}  // namespace rotoscan::capture

namespace rotoscan::capture {
namespace {

// Stops the scan (as Ctrl-C does) once `after` steps are done.
class StopAfter : public Progress {
 public:
  explicit StopAfter(uint64_t after) : after_(after) {}
  void Begin(const std::string&, uint64_t) override {}
  void Advance(uint64_t n) override { done_ += n; }
  void End() override {}
  bool Cancelled() const override { return done_ >= after_; }

 private:
  uint64_t after_;
  uint64_t done_ = 0;
};

// Interrupted after 3 of 6 steps: lasers off, a partial bundle; resumed: complete, no step lost or taken
// twice. Then the unplug: the USB cable pulled mid-scan for 300 ms (the program stops on the board's
// laser safety and is resumed), a complete bundle.
TEST_F(CaptureTest, InterruptedScanResumesAndUnplugIsSurvived) {
  for (Timing timing : {Timing::kFreeRunning, Timing::kTriggered}) {
    SCOPED_TRACE(TimingName(timing));
    const fs::path out = dir_ / (std::string("b-") + TimingName(timing));
    {
      Rig rig = Open({});
      ScanOptions o = Options(6);
      o.timing = timing;
      StopAfter stop(3);
      auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, out, o, &stop);
      ASSERT_EQ(summary.status().code(), StatusCode::kCancelled);
      EXPECT_EQ(rig.board->lasers(), 0);
      EXPECT_TRUE(fs::exists(bundle::BundleWriter::PartialDirectory(out)));
      EXPECT_FALSE(fs::exists(out));
    }
    Rig rig = Open({});
    ScanOptions o = Options(6);
    o.timing = timing;
    o.resume = true;
    auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, out, o, nullptr);
    ASSERT_TRUE(summary.ok()) << summary.status().ToString();
    EXPECT_GE(summary.value().steps_resumed, 3);
    auto bundle = bundle::ReadBundle(out);
    ASSERT_TRUE(bundle.ok()) << bundle.status().ToString();
    EXPECT_EQ(bundle.value().frames.size(), 24u);
    for (int step = 0; step < 6; ++step) {
      for (auto s : {bundle::LaserState::kLeft, bundle::LaserState::kRight, bundle::LaserState::kOff,
                     bundle::LaserState::kNatural}) {
        EXPECT_GE(bundle.value().FindFrame(step, s), 0) << step;
      }
    }
  }
  Rig rig = Open({"unplug_at_ms=400", "unplug_for_ms=300"});
  ScanOptions o = Options(8);
  o.timing = Timing::kTriggered;
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "unplug", o, nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  auto bundle = bundle::ReadBundle(dir_ / "unplug");
  ASSERT_TRUE(bundle.ok());
  EXPECT_EQ(bundle.value().frames.size(), 32u) << summary.value().Summary();
}

// Issue 13's rare re-take failure: the host stalls while writing a frame (fsync on a busy disk took 25 s
// beside the other builds and two CPU hogs) for longer than the board's laser safety (2 s) and than the
// scan's no-frame limit (10 s). Meanwhile the board keeps raising edges until its laser safety stops the
// program, and the camera keeps their frames. The scan must count the silence from when it listens again:
// it reads what waited, resumes the stopped program and ends complete, instead of "no trigger edge and no
// frame for 10 s". Once in the first program and once in a one-step re-take (the failure was seen there);
// on the virtual clock, so the stall is exact and costs no real time.
TEST_F(CaptureTest, TriggeredHostStallLongerThanTheNoFrameLimitResumesAndEndsComplete) {
  Rig rig = Open({"drop=9"});  // frame 9 lost by the camera: step 2's shot is re-taken by a one-step program
  ScanOptions o = Options(16);  // long enough for the board's laser safety to stop the first program
  o.timing = Timing::kTriggered;
  RigTruth* truth = rig.board->truth();
  Clock& clock = *rig.context.clock;
  ASSERT_TRUE(clock.is_virtual());
  int frames_seen = 0;
  int stalls = 0;
  bool in_retake = false;
  std::set<std::pair<int, int>> written;
  o.on_frame = [&](const CapturedFrame& c) {
    EXPECT_TRUE(truth->LaserSwitches(c.frame->exposure_start_us, c.frame->ExposureEndUs()).empty()) << c.step;
    EXPECT_NEAR(truth->TableAngleAt(c.frame->exposure_start_us), c.table_angle_rad, 1e-9) << c.step;
    EXPECT_TRUE(written.insert({c.step, static_cast<int>(c.laser)}).second) << "step " << c.step << " written twice";
    ++frames_seen;
    // The first program writes steps in order; a frame of step 2 after step 3's is the re-take's.
    if (c.step == 2 && written.count({3, 0}) != 0) in_retake = true;
    if (frames_seen == 5 || (in_retake && stalls == 1)) {
      ++stalls;
      clock.WaitUntilUs(clock.NowUs() + 11'000'000);  // the host busy for 11 s: the board runs on
    }
    return Status::Ok();
  };
  auto summary = RunScan(*rig.board, *rig.camera, clock, dir_ / "b", o, nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  const auto& s = summary.value();
  EXPECT_EQ(stalls, 2) << s.Summary();
  EXPECT_EQ(s.frames_used, 64) << s.Summary();
  EXPECT_GE(s.shots_retaken, 1) << s.Summary();
  auto bundle = bundle::ReadBundle(dir_ / "b");
  ASSERT_TRUE(bundle.ok()) << bundle.status().ToString();
  EXPECT_EQ(bundle.value().frames.size(), 64u);
}

// A natural frame every 3 steps, hardware-triggered: the laser shots run as one board program and the
// natural frames as a second one whose moves are 3 steps long. Every frame against the simulator's pin log
// (one laser state over its exposure, the table at the step's angle); naturals at steps 0, 3, 6 only; the
// cloud on the true sphere, coloured from the natural frames where a step has one. Interrupted in the
// second program and resumed: no frame lost or taken twice.
TEST_F(CaptureTest, TriggeredNaturalEveryThreeStepsTwoProgramsAndResume) {
  constexpr int kSteps = 8;
  const fs::path out = dir_ / "b";
  RigTruth* truth = nullptr;
  int naturals = 0;
  auto check = [&](const CapturedFrame& c) {
    EXPECT_TRUE(truth->LaserSwitches(c.frame->exposure_start_us, c.frame->ExposureEndUs()).empty()) << c.step;
    double left = 0, right = 0;
    truth->LaserFractions(c.frame->exposure_start_us, c.frame->ExposureEndUs(), &left, &right);
    EXPECT_EQ(left, c.laser == bundle::LaserState::kLeft ? 1.0 : 0.0) << c.step;
    EXPECT_EQ(right, c.laser == bundle::LaserState::kRight ? 1.0 : 0.0) << c.step;
    EXPECT_NEAR(truth->TableAngleAt(c.frame->exposure_start_us), c.table_angle_rad, 1e-9) << c.step;
    EXPECT_NEAR(truth->TableAngleAt(c.frame->ExposureEndUs()), c.table_angle_rad, 1e-9) << c.step;
    EXPECT_EQ(c.frame->exposure_us, c.laser == bundle::LaserState::kNatural ? 20000 : 2000) << c.step;
    if (c.laser == bundle::LaserState::kNatural) {
      EXPECT_EQ(c.step % 3, 0) << c.step;
      ++naturals;
    }
    return Status::Ok();
  };
  {
    Rig rig = Open({});
    truth = rig.board->truth();
    ScanOptions o = Options(kSteps);
    o.timing = Timing::kTriggered;
    o.natural_every = 3;
    // Stop (as Ctrl-C does) after the first natural frame: inside the second program.
    o.on_frame = [&](const CapturedFrame& c) {
      (void)check(c);
      return naturals == 1 ? CancelledError("stopped for the test") : Status::Ok();
    };
    auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, out, o, nullptr);
    ASSERT_EQ(summary.status().code(), StatusCode::kCancelled) << summary.status().ToString();
    EXPECT_EQ(rig.board->lasers(), 0);
  }
  Rig rig = Open({});
  truth = rig.board->truth();
  ScanOptions o = Options(kSteps);
  o.timing = Timing::kTriggered;
  o.natural_every = 3;
  o.resume = true;
  o.on_frame = check;
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, out, o, nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(summary.value().frames_used, 2) << summary.value().Summary();  // the naturals of steps 3 and 6
  EXPECT_EQ(naturals, 3);
  auto bundle = bundle::ReadBundle(out);
  ASSERT_TRUE(bundle.ok()) << bundle.status().ToString();
  EXPECT_EQ(bundle.value().frames.size(), static_cast<size_t>(kSteps * 3 + 3));
  for (int step = 0; step < kSteps; ++step) {
    for (auto s : {bundle::LaserState::kLeft, bundle::LaserState::kRight, bundle::LaserState::kOff}) {
      EXPECT_GE(bundle.value().FindFrame(step, s), 0) << step;
    }
    EXPECT_EQ(bundle.value().FindFrame(step, bundle::LaserState::kNatural) >= 0, step % 3 == 0) << step;
  }
  const auto scene = sim::LoadScene(scene_path_).value();
  pipeline::ProcessOptions po;
  po.threads = 1;
  auto processed = pipeline::ProcessBundle(out, scene.rig, po);
  ASSERT_TRUE(processed.ok()) << processed.status().ToString();
  double sum2 = 0;
  size_t n = 0, with_natural = 0, coloured = 0;
  for (const auto& p : processed.value().cloud.points) {
    const Eigen::Vector3d x = p.position_in_table.cast<double>();
    if (x.z() < 2.0) continue;  // the table top
    const double d = (x - Eigen::Vector3d(0, 0, 30)).norm() - 30.0;
    sum2 += d * d;
    ++n;
    // Points of steps with a natural frame take their colour from it, not the flat grey (128) given to
    // points of steps without one.
    if (p.step % 3 == 0) {
      ++with_natural;
      if (!(p.color[0] == 128 && p.color[1] == 128 && p.color[2] == 128)) ++coloured;
    }
  }
  ASSERT_GT(n, 300u);
  ASSERT_GT(with_natural, 50u);
  EXPECT_GT(coloured, with_natural * 9 / 10);
  const double rms = std::sqrt(sum2 / static_cast<double>(n));
  EXPECT_LT(rms, 0.1) << n << " points";
  std::printf("natural every 3 steps: %zu points, RMS distance to the true sphere %.4f mm\n", n, rms);
}

// Hardware-triggered scan, processed with the true rig: the cloud lies on the true sphere (r = 30 mm at
// 30 mm above the table; the renderer's 128-segment mesh is within 0.01 mm of it).
TEST_F(CaptureTest, TriggeredScanCloudMatchesTheObject) {
  Rig rig = Open({});
  ScanOptions o = Options(8);
  o.timing = Timing::kTriggered;
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", o, nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  const auto scene = sim::LoadScene(scene_path_).value();
  pipeline::ProcessOptions po;
  po.threads = 1;
  auto processed = pipeline::ProcessBundle(dir_ / "b", scene.rig, po);
  ASSERT_TRUE(processed.ok()) << processed.status().ToString();
  double sum2 = 0;
  size_t n = 0;
  for (const auto& p : processed.value().cloud.points) {
    const Eigen::Vector3d x = p.position_in_table.cast<double>();
    if (x.z() < 2.0) continue;  // the table top
    const double d = (x - Eigen::Vector3d(0, 0, 30)).norm() - 30.0;
    sum2 += d * d;
    ++n;
  }
  ASSERT_GT(n, 300u);
  const double rms = std::sqrt(sum2 / static_cast<double>(n));
  EXPECT_LT(rms, 0.1) << n << " points";
  std::printf("triggered scan of the sphere: %zu points, RMS distance to the true sphere %.4f mm\n", n, rms);
}

// Shared off frame (ScanOptions::shared_off): 3 frames per step, all at the laser exposure, in both timing
// modes; the bundle says so (format_version 2) and processing needs no option. Against the truth: the
// cloud's distance to the true surface and its color error against the true albedo (pipeline/evaluate.h:
// one gain per channel) of an orange sphere with a dark checker, next to the 4-frame default's.
TEST_F(CaptureTest, SharedOffFrameThreeFramesPerStepAgainstTheTruth) {
  std::ofstream(scene_path_) << R"({"camera": {"width": 256, "height": 192, "hfov_deg": 20},
    "objects": [{"type": "sphere", "radius_mm": 30, "position_mm": [0, 0, 0], "color": [0.9, 0.5, 0.2],
                 "checker_mm": 12, "dark_albedo": 0.3}]})";
  const auto scene = sim::LoadScene(scene_path_).value();
  constexpr int kSteps = 12;
  struct Figures {
    double rms_mm = 0, color_error = 0, hue_error = 0;
    size_t points = 0;
  };
  auto scan = [&](Timing timing, bool shared, Figures* figures) {
    SCOPED_TRACE(std::string(TimingName(timing)) + (shared ? " shared off" : " 4 frames"));
    Rig rig = Open(timing == Timing::kFreeRunning ? std::vector<std::string>{"rolling=1"} : std::vector<std::string>{});
    RigTruth* truth = rig.board->truth();
    ScanOptions o = Options(kSteps);
    o.timing = timing;
    o.shared_off = shared;
    o.on_frame = [&](const CapturedFrame& c) {
      // Every frame at the laser exposure, exposed inside one laser state (the simulator's own record).
      if (shared) {
        EXPECT_NE(c.laser, bundle::LaserState::kNatural) << c.step;
        EXPECT_EQ(c.frame->exposure_us, 2000) << c.step;
      }
      EXPECT_TRUE(truth->LaserSwitches(c.frame->exposure_start_us, c.frame->ExposureEndUs()).empty()) << c.step;
      return Status::Ok();
    };
    const fs::path out = dir_ / (std::string(shared ? "shared_" : "four_") + TimingName(timing));
    auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, out, o, nullptr);
    ASSERT_TRUE(summary.ok()) << summary.status().ToString();
    EXPECT_EQ(summary.value().frames_used, kSteps * (shared ? 3 : 4)) << summary.value().Summary();
    auto bundle = bundle::ReadBundle(out);
    ASSERT_TRUE(bundle.ok()) << bundle.status().ToString();
    EXPECT_EQ(bundle.value().header.shared_off_frame, shared);
    EXPECT_EQ(bundle.value().header.format_version, shared ? 2 : 1);
    EXPECT_EQ(bundle.value().frames.size(), static_cast<size_t>(kSteps * (shared ? 3 : 4)));
    // The truth of the virtual scanner next to the bundle, as `rotoscan simulate` writes it.
    fs::create_directories(bundle::TruthRigPath(out).parent_path());
    ASSERT_TRUE(geometry::WriteRigYaml(bundle::TruthRigPath(out), scene.rig).ok());
    ASSERT_TRUE(bundle::WritePlyMesh(bundle::TruthMeshPath(out), sim::Renderer::Create(scene).value()->ObjectMesh()).ok());
    pipeline::ProcessOptions po;
    po.threads = 1;
    auto processed = pipeline::ProcessBundle(out, scene.rig, po);  // no option: the bundle says shared or not
    ASSERT_TRUE(processed.ok()) << processed.status().ToString();
    EXPECT_EQ(processed.value().summary.skipped_steps, 0);
    cloud::PointCloud object;  // without the table top
    for (const auto& p : processed.value().cloud.points) {
      if (p.position_in_table.z() >= 2.0f) object.points.push_back(p);
    }
    auto surface = pipeline::LoadTruthSurface(out, scene_path_);
    ASSERT_TRUE(surface.ok()) << surface.status().ToString();
    auto views = pipeline::LoadEvaluationViews(out);
    ASSERT_TRUE(views.ok()) << views.status().ToString();
    pipeline::EvaluateOptions eo;
    eo.threads = 1;
    auto report = pipeline::EvaluateCloud(object, surface.value(), views.value(), eo);
    ASSERT_TRUE(report.ok()) << report.status().ToString();
    ASSERT_TRUE(report.value().has_color);
    figures->rms_mm = report.value().distance.rms_mm;
    figures->color_error = report.value().color.mean_abs_error_all;
    figures->hue_error = report.value().color.mean_abs_error_per_point_gain;
    figures->points = report.value().points;
    std::printf("%s, %s: %d frames/step, %zu points, RMS to the true surface %.4f mm, color error %.2f levels "
                "(%.0f %% within %.0f), with one gain per point (hue) %.2f\n",
                TimingName(timing), shared ? "shared off frame" : "4 frames", shared ? 3 : 4, figures->points,
                figures->rms_mm, figures->color_error, 100 * report.value().color.within_tolerance,
                report.value().color.tolerance, report.value().color.mean_abs_error_per_point_gain);
  };
  for (Timing timing : {Timing::kTriggered, Timing::kFreeRunning}) {
    Figures four, shared;
    scan(timing, false, &four);
    scan(timing, true, &shared);
    ASSERT_GT(shared.points, 300u);
    EXPECT_LT(shared.rms_mm, 0.1);
    EXPECT_LT(shared.rms_mm, four.rms_mm * 1.2 + 0.005);  // the same background: the same geometry
    // Colors (measured 2026-11-24, 12 steps): the 4-frame scan's natural frames carry the lamp's shading,
    // which 12 views of 22.5° do not divide out (error ~32 levels) but have the hue right (per-point gain
    // ~1 level); the virtual scanner's off frame is lit by the ambient light alone (no shading: ~15
    // levels), but it is 10x darker, so its hue is off by ~10.6 levels (quantization and noise).
    EXPECT_LT(four.hue_error, 3.0);
    EXPECT_LT(four.color_error, 40.0);
    EXPECT_LT(shared.hue_error, 14.0);
    EXPECT_LT(shared.color_error, 20.0);
  }
}

}  // namespace
}  // namespace rotoscan::capture
