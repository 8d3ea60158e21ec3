// `rotoscan scan` and `rotoscan devices` as the user runs them, with no hardware: the sim board and the
// virtual camera, --live processing into a cloud, and bad input answered with a message and an exit code.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <thread>

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include "command.h"
#include "fake_ciclop.h"
#include "fake_ciclop_truth.h"
#include "rotoscan/bundle/bundle.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/pipeline/calibrate.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::cli {
namespace {

namespace fs = std::filesystem;

int RunCli(std::vector<std::string> args, std::string* out_text = nullptr, std::string* err_text = nullptr) {
  args.insert(args.begin(), "rotoscan");
  args.push_back("--no-progress");
  std::vector<const char*> argv;
  for (const auto& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int code = Main(static_cast<int>(argv.size()), argv.data(), out, err);
  if (out_text != nullptr) *out_text = out.str();
  if (err_text != nullptr) *err_text = err.str();
  return code;
}

class ScanCommandTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("rotoscan_scan_cmd_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    scene_ = (dir_ / "scene.json").string();
    std::ofstream(scene_) << R"({"camera": {"width": 256, "height": 192, "hfov_deg": 20},
      "objects": [{"type": "sphere", "radius_mm": 30, "color": [0.8, 0.8, 0.8]}]})";
    calib_ = (dir_ / "calib.yaml").string();
    ASSERT_TRUE(geometry::WriteRigYaml(calib_, sim::LoadScene(scene_).value().rig).ok());
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
  std::string scene_, calib_;
};

TEST_F(ScanCommandTest, SimBoardVirtualCameraLiveCloud) {
  std::string out, err;
  const std::string bundle = (dir_ / "scan").string();
  const std::string cloud = (dir_ / "cloud.ply").string();
  ASSERT_EQ(RunCli({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene_, "--calib", calib_, "--out",
                 bundle, "--steps", "8", "--live", "--cloud", cloud},
                &out, &err),
            0)
      << err;
  EXPECT_NE(out.find("frames captured 32, used 32"), std::string::npos) << out;
  auto points = cloud::ReadPly(cloud);
  ASSERT_TRUE(points.ok()) << points.status().ToString();
  EXPECT_GT(points.value().points.size(), 300u);
  EXPECT_TRUE(fs::exists(fs::path(bundle) / "bundle.json"));
}

// RMS distance of a cloud's points above the table to the true sphere (the scene's: r = 30 mm, resting on
// the table at the origin).
double SphereRms(const cloud::PointCloud& cloud, size_t* n) {
  double sum2 = 0;
  *n = 0;
  for (const auto& p : cloud.points) {
    const Eigen::Vector3d x = p.position_in_table.cast<double>();
    if (x.z() < 2.0) continue;  // the table top
    const double d = (x - Eigen::Vector3d(0, 0, 30)).norm() - 30.0;
    sum2 += d * d;
    ++*n;
  }
  return *n > 0 ? std::sqrt(sum2 / static_cast<double>(*n)) : 0.0;
}

