// rotoscan scan: Scan with the real scanner (or the simulated one): drive the board, capture frames, write
// a scan (or calibration) bundle; with --live, extract and triangulate while scanning.
//   rotoscan scan --device usb[:SERIAL]|sim|ciclop:/dev/ttyUSB0 --camera v4l2:/dev/video0|aravis[:ID]|virtual
//                 --out BUNDLE [--calib calib.yaml] [--steps N] [--placement N] [--live [--cloud FILE]]
//                 [--timing ...] [--shared-off] ...
// rotoscan devices: the boards and cameras this build can open, and those it finds attached.
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <ostream>
#include <thread>

#include "command.h"
#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/capture/scan.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/pipeline/process.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::cli {

struct ScanCommandOptions {
  std::string device = "sim";
  std::string camera = "virtual";
  std::string calib;
  std::string out;
  std::string scene;
  std::string kind = "scan";
  std::string timing = "auto";
  std::string cloud;
  std::vector<std::string> backend_options;
  int steps = 200;
  double step_deg = 0.0;  // 0: 360 / steps
  int placement = 0;
  double fps = 30.0;
  int64_t laser_exposure_us = 2000;
  int64_t natural_exposure_us = 20000;
  int natural_every = 1;
  int target_cols = 9, target_rows = 6;
  double target_square_mm = 7.0;
  double target_origin_height_mm = std::numeric_limits<double>::quiet_NaN();
  int stop_without_board = 3;
  bool live = false;
  bool shared_off = false;
  bool resume = false;
  bool overwrite = false;
};

namespace {

// Steps handed from the scan to the live processing as they are completed.
class LiveSource : public pipeline::StepSource {
 public:
  LiveSource(int steps, bool shared_off) : steps_(steps), shared_off_(shared_off) {}
  int StepCount() const override { return steps_; }
  Result<pipeline::StepFrames> Load(int index) const override {
    std::unique_lock<std::mutex> lock(mutex_);
    ready_.wait(lock, [&] { return ended_ || done_.count(index) != 0; });
    auto it = done_.find(index);
    if (it == done_.end()) return NotFoundError("step " + std::to_string(index) + " was not captured in this run");
    pipeline::StepFrames frames = std::move(it->second);
    done_.erase(it);
    return frames;
  }
  void Add(const capture::CapturedFrame& c) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto& s = pending_[c.step];
    s.step = c.step;
    s.table_angle_rad = c.table_angle_rad;
    s.name = "step " + std::to_string(c.step);
    const cv::Mat image = c.frame->image.clone();
    s.Set(c.laser, image);
    if (c.laser == bundle::LaserState::kNatural) last_natural_ = image;
  }
  void StepDone(int step) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      auto it = pending_.find(step);
      if (it == pending_.end()) return;
      if (it->second.natural.empty()) {  // the off frame (shared off frame), or the last natural (every k steps)
        it->second.natural = shared_off_ ? it->second.off : last_natural_;
      }
      done_[step] = std::move(it->second);
      pending_.erase(it);
    }
    ready_.notify_all();
  }
  void End() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ended_ = true;
    }
    ready_.notify_all();
  }

 private:
  int steps_;
  bool shared_off_;
  mutable std::mutex mutex_;
  mutable std::condition_variable ready_;
  std::map<int, pipeline::StepFrames> pending_;
  mutable std::map<int, pipeline::StepFrames> done_;
  cv::Mat last_natural_;
  bool ended_ = false;
};

Result<bundle::TargetKind> TargetOf(const std::string& kind) {
  if (kind == "scan") return bundle::TargetKind::kNone;
  if (kind == "checkerboard") return bundle::TargetKind::kCheckerboard;
  if (kind == "table-checkerboard") return bundle::TargetKind::kTableCheckerboard;
  if (kind == "calib-object") return bundle::TargetKind::kCalibrationObject;
  return InvalidArgumentError("--kind must be scan, checkerboard, table-checkerboard or calib-object");
}

}  // namespace

