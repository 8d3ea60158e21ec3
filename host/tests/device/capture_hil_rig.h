// The shared parts of the capture hardware-in-the-loop scans (`capture::RunScan` through the `usb` board
// backend against a board behind MockUsbBoard, with the virtual camera, hardware-triggered): the scene (a
// sphere off the table's axis, so that a frame at the wrong angle leaves it), opening the `usb` board and
// the `virtual` camera with a test's rig truth, the scan's options with a check of every frame against that
// truth, and the check of the bundle and its processed cloud against the true sphere. Used by
// capture_hil_emu_test (the flashed image on the emulated chip); written so that capture_hil_test (the
// firmware core built for the host) can use it too.
#pragma once

#include <Eigen/Core>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "rotoscan/capture/factory.h"
#include "rotoscan/capture/scan.h"
#include "rotoscan/capture/virtual_rig.h"

namespace rotoscan::capture::testing {

// A 200-step motor at 16 microsteps, direct drive: 16 steps of the scan's 200-step program are 22.5°.
constexpr int kHilStepsPerRev = 3200;
constexpr double kHilSphereRadiusMm = 20.0;
// Points from the true rig on the true sphere: what the virtual-time scans reach (0.05 mm), with room for
// the frames of a real-time scan.
constexpr double kHilRmsToleranceMm = 0.1;
constexpr double kHilWorstToleranceMm = 1.0;

// The sphere's centre in table coordinates (the scene puts it at (12, 0, 0) on a table 20 mm below).
Eigen::Vector3d HilSphereCentre();
// Writes the scene (a 256 x 192 camera, the sphere) to `path`.
void WriteHilScene(const std::filesystem::path& path);

struct HilRig {
  std::unique_ptr<Board> board;
  std::unique_ptr<Camera> camera;
  OpenContext context;
};
// Opens the board `board_spec` ("usb", or "usb:SERIAL"; reconnect window `reconnect_ms`) and the `virtual`
// camera rendering `scene_path` from `truth`, with `camera_options` (e.g. "drop=21": a frame lost). Failures are gtest failures; the rig then lacks what did not
// open.
HilRig OpenHilRig(const std::filesystem::path& scene_path, RigTruth* truth, int reconnect_ms = 1000,
                  const std::string& board_spec = "usb", const std::vector<std::string>& camera_options = {});

// Options of a hardware-triggered scan of `steps` steps; every frame is checked against `truth`: exposed
// inside one laser state, the laser the frame says, the table standing at the frame's angle over the whole
// exposure.
// `*checked` counts the frames checked; `then` (may be null) runs after each check (a test's fault
// injection).
ScanOptions HilScanOptions(int steps, const std::filesystem::path& scene_path, RigTruth* truth, int* checked,
                           std::function<void(const CapturedFrame&)> then, const std::string& created_by);

// The bundle holds every (step, laser) once and its processed cloud lies on the true sphere (prints RMS and
// worst distance). gtest failures otherwise.
void CheckHilBundleAndCloud(const std::filesystem::path& bundle_dir, const std::filesystem::path& scene_path,
                            int steps);

// A scan stopped by an unplug longer than the reconnect window: a device error that names the window.
void ExpectReconnectWindowError(const Status& status, int reconnect_ms);

// The board's laser safety after an unplug at host time `unplugged_at`: waits in real time until its laser
// timeout (MotionConfig's default, which the `usb` backend sets) and 300 ms more have passed, then checks
// on `truth` that both lasers are off and that they went off no later than 200 ms after the timeout.
void ExpectLaserSafetyAfterUnplug(RigTruth& truth, int64_t unplugged_at);

// Issue 13's unplug beyond the reconnect window, the same for every board behind the mocked bus: the board
// is unplugged (`unplug`) at the scan's step 6 and stays away; the scan fails naming the reconnect window
// (1000 ms), a partial bundle stays and the board's laser safety turns the lasers off on the pins; once the
// board is back (`replug`) the scan resumes (`open` opens the rig each time, `options` gives the scan's
// options) to a complete bundle with no step lost or taken twice and a cloud on the true sphere.
// `*on_frame` is the fixture's fault hook (ScanOptions from `options` call it); `context` (may be null)
// adds to failure messages and, at the end, must be empty (the emulator's own error).
struct UnplugBeyondRig {
  std::filesystem::path dir;  // the bundle is dir / "b"
  std::filesystem::path scene_path;
  int steps = 0;
  RigTruth* truth = nullptr;
  std::function<void(const CapturedFrame&)>* on_frame = nullptr;
  std::function<HilRig()> open;
  std::function<ScanOptions()> options;
  std::function<void()> unplug;
  std::function<void()> replug;
  std::function<std::string()> context;
};
void RunUnplugBeyondTheReconnectWindow(const UnplugBeyondRig& rig);

}  // namespace rotoscan::capture::testing