// --live --resume: a live scan that failed half way (the simulated board unplugged for good: the client
// gives up after its reconnect window) is resumed live; the steps taken before the interruption are read
// back from the partial bundle into the live processing. Its cloud equals that of a scan never interrupted:
// every step and laser there; the steps taken before the interruption point for point (the same frames:
// the camera's frame ids, hence its noise, are those of the uninterrupted run); the steps taken after it
// differ only by the sensor noise of other frame ids (another capture of the same surface, whose rows are
// found or not near the silhouette by noise): point counts per step and laser within 15 %, the median
// distance from a point to the other cloud's nearest point of the same step and laser within kSameMm (the
// clouds lie 0.05 mm RMS from the true surface), and the RMS distance to the true sphere within 0.005 mm.
TEST_F(ScanCommandTest, LiveResumeGivesTheCloudOfAnUninterruptedScan) {
  constexpr double kSameMm = 0.05;
  std::string out, err;
  const std::string whole = (dir_ / "whole").string();
  ASSERT_EQ(RunCli({"scan", "--scene", scene_, "--calib", calib_, "--out", whole, "--steps", "8", "--live"}, &out, &err), 0)
      << err;
  const std::string bundle = (dir_ / "resumed").string();
  EXPECT_EQ(RunCli({"scan", "--scene", scene_, "--calib", calib_, "--out", bundle, "--steps", "8", "--live", "--option",
                    "unplug_at_ms=500", "--option", "unplug_for_ms=100000"},
                   &out, &err),
            1);
  EXPECT_NE(err.find("did not come back"), std::string::npos) << err;
  EXPECT_TRUE(fs::exists(bundle + ".partial"));
  ASSERT_EQ(RunCli({"scan", "--scene", scene_, "--calib", calib_, "--out", bundle, "--steps", "8", "--live", "--resume"},
                   &out, &err),
            0)
      << err;
  int resumed_steps = 0;
  const auto pos = out.find(" done before)");
  ASSERT_NE(pos, std::string::npos) << out;
  ASSERT_EQ(std::sscanf(out.c_str() + out.rfind('(', pos), "(%d", &resumed_steps), 1) << out;
  EXPECT_GE(resumed_steps, 1) << out;
  EXPECT_NE(out.find("live: steps 8 of 8 processed, 0 skipped"), std::string::npos) << out;
  auto a = cloud::ReadPly(whole + ".ply");
  auto b = cloud::ReadPly(bundle + ".ply");
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  using Key = std::pair<int, int>;  // step, laser
  std::map<Key, std::vector<Eigen::Vector3f>> in_a, in_b;
  for (const auto& p : a.value().points) in_a[{p.step, p.laser}].push_back(p.position_in_table);
  for (const auto& p : b.value().points) in_b[{p.step, p.laser}].push_back(p.position_in_table);
  ASSERT_EQ(in_a.size(), in_b.size());
  std::vector<double> nearest;
  for (const auto& [key, points_a] : in_a) {
    ASSERT_EQ(in_b.count(key), 1u) << "step " << key.first << " laser " << key.second << " missing after resume";
    const auto& points_b = in_b[key];
    if (key.first < resumed_steps) {
      EXPECT_EQ(points_b, points_a) << "step " << key.first << " laser " << key.second << " (read back from disk)";
      continue;
    }
    EXPECT_NEAR(static_cast<double>(points_b.size()), static_cast<double>(points_a.size()), 0.15 * points_a.size())
        << "step " << key.first << " laser " << key.second;
    for (const auto& p : points_b) {
      double best = std::numeric_limits<double>::max();
      for (const auto& q : points_a) best = std::min(best, static_cast<double>((q - p).norm()));
      nearest.push_back(best);
    }
  }
  size_t na = 0, nb = 0;
  const double rms_a = SphereRms(a.value(), &na), rms_b = SphereRms(b.value(), &nb);
  ASSERT_FALSE(nearest.empty());
  std::sort(nearest.begin(), nearest.end());
  const double median = nearest[nearest.size() / 2];
  const double p90 = nearest[nearest.size() * 9 / 10];
  std::printf("uninterrupted: %zu points, %.4f mm RMS to the sphere; resumed live (%d steps before): %zu points, "
              "%.4f mm; later steps' points to the uninterrupted cloud: median %.4f mm, p90 %.4f mm\n",
              na, rms_a, resumed_steps, nb, rms_b, median, p90);
  EXPECT_LT(median, kSameMm);
  EXPECT_NEAR(rms_b, rms_a, 0.005);
}
// --shared-off: 3 frames per step, recorded in the bundle, so `rotoscan process` needs no flag; --live
// colors from the off frames too. The points lie on the true sphere and are colored (not the flat grey 128
// of a step without a color frame).
TEST_F(ScanCommandTest, SharedOffFrameScanProcessesWithoutAFlag) {
  std::string out, err;
  const std::string bundle = (dir_ / "scan").string();
  const std::string live_cloud = (dir_ / "live.ply").string(), cloud = (dir_ / "cloud.ply").string();
  ASSERT_EQ(RunCli({"scan", "--scene", scene_, "--calib", calib_, "--out", bundle, "--steps", "8", "--shared-off",
                    "--live", "--cloud", live_cloud},
                   &out, &err),
            0)
      << err;
  EXPECT_NE(out.find("frames captured 24, used 24"), std::string::npos) << out;
  const std::string json = ReadFile(fs::path(bundle) / "bundle.json").value();
  EXPECT_NE(json.find("\"shared_off_frame\": true"), std::string::npos);
  EXPECT_NE(json.find("\"format_version\": 2"), std::string::npos);
  ASSERT_EQ(RunCli({"process", bundle, "--calib", calib_, "--out", cloud}, &out, &err), 0) << err;
  for (const std::string& path : {live_cloud, cloud}) {
    auto points = cloud::ReadPly(path);
    ASSERT_TRUE(points.ok()) << points.status().ToString();
    size_t n = 0, grey = 0;
    EXPECT_LT(SphereRms(points.value(), &n), 0.1) << path;
    EXPECT_GT(n, 300u) << path;
    for (const auto& p : points.value().points) {
      if (p.color[0] == 128 && p.color[1] == 128 && p.color[2] == 128) ++grey;
    }
    EXPECT_LT(grey, points.value().points.size() / 20) << path;
  }
  // Not with calibration views, nor with a natural frame every k steps.
  EXPECT_EQ(RunCli({"scan", "--scene", scene_, "--out", (dir_ / "c").string(), "--steps", "4", "--shared-off",
                    "--kind", "checkerboard"},
                   nullptr, &err),
            1);
  EXPECT_NE(err.find("--shared-off"), std::string::npos) << err;
  EXPECT_EQ(RunCli({"scan", "--scene", scene_, "--out", (dir_ / "k").string(), "--steps", "4", "--shared-off",
                    "--natural-every", "3"},
                   nullptr, &err),
            1);
  EXPECT_NE(err.find("natural frame every k steps"), std::string::npos) << err;
}