int RunScanCommand(const ScanCommandOptions& o, const Context& context) {
  // Output paths before any device is opened (issue 20): the bundle's directory, and the live cloud.
  std::vector<OutputPath> outputs{{o.out, "--out", OutputKind::kDirectory}};
  if (o.live) outputs.push_back({o.cloud.empty() ? o.out + ".ply" : o.cloud, o.cloud.empty() ? "--out (.ply)" : "--cloud"});
  std::vector<std::filesystem::path> inputs;
  for (const std::string& input : {o.scene, o.calib}) {
    if (!input.empty()) inputs.push_back(input);
  }
  if (const Status paths = CheckOutputPaths(outputs, inputs); !paths.ok()) return ReportStatus(context, "scan", paths);
  auto timing = capture::ParseTiming(o.timing);
  if (!timing.ok()) return ReportStatus(context, "scan", timing.status());
  auto target = TargetOf(o.kind);
  if (!target.ok()) return ReportStatus(context, "scan", target.status());
  if (o.shared_off && *target != bundle::TargetKind::kNone) {
    return ReportStatus(context, "scan", InvalidArgumentError("--shared-off is for scans, not calibration views"));
  }
  if (o.live && o.calib.empty()) {
    return ReportStatus(context, "scan", InvalidArgumentError("--live needs --calib (the rig to triangulate with)"));
  }
  std::optional<geometry::Rig> rig;
  if (!o.calib.empty()) {
    auto read = geometry::ReadRigYaml(o.calib);
    if (!read.ok()) return ReportStatus(context, "scan", read.status());
    rig = *read;
  }
  capture::OpenContext open;
  open.scene_path = o.scene;
  open.placement = o.placement;
  open.options = o.backend_options;
  auto board = capture::OpenBoard(o.device, &open);
  if (!board.ok()) return ReportStatus(context, "scan", board.status());
  open.board = board->get();
  auto camera = capture::OpenCamera(o.camera, open);
  if (!camera.ok()) return ReportStatus(context, "scan", camera.status());

  capture::ScanOptions options;
  options.steps = o.steps;
  options.step_deg = o.step_deg;
  options.timing = *timing;
  options.frame_rate_hz = o.fps;
  options.laser_exposure_us = o.laser_exposure_us;
  options.natural_exposure_us = o.natural_exposure_us;
  options.natural_every = o.natural_every;
  options.shared_off = o.shared_off;
  options.resume = o.resume;
  options.overwrite = o.overwrite;
  options.replay_resumed = o.live;  // --live --resume: the steps taken before the interruption, from disk
  auto& header = options.header;
  header.kind = *target == bundle::TargetKind::kNone ? bundle::BundleKind::kScan : bundle::BundleKind::kCalibration;
  header.created_by = "rotoscan scan";
  header.placement = o.placement;
  header.camera.name = (*camera)->Description();
  if (rig) {
    header.camera.model = rig->camera;
  } else if (!o.scene.empty()) {
    auto scene = sim::LoadScene(o.scene);
    if (!scene.ok()) return ReportStatus(context, "scan", scene.status());
    header.camera.model = scene->rig.camera;
  } else {
    auto scene = sim::SceneDefaults("machine_vision");
    header.camera.model = scene->rig.camera;  // nominal: the default rig
  }
  header.camera.laser_exposure_us = static_cast<double>(o.laser_exposure_us);
  header.camera.natural_exposure_us = static_cast<double>(o.natural_exposure_us);
  header.device.name = (*board)->info().name;
  header.device.serial = (*board)->info().serial;
  header.device.firmware_version = (*board)->info().firmware_version;
  header.target.kind = *target;
  if (*target != bundle::TargetKind::kNone) {
    header.target.cols = o.target_cols;
    header.target.rows = o.target_rows;
    header.target.square_mm = o.target_square_mm;
    header.target.origin_height_mm = o.target_origin_height_mm;
  }

  // Calibration: each view is looked at for the board as it is taken (the detector `rotoscan calibrate`
  // uses), so a board that is not found is known at once, not after the sweep: each such view is named on
  // stderr as it is taken. A board missing from the first --stop-without-board views (3 by default) stops
  // the capture: the pattern given is wrong, or the board is out of view or unlit, and the rest of the
  // sweep would be wasted. Later views without it only warn: a board on the table turns edge-on at the ends
  // of a sweep. The partial bundle is kept (--resume continues it once fixed, --overwrite starts again).
  int views = 0, views_without_target = 0;
  const bool check_board =
      *target == bundle::TargetKind::kCheckerboard || *target == bundle::TargetKind::kTableCheckerboard;
  calib::CheckerboardPattern pattern;
  if (check_board) {
    auto parsed = calib::ParsePattern(std::to_string(o.target_cols) + "x" + std::to_string(o.target_rows),
                                      o.target_square_mm);
    if (!parsed.ok()) return ReportStatus(context, "scan", parsed.status());
    pattern = *parsed;
  }
  std::unique_ptr<LiveSource> live;
  if (o.live) live = std::make_unique<LiveSource>(o.steps, o.shared_off);
  options.on_frame = [&](const capture::CapturedFrame& c) -> Status {
    if (live) live->Add(c);
    if (check_board && c.laser == bundle::LaserState::kNatural && !c.resumed) {
      ++views;
      if (!calib::DetectCheckerboard(c.frame->image, pattern).ok()) {
        ++views_without_target;
        *context.err << "rotoscan scan: view " << c.step << ": no " << o.target_cols << "x" << o.target_rows
                     << " board found (lighting, focus, or --target-cols/--target-rows?)\n";
        if (o.stop_without_board > 0 && views == o.stop_without_board && views_without_target == views) {
          return FailedPreconditionError(
              "no " + std::to_string(o.target_cols) + "x" + std::to_string(o.target_rows) +
              " board found in the first " + std::to_string(views) +
              " views: check --target-cols/--target-rows, that the whole board is in view and lit; stopped "
              "(--resume continues the capture, --overwrite starts it again, --stop-without-board 0 never "
              "stops)");
        }
      }
    }
    return Status::Ok();
  };
  if (live) options.on_step_done = [&](int step) { live->StepDone(step); };

  Result<pipeline::ProcessResult> processed = InternalError("not run");
  std::thread worker;
  if (live) {
    worker = std::thread([&] {
      pipeline::ProcessOptions process_options;
      process_options.threads = 1;  // the other core renders or reads the camera
      processed = pipeline::ProcessSteps(*rig, *live, process_options, nullptr);
    });
  }
  auto summary = capture::RunScan(**board, **camera, *open.clock, o.out, options, context.progress);
  const auto scan_end = std::chrono::steady_clock::now();
  if (live) {
    live->End();
    worker.join();
  }
  // How far live processing lagged behind: wall time from the last frame to the cloud being ready.
  const double lag_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - scan_end).count();
  if (!summary.ok()) return ReportStatus(context, "scan", summary.status());
  *context.out << "rotoscan scan: wrote " << o.out << "\n" << summary->Summary() << "\n";
  if (check_board) *context.out << "board found in " << views - views_without_target << " of " << views << " views\n";
  if (live) {
    if (!processed.ok()) return ReportStatus(context, "scan", processed.status());
    const std::string cloud_path = o.cloud.empty() ? o.out + ".ply" : o.cloud;
    const Status written = cloud::WritePly(cloud_path, processed->cloud);
    if (!written.ok()) return ReportStatus(context, "scan", written);
    *context.out << "live: " << pipeline::FormatSummary(processed->summary) << "\nlive: cloud ready " << lag_ms
                 << " ms after the last frame (" << processed->summary.seconds << " s of processing)\nwrote "
                 << cloud_path << "\n";
  }
  return kExitOk;
}