// Calibration captures (`scan --kind checkerboard|table-checkerboard`): each view is checked for the board
// as it is taken, with the detector `rotoscan calibrate` uses, and a view without it is named at once.
// A board standing on the table, tilted back, seen over a 120° sweep (views at -60° ... 60°): it is edge-on
// or partly out of view in the last three views, which are named one by one as they are taken, and the
// capture goes on (a sweep's ends lose the board). A wrong pattern (14 columns for a board of 15) finds no
// board in the first three views: the capture stops there, naming each, with a partial bundle.
TEST_F(ScanCommandTest, CalibrationCaptureNamesEachViewWithoutTheBoardAtOnce) {
  const std::string scene = (dir_ / "board.json").string();
  std::ofstream(scene) << R"({"seed": 3, "camera": {"width": 640, "height": 480, "hfov_deg": 20, "supersampling": 2},
    "objects": [{"type": "checkerboard", "cols": 15, "rows": 12, "square_mm": 4, "color": [1, 1, 1],
                 "position_mm": [0, 25, 0], "rotation_deg": [-25, 0, -60]}]})";
  std::string out, err;
  const std::string bundle = (dir_ / "table-board").string();
  ASSERT_EQ(RunCli({"scan", "--kind", "table-checkerboard", "--scene", scene, "--target-cols", "15", "--target-rows",
                    "12", "--target-square", "4", "--steps", "9", "--step-deg", "15", "--out", bundle},
                   &out, &err),
            0)
      << err;
  EXPECT_NE(out.find("board found in 6 of 9 views"), std::string::npos) << out;
  for (int view = 0; view < 9; ++view) {
    const std::string line = "view " + std::to_string(view) + ": no 15x12 board found";
    EXPECT_EQ(err.find(line) != std::string::npos, view >= 6) << "view " << view << ":\n" << err;
  }
  // Named in the order taken, each before the next view (stderr is written as the views come).
  EXPECT_LT(err.find("view 6:"), err.find("view 7:"));
  EXPECT_LT(err.find("view 7:"), err.find("view 8:"));
  const std::string json = ReadFile(fs::path(bundle) / "bundle.json").value();
  EXPECT_NE(json.find("\"kind\": \"table_checkerboard\""), std::string::npos) << json.substr(0, 600);

  for (const std::string kind : {"checkerboard", "table-checkerboard"}) {
    SCOPED_TRACE(kind);
    const std::string wrong = (dir_ / ("wrong-" + kind)).string();
    EXPECT_EQ(RunCli({"scan", "--kind", kind, "--scene", scene, "--target-cols", "14", "--target-rows", "12",
                      "--target-square", "4", "--steps", "9", "--step-deg", "15", "--out", wrong},
                     &out, &err),
              1);
    for (int view = 0; view < 3; ++view) {
      EXPECT_NE(err.find("view " + std::to_string(view) + ": no 14x12 board found"), std::string::npos) << err;
    }
    EXPECT_EQ(err.find("view 3:"), std::string::npos) << "the capture went on:\n" << err;
    EXPECT_NE(err.find("no 14x12 board found in the first 3 views"), std::string::npos) << err;
    EXPECT_FALSE(fs::exists(wrong));
    EXPECT_TRUE(fs::exists(wrong + ".partial"));
  }
}

// A good calibration capture: three placements of a board standing on the table (those of
// data/scenes/calibration.json, calibration-2 and -3), each swept through 120° in 17 views (7.5° apart) by `rotoscan scan
// --kind table-checkerboard` (the sim board, the virtual camera at its full 1288 x 964), accepted by `rotoscan
// calibrate` (its checks passed, exit 0), the rig within the README's calibration targets of the true one
// (fx 0.1 %, laser planes 0.05° and 0.05 mm, the table axis 0.05 mm and 0.05°, the table top 0.05 mm).
// Opt-in (rendering 204 full-size frames takes a minute or more): ROTOSCAN_SCAN_CALIB=1.
TEST_F(ScanCommandTest, CalibrationCaptureCalibratesCloseToTheTruth) {
  if (std::getenv("ROTOSCAN_SCAN_CALIB") == nullptr) GTEST_SKIP() << "set ROTOSCAN_SCAN_CALIB=1";
  const char* const placements[] = {R"("position_mm": [20, 20, 0], "rotation_deg": [0, 0, -60])",
                                    R"("position_mm": [-20, -20, 0], "rotation_deg": [0, 0, -60])",
                                    R"("position_mm": [0, 25, 0], "rotation_deg": [-25, 0, -60])"};
  std::vector<std::string> calibrate{"calibrate"};
  std::string out, err;
  geometry::Rig truth;
  for (int p = 0; p < 3; ++p) {
    const std::string scene = (dir_ / ("board-" + std::to_string(p + 1) + ".json")).string();
    std::ofstream(scene) << R"({"seed": )" << p + 1 << R"(, "camera": {"supersampling": 2},
      "objects": [{"type": "checkerboard", "cols": 15, "rows": 12, "square_mm": 4, "color": [1, 1, 1], )"
                         << placements[p] << "}]}";
    truth = sim::LoadScene(scene).value().rig;
    const std::string bundle = (dir_ / ("board-" + std::to_string(p + 1))).string();
    // The board's first inner corner stands (rows + 1) squares above the table top: 52 mm.
    ASSERT_EQ(RunCli({"scan", "--kind", "table-checkerboard", "--scene", scene, "--target-cols", "15",
                      "--target-rows", "12", "--target-square", "4", "--target-origin-height", "52", "--steps",
                      "17", "--step-deg", "7.5", "--stop-without-board", "0", "--out", bundle},
                     &out, &err),
              0)
        << err;
    std::printf("placement %d: %s", p + 1, out.substr(out.find("board found")).c_str());
    calibrate.push_back(bundle);
  }
  const std::string calib = (dir_ / "calibrated.yaml").string();
  calibrate.insert(calibrate.end(), {"--out", calib});
  const int code = RunCli(calibrate, &out, &err);
  std::printf("%s%s", out.c_str(), err.c_str());
  EXPECT_EQ(code, 0) << err;
  auto rig = geometry::ReadRigYaml(calib);
  ASSERT_TRUE(rig.ok()) << rig.status().ToString();
  const pipeline::RigError e = pipeline::CompareRigs(rig.value(), truth);
  std::printf("against the truth: fx %.4f %%, normals %.4f / %.4f deg, offsets %.4f / %.4f mm, axis %.4f mm %.4f deg, "
              "table top %.4f mm\n",
              e.fx_percent, e.normal_deg[0], e.normal_deg[1], e.offset_mm[0], e.offset_mm[1], e.axis_offset_mm,
              e.axis_angle_deg, e.table_top_mm);
  EXPECT_LT(std::abs(e.fx_percent), 0.1);
  for (int l = 0; l < 2; ++l) {
    EXPECT_LT(e.normal_deg[static_cast<size_t>(l)], 0.05);
    EXPECT_LT(e.offset_mm[static_cast<size_t>(l)], 0.05);
  }
  EXPECT_LT(e.axis_offset_mm, 0.05);
  EXPECT_LT(e.axis_angle_deg, 0.05);
  EXPECT_LT(e.table_top_mm, 0.05);
}

// A file's text, or `fallback` when it cannot be read.
std::string TextOr(const fs::path& path, const std::string& fallback) {
  auto text = ReadFile(path);
  return text.ok() ? text.value() : fallback;
}

// `rotoscan scan` (the program, in a child process: its own interrupt handler) is sent `signal` once 3
// steps are written, then `--resume` completes the partial bundle: every (step, laser) once, the frames
// written before the signal kept byte for byte (not taken again; after a kill, one frame whose record the
// kill cut off may be), only the missing ones written.
// SIGINT (Ctrl-C): it exits non-zero saying it was interrupted and how to resume, and the board's laser pins
// are off (the sim board writes their levels when let go: option pins_file). SIGKILL (a crash): whatever
// it had written is a resumable bundle.
void InterruptAndResume(const fs::path& dir_, const std::string& scene_, int signal) {
  constexpr int kSteps = 48;
  const fs::path bundle = dir_ / "interrupted";
  const fs::path partial = dir_ / "interrupted.partial";
  const fs::path pins = dir_ / "pins.txt";
  const fs::path err_path = dir_ / "stderr.txt";
  const std::vector<std::string> args = {ROTOSCAN_CLI_PATH, "--no-progress", "scan", "--device", "sim", "--camera",
                                         "virtual", "--scene", scene_, "--steps", std::to_string(kSteps), "--out",
                                         bundle.string(), "--option", "pins_file=" + pins.string()};
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    const int fd = ::open(err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd >= 0) {
      ::dup2(fd, STDERR_FILENO);
      ::dup2(fd, STDOUT_FILENO);
    }
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  // Once 3 steps are written (frames appear in the partial bundle as they are taken), Ctrl-C.
  auto frames_in = [](const fs::path& dir) {
    std::error_code ec;
    size_t n = 0;
    for (auto it = fs::directory_iterator(dir / "frames", ec); !ec && it != fs::directory_iterator(); it.increment(ec)) ++n;
    return n;
  };
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  int status = 0;
  bool exited = false;
  while (frames_in(partial) < 12 && std::chrono::steady_clock::now() < deadline) {
    if (::waitpid(child, &status, WNOHANG) == child) {
      exited = true;
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  ASSERT_FALSE(exited) << "the scan ended before it could be interrupted: " << TextOr(err_path, "");
  ASSERT_EQ(::kill(child, signal), 0);
  while (!exited && std::chrono::steady_clock::now() < deadline) {
    exited = ::waitpid(child, &status, WNOHANG) == child;
    if (!exited) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  if (!exited) {
    ::kill(child, SIGKILL);
    ::waitpid(child, &status, 0);
    FAIL() << "the scan did not stop within 60 s of Ctrl-C";
  }
  const std::string err = TextOr(err_path, "");
  std::printf("after signal %d (exit %d):\n%s", signal, WIFEXITED(status) ? WEXITSTATUS(status) : -1, err.c_str());
  if (signal == SIGINT) {
    ASSERT_TRUE(WIFEXITED(status)) << "killed by a signal, not stopped cleanly:\n" << err;
    EXPECT_NE(WEXITSTATUS(status), 0) << err;
    EXPECT_NE(err.find("interrupted"), std::string::npos) << err;
    EXPECT_NE(err.find("--resume"), std::string::npos) << err;
    EXPECT_EQ(TextOr(pins, "(no pins file)"), "left 0\nright 0\n");
  } else {
    EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == signal);
  }
  EXPECT_FALSE(fs::exists(bundle));
  ASSERT_TRUE(fs::exists(partial));

  // The frames written before the signal, to compare after the resume.
  auto partial_bundle = bundle::ReadBundle(partial);
  std::map<std::string, std::string> before;
  if (partial_bundle.ok()) {
    for (const auto& f : partial_bundle.value().frames) before[f.file] = TextOr(partial / f.file, "");
  } else {  // no bundle.json yet: the frames on disk, not a temporary file a killed write left
    for (const auto& entry : fs::directory_iterator(partial / "frames")) {
      const std::string name = entry.path().filename().string();
      if (name.find(".tmp-") == std::string::npos) before["frames/" + name] = TextOr(entry.path(), "");
    }
  }
  ASSERT_GE(before.size(), 8u);
  ASSERT_LT(before.size(), static_cast<size_t>(kSteps * 4)) << "nothing was left to resume";
  std::printf("%zu frames written before the signal\n", before.size());

  std::string out;
  std::string resume_err;
  ASSERT_EQ(RunCli({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene_, "--steps",
                    std::to_string(kSteps), "--out", bundle.string(), "--resume"},
                   &out, &resume_err),
            0)
      << resume_err;
  std::printf("%s", out.c_str());
  auto done = bundle::ReadBundle(bundle);
  ASSERT_TRUE(done.ok()) << done.status().ToString();
  std::map<std::pair<int, int>, int> count;
  for (const auto& f : done.value().frames) ++count[{f.step, static_cast<int>(f.laser)}];
  EXPECT_EQ(count.size(), static_cast<size_t>(kSteps * 4));
  for (const auto& [key, n] : count) EXPECT_EQ(n, 1) << "step " << key.first << " laser " << key.second;
  size_t kept = 0;
  for (const auto& [file, bytes] : before) {
    const auto now = ReadFile(fs::path(bundle) / file);
    ASSERT_TRUE(now.ok()) << file << " is gone";
    if (now.value() == bytes) ++kept;
  }
  // Ctrl-C: every frame on disk was recorded. A kill may land between a frame's file and its record in the
  // bundle's journal: that one frame is taken again (and replaced), no other.
  EXPECT_GE(kept + (signal == SIGKILL ? 1 : 0), before.size()) << "frames written before the signal were taken again";
  for (const auto& entry : fs::recursive_directory_iterator(bundle)) {
    EXPECT_EQ(entry.path().filename().string().find(".tmp-"), std::string::npos) << entry.path() << " left over";
  }
  // Written in the resumed run: only what was missing (a step cut short by the signal is exposed whole by the
  // board's program, so the camera may deliver a frame more than is used).
  const int used_now = [&] {
    const auto at = out.find(", used ");
    return at == std::string::npos ? -1 : std::atoi(out.c_str() + at + 7);
  }();
  EXPECT_EQ(used_now, kSteps * 4 - static_cast<int>(kept)) << out;
}

TEST_F(ScanCommandTest, CtrlCLeavesLasersOffAndAResumableBundle) { InterruptAndResume(dir_, scene_, SIGINT); }

TEST_F(ScanCommandTest, KilledMidScanLeavesAResumableBundle) { InterruptAndResume(dir_, scene_, SIGKILL); }

// `rotoscan scan --device ciclop:PTY` against the fake horus-fw board on a pseudo-terminal, with the virtual
// camera filming that board (a camera backend this test registers: the `virtual` camera given the fake's
// truth), free-running at 30 frames/s with a rolling shutter, --live, ending in a cloud on the true sphere.
TEST_F(ScanCommandTest, CiclopBoardOnAPtyEndsInACloud) {
  using device::testing::FakeCiclop;
  using device::testing::FakeCiclopOptions;
  using device::testing::FakeCiclopTruth;
  FakeCiclopOptions fake_options;  // horus-fw's defaults: 176 steps/deg, 180 deg/s, 180 deg/s^2
  fake_options.link_path = (dir_ / "ttyUSB0").string();
  FakeCiclop fake(fake_options);
  ASSERT_TRUE(fake.Start()) << fake.error();
  FakeCiclopTruth truth(&fake);
  static FakeCiclopTruth* current = nullptr;
  current = &truth;
  static bool registered = false;
  if (!registered) {
    registered = true;
    capture::CameraBackend eye;
    eye.name = "ciclop-eye";
    eye.description = "test: the virtual camera filming the fake Ciclop board";
    eye.open = [](const std::string& argument, const capture::OpenContext& context) {
      capture::OpenContext with_truth = context;
      with_truth.truth = current;
      return capture::OpenCamera("virtual" + (argument.empty() ? "" : ":" + argument), with_truth);
    };
    capture::BackendRegistry::Instance().AddCamera(eye);
  }
  std::string out, err;
  const std::string bundle = (dir_ / "ciclop").string();
  ASSERT_EQ(RunCli({"scan", "--device", "ciclop:" + fake_options.link_path, "--camera", "ciclop-eye", "--scene", scene_,
                    "--calib", calib_, "--out", bundle, "--steps", "4", "--live", "--option", "rolling=1", "--option",
                    "ok_timeout_ms=2000"},  // no lost "ok" here: a real-time bound on a failure only, generous for load
                   &out, &err),
            0)
      << err;
  current = nullptr;
  EXPECT_NE(out.find("free-running: 4 steps"), std::string::npos) << out;
  EXPECT_NE(out.find("used 16"), std::string::npos) << out;
  EXPECT_FALSE(fake.LaserAt(1, capture::MonotonicNowUs()));
  EXPECT_FALSE(fake.LaserAt(2, capture::MonotonicNowUs()));
  auto cloud = cloud::ReadPly(bundle + ".ply");
  ASSERT_TRUE(cloud.ok()) << cloud.status().ToString();
  size_t n = 0;
  const double rms = SphereRms(cloud.value(), &n);
  std::printf("ciclop over a pty, --live: %zu points on the sphere, %.4f mm RMS\n%s", n, rms, out.c_str());
  EXPECT_GT(n, 100u);
  EXPECT_LT(rms, 0.1);
}

// `scan --placement N` records the placement; the virtual camera films the scene's placement N, and a
// placement the scene does not define is refused before anything is written.
TEST_F(ScanCommandTest, PlacementIsRecordedAndRendered) {
  const std::string scene = (dir_ / "placed.json").string();
  std::ofstream(scene) << R"({"camera": {"width": 256, "height": 192, "hfov_deg": 20},
      "objects": [{"type": "box", "size_mm": [40, 20, 10]}],
      "placements": [{}, {"rotation_deg": [90, 0, 0]}]})";
  std::string out, err;
  const std::string bundle = (dir_ / "side").string();
  ASSERT_EQ(RunCli({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene, "--out", bundle, "--steps",
                    "4", "--placement", "1"},
                   &out, &err),
            0)
      << err;
  std::ifstream json(fs::path(bundle) / "bundle.json");
  const std::string text((std::istreambuf_iterator<char>(json)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("\"placement\": 1"), std::string::npos);
  EXPECT_EQ(RunCli({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene, "--out",
                    (dir_ / "nope").string(), "--steps", "4", "--placement", "2"},
                   nullptr, &err),
            1);
  EXPECT_NE(err.find("placement 2 is not defined"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir_ / "nope"));
}

TEST_F(ScanCommandTest, BadInputIsAClearError) {
  std::string err;
  const std::string bundle = (dir_ / "b").string();
  EXPECT_EQ(RunCli({"scan", "--device", "nosuch", "--out", bundle}, nullptr, &err), 1);
  EXPECT_NE(err.find("unknown board 'nosuch'"), std::string::npos) << err;
  EXPECT_EQ(RunCli({"scan", "--live", "--out", bundle}, nullptr, &err), 1);
  EXPECT_NE(err.find("--live needs --calib"), std::string::npos) << err;
  EXPECT_EQ(RunCli({"scan", "--timing", "sometimes", "--out", bundle}, nullptr, &err), 1);
  EXPECT_EQ(RunCli({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene_, "--steps", "7",
                 "--timing", "triggered", "--out", bundle},
                nullptr, &err),
            1);
  EXPECT_NE(err.find("not a whole number of motor steps"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(bundle));
  std::string out;
  EXPECT_EQ(RunCli({"devices"}, &out, &err), 0);
  EXPECT_NE(out.find("sim"), std::string::npos) << out;
}

}  // namespace
}  // namespace rotoscan::cli