int RunDevices(const Context& context) {
  const auto list = capture::ListDevices();
  auto join = [](const std::vector<std::string>& v) {
    std::string s;
    for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
    return s;
  };
  *context.out << "boards (built: " << join(capture::BuiltBoardBackends()) << "):\n";
  for (const auto& d : list.boards) *context.out << "  " << d.spec << "  " << d.description << "\n";
  *context.out << "cameras (built: " << join(capture::BuiltCameraBackends()) << "):\n";
  for (const auto& d : list.cameras) *context.out << "  " << d.spec << "  " << d.description << "\n";
  for (const auto& e : list.errors) *context.err << "rotoscan devices: " << e << "\n";
  return kExitOk;
}

void RegisterScan(CLI::App& app, const Context& context, int* exit_code) {
  auto o = std::make_shared<ScanCommandOptions>();
  CLI::App* sub = app.add_subcommand(
      "scan", "Scan with the real scanner: drive the board, capture frames, write a scan bundle");
  sub->add_option("--device", o->device, "board: usb[:SERIAL], sim or ciclop:/dev/ttyUSB0")->capture_default_str();
  sub->add_option("--camera", o->camera, "camera: v4l2:/dev/video0, aravis[:ID] or virtual")->capture_default_str();
  sub->add_option("--calib", o->calib, "calib.yaml: the camera model in bundle.json, and the rig for --live");
  sub->add_option("--out", o->out, "output bundle directory")->required();
  sub->add_option("--steps", o->steps, "table steps over 360° (or views)")->capture_default_str()->check(CLI::Range(1, 100000));
  sub->add_option("--step-deg", o->step_deg,
                  "table step, degrees (default 360 / --steps); calibration views: e.g. --steps 8 --step-deg 15 "
                  "turns a board on the table through 105 degrees")
      ->check(CLI::Range(0.0, 360.0));
  sub->add_flag("--live", o->live, "extract and triangulate while scanning (needs --calib)");
  sub->add_option("--cloud", o->cloud, "--live: the cloud to write (default BUNDLE.ply)");
  sub->add_option("--timing", o->timing, "auto, triggered or free-running")->capture_default_str();
  sub->add_option("--fps", o->fps, "camera frame rate")->capture_default_str()->check(CLI::Range(0.1, 10000.0));
  sub->add_option("--laser-exposure", o->laser_exposure_us, "left/right/off exposure, us")->capture_default_str()->check(CLI::Range(1, 10000000));
  sub->add_option("--natural-exposure", o->natural_exposure_us, "natural exposure, us")->capture_default_str()->check(CLI::Range(1, 10000000));
  sub->add_option("--natural-every", o->natural_every, "a natural frame every k steps (0: none)")->capture_default_str()->check(CLI::Range(0, 100000));
  sub->add_flag("--shared-off", o->shared_off,
                "3 frames per step: the off frame (laser exposure) is also the color frame, no natural frame "
                "(recorded in the bundle; `process` needs no flag)");
  sub->add_option("--kind", o->kind, "scan, checkerboard, table-checkerboard or calib-object")->capture_default_str();
  sub->add_option("--target-cols", o->target_cols, "calibration board inner corners across")->check(CLI::Range(2, 100));
  sub->add_option("--target-rows", o->target_rows, "calibration board inner corners down")->check(CLI::Range(2, 100));
  sub->add_option("--target-square", o->target_square_mm, "calibration board square, mm")->check(CLI::Range(0.1, 1000.0));
  sub->add_option("--stop-without-board", o->stop_without_board,
                  "checkerboard kinds: stop when the board is found in none of the first N views (0: never)")
      ->capture_default_str()
      ->check(CLI::Range(0, 100000));
  sub->add_option("--target-origin-height", o->target_origin_height_mm,
                  "table-checkerboard: height of the board's first inner corner above the table top, mm "
                  "(measured once; puts the table frame's origin on the table top)")
      ->check(CLI::Range(-1000.0, 1000.0));
  sub->add_option("--placement", o->placement,
                  "the object's placement on the table (0 the first; 1 e.g. on its side), recorded in the "
                  "bundle for `rotoscan merge`; the virtual camera renders the scene's placement N")
      ->check(CLI::Range(0, 255));
  sub->add_option("--scene", o->scene, "virtual camera: the scene (JSON, sim/scene.h); default a sphere");
  sub->add_option("--option", o->backend_options, "backend option key=value (repeatable), e.g. rolling=1");
  auto* overwrite = sub->add_flag("--overwrite", o->overwrite, "replace an existing or interrupted bundle");
  sub->add_flag("--resume", o->resume, "continue an interrupted scan (same options)")->excludes(overwrite);
  sub->callback([o, &context, exit_code] { *exit_code = RunScanCommand(*o, context); });

  CLI::App* devices = app.add_subcommand("devices", "List the boards and cameras this build can open and finds");
  devices->callback([&context, exit_code] { *exit_code = RunDevices(context); });
}

}  // namespace rotoscan::cli
