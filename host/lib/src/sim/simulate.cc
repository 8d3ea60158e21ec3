#include "rotoscan/sim/simulate.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <map>
#include <mutex>
#include <thread>
#include <vector>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/core/version.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/sim/renderer.h"

namespace rotoscan::sim {

using bundle::LaserState;

Result<SimulateKind> ParseSimulateKind(const std::string& name) {
  if (name == "scan") return SimulateKind::kScan;
  if (name == "calib-object") return SimulateKind::kCalibrationObject;
  if (name == "checkerboard") return SimulateKind::kCheckerboard;
  if (name == "table-checkerboard") return SimulateKind::kTableCheckerboard;
  return InvalidArgumentError("kind '" + name +
                              "' must be scan, calib-object, checkerboard or table-checkerboard");
}

Result<SlipMode> ParseSlipMode(const std::string& name) {
  if (name == "independent") return SlipMode::kIndependent;
  if (name == "cumulative") return SlipMode::kCumulative;
  return InvalidArgumentError("table slip mode '" + name + "' must be independent or cumulative");
}

namespace {

constexpr double kFramePeriodUs = 1e6 / 30.0;  // trigger period of the virtual camera

// One unit of work: a table angle (and target pose) with the frames to render there.
struct Job {
  int pose = -1;
  int step = 0;
  double angle = 0.0;  // commanded table angle (bundle.json)
  FrameMask mask = kAllFrames;
  double true_angle = 0.0;  // where the table is when the frames are exposed (rendering and truth/)
};

// The deviation of the true table angle from the commanded one at a step (SimulateOptions::table_slip_deg):
// uniform in +-slip, from the scene seed and the step only.
double TableSlip(uint64_t scene_seed, int pose, int step, double slip_rad) {
  if (!(slip_rad > 0)) return 0.0;
  const double u = static_cast<double>(FrameSeed(scene_seed, pose, step, 0x51) >> 11) * 0x1.0p-53;  // [0, 1)
  return slip_rad * (2.0 * u - 1.0);
}

const ObjectSpec* FindObject(const Scene& scene, ObjectType type) {
  for (const ObjectSpec& o : scene.objects) {
    if (o.type == type) return &o;
  }
  return nullptr;
}

// The pose of a hand-held board for intrinsics: tilted up to ~25°, spread over the view, 260..330 mm.
Eigen::Isometry3d BoardPose(const ObjectSpec& board, int i, int n) {
  const double phase = 2.0 * 3.14159265358979323846 * i / std::max(1, n);
  const double tilt_x = geometry::DegToRad(25.0 * std::sin(phase));
  const double tilt_y = geometry::DegToRad(25.0 * std::cos(phase));
  const double roll = geometry::DegToRad(8.0 * std::sin(3 * phase));
  const Eigen::Vector3d centre(8.0 * std::cos(2 * phase), 6.0 * std::sin(2 * phase),
                               295.0 + 30.0 * std::sin(phase + 1.0) * ((i % 2) ? 1 : -1));
  const Eigen::Vector3d board_centre((board.cols - 1) * board.square_mm / 2,
                                     (board.rows - 1) * board.square_mm / 2, 0);
  return Eigen::Translation3d(centre) * Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) *
         Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()) *
         Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()) * Eigen::Translation3d(-board_centre);
}

bundle::FrameRecord JobFrame(const Job& job, int frame) {
  bundle::FrameRecord record;
  record.step = job.step;
  record.pose = job.pose;
  record.table_angle_rad = job.angle;
  record.laser = static_cast<LaserState>(frame);
  record.file = bundle::FrameFileName(job.step, record.laser, job.pose);
  return record;
}

// True when every frame of `job` (and its line truth) is in the resumed bundle already.
bool JobDone(const bundle::BundleWriter& writer, const Job& job, bool truth) {
  for (int f = 0; f < 4; ++f) {
    if (!job.mask[f]) continue;
    const bundle::FrameRecord record = JobFrame(job, f);
    if (!writer.HasFrame(record.file)) return false;
    std::error_code ec;
    if (truth && f < 2 &&
        !std::filesystem::is_regular_file(bundle::LineTruthPath(writer.working_directory(), record), ec)) {
      return false;
    }
  }
  return true;
}

}  // namespace

Status Simulate(const Scene& input_scene, const SimulateOptions& options, Progress* progress) {
  Scene scene = input_scene;
  const SimulateKind kind = options.kind;
  int steps = options.steps;
  if (steps < 0) return InvalidArgumentError("steps must be >= 0");
  if (!(options.table_slip_deg >= 0.0) || !(options.table_slip_deg <= 45.0)) {
    return InvalidArgumentError("table slip must be in [0, 45] degrees");
  }
  if (!(options.step_deg >= 0.0) || !(options.step_deg <= 360.0)) {
    return InvalidArgumentError("table step must be in (0, 360] degrees (0: the scene's)");
  }
  if (options.table_slip_deg > 0.0 && kind == SimulateKind::kCheckerboard) {
    return InvalidArgumentError("table slip needs a table: the hand-held checkerboard kind has none");
  }
  if (options.placement != 0 && kind != SimulateKind::kScan) {
    return InvalidArgumentError("--placement applies to scans only");
  }
  Eigen::Isometry3d table_from_reference = Eigen::Isometry3d::Identity();
  if (kind == SimulateKind::kScan) {
    ROTOSCAN_ASSIGN_OR_RETURN(scene, PlaceScene(input_scene, options.placement, &table_from_reference));
  }
  // After the placement, which starts again from the input scene.
  if (options.step_deg > 0.0) scene.rig.step_angle_rad = options.step_deg * 3.14159265358979323846 / 180.0;
  if (steps == 0) {
    steps = kind == SimulateKind::kScan                ? scene.steps
            : kind == SimulateKind::kCalibrationObject ? 1
            : kind == SimulateKind::kCheckerboard      ? 12
                                                       : 8;
  }
  bundle::BundleHeader header;
  header.kind = kind == SimulateKind::kScan ? bundle::BundleKind::kScan : bundle::BundleKind::kCalibration;
  header.created_by = std::string("rotoscan simulate ") + ROTOSCAN_VERSION_STRING;
  header.device = {"virtual scanner", "sim-" + std::to_string(scene.seed), ROTOSCAN_VERSION_STRING};

  std::vector<Job> jobs;
  std::vector<ObjectSpec> targets;  // for the calibration kinds: one per pose
  if (kind != SimulateKind::kScan) {
    scene.sensor.supersampling = std::max(scene.sensor.supersampling, 2);
    ObjectSpec target;
    if (kind == SimulateKind::kCalibrationObject) {
      const ObjectSpec* found = FindObject(scene, ObjectType::kCalibrationObject);
      if (found != nullptr) {
        target = *found;
      } else {
        target.type = ObjectType::kCalibrationObject;
        target.square_mm = 10.0;
        target.size_mm = {60, 60, 60};
      }
      header.target = {bundle::TargetKind::kCalibrationObject, 0, 0, target.square_mm,
                       "two orthogonal planes (y = 0 and x = 0 of the target frame), " +
                           std::to_string(target.size_mm.x()) + " mm wide, checker of the given pitch"};
    } else {
      const ObjectSpec* found = FindObject(scene, ObjectType::kCheckerboard);
      if (found != nullptr) {
        target = *found;
      } else {
        target.type = ObjectType::kCheckerboard;
      }
      target.color = {1, 1, 1};
      header.target = {kind == SimulateKind::kCheckerboard ? bundle::TargetKind::kCheckerboard
                                                           : bundle::TargetKind::kTableCheckerboard,
                       target.cols, target.rows, target.square_mm, "checkerboard, inner corners cols x rows"};
    }
    scene.objects = {target};
  }
  switch (kind) {
    case SimulateKind::kScan:
      for (int s = 0; s < steps; ++s) jobs.push_back({-1, s, s * scene.rig.step_angle_rad, kAllFrames, 0.0});
      break;
    case SimulateKind::kCalibrationObject:
    case SimulateKind::kTableCheckerboard: {
      // Angles: whole motor steps, spread over a quarter turn (object) or a half turn (board) centred on 0.
      const double span = geometry::DegToRad(kind == SimulateKind::kCalibrationObject ? 90.0 : 120.0);
      for (int s = 0; s < steps; ++s) {
        const double wanted = steps == 1 ? 0.0 : -span / 2 + span * s / (steps - 1);
        const double motor_steps = std::round(wanted / scene.rig.step_angle_rad);
        jobs.push_back({0, s, motor_steps * scene.rig.step_angle_rad, kAllFrames, 0.0});
      }
      break;
    }
    case SimulateKind::kCheckerboard:
      for (int p = 0; p < steps; ++p) jobs.push_back({p, 0, 0.0, {false, false, false, true}, 0.0});
      break;
  }
  const double slip_rad = geometry::DegToRad(options.table_slip_deg);
  if (options.table_slip_mode == SlipMode::kCumulative) {
    // The deviations add up along each pose's positions, in step order (jobs are in that order).
    std::map<int, double> drift;  // per pose
    for (Job& job : jobs) {
      double& d = drift[job.pose];
      d += TableSlip(scene.seed, job.pose, job.step, slip_rad);
      job.true_angle = job.angle + d;
    }
  } else {
    for (Job& job : jobs) job.true_angle = job.angle + TableSlip(scene.seed, job.pose, job.step, slip_rad);
  }
  header.table_step_rad = scene.rig.step_angle_rad;
  header.placement = options.placement;
  header.camera.name = "virtual " + scene.preset + " " + std::to_string(scene.rig.camera.width) + "x" +
                       std::to_string(scene.rig.camera.height);
  header.camera.model = scene.rig.camera;  // nominal = true here; calibration must estimate its own
  header.camera.channels = 3;
  header.camera.bit_depth = scene.sensor.bit_depth;
  header.camera.bayer = false;  // frames are demosaiced
  header.camera.pixel_size_um = scene.sensor.pixel_size_um;
  header.camera.laser_exposure_us = scene.sensor.laser_exposure_us;
  header.camera.natural_exposure_us = scene.sensor.natural_exposure_us;
  header.camera.gain_db = scene.sensor.gain_db;

  // One renderer, or one per pose for the hand-held board.
  std::vector<std::unique_ptr<Renderer>> renderers;
  std::vector<bundle::TargetPose> poses;
  if (kind == SimulateKind::kCheckerboard) {
    const Eigen::Isometry3d table_from_cam = scene.rig.CamFromTable().inverse();
    for (int p = 0; p < steps; ++p) {
      Scene posed = scene;
      const Eigen::Isometry3d cam_from_target = BoardPose(scene.objects[0], p, steps);
      posed.objects[0].has_pose = true;
      posed.objects[0].table_from_object = table_from_cam * cam_from_target;
      ROTOSCAN_ASSIGN_OR_RETURN(auto renderer, Renderer::Create(posed));
      renderers.push_back(std::move(renderer));
      poses.push_back({p, 0, cam_from_target});
    }
  } else {
    ROTOSCAN_ASSIGN_OR_RETURN(auto renderer, Renderer::Create(scene));
    renderers.push_back(std::move(renderer));
    if (kind != SimulateKind::kScan) {
      const Eigen::Isometry3d table_from_target = renderers[0]->TableFromObject(0);
      // Where the table top is below the target's origin: what calibration needs to put the table
      // frame's origin on the table top (bundle.h TargetInfo). Exact here; measured on a real rig.
      header.target.origin_height_mm = table_from_target.translation().z();
      for (const Job& job : jobs) {
        const Eigen::Isometry3d cam_from_target =
            scene.rig.WorldFromCamAtAngle(job.true_angle).inverse() * table_from_target;
        poses.push_back({job.pose, job.step, cam_from_target});
      }
    }
  }

  // Everything that decides the frames beyond the header: a resume with another scene, seed, kind, step
  // count or truth setting is refused (FNV-1a 64 of them).
  uint64_t hash = 14695981039346656037ull;
  const std::string what = scene.source + "|kind " + std::to_string(static_cast<int>(kind)) + "|steps " +
                           std::to_string(steps) + "|truth " + (options.truth ? "1" : "0") +
                           (options.placement != 0 ? "|placement " + std::to_string(options.placement) : "") +
                           (options.step_deg > 0.0 ? "|step " + std::to_string(options.step_deg) : "");
  for (const char c : what) hash = (hash ^ static_cast<unsigned char>(c)) * 1099511628211ull;
  char hash_text[17];
  std::snprintf(hash_text, sizeof(hash_text), "%016llx", static_cast<unsigned long long>(hash));
  ROTOSCAN_ASSIGN_OR_RETURN(auto writer, bundle::BundleWriter::Create(
                                             options.out, header, {options.overwrite, options.resume}, hash_text));
  const std::filesystem::path work = writer->working_directory();
  if (options.truth) {
    ROTOSCAN_RETURN_IF_ERROR(geometry::WriteRigYaml(work / "truth" / "rig.yaml", scene.rig));
    if (kind == SimulateKind::kScan) {
      ROTOSCAN_RETURN_IF_ERROR(
          bundle::WritePlyMesh(work / "truth" / "object.ply", renderers[0]->ObjectMesh()));
      ROTOSCAN_RETURN_IF_ERROR(bundle::WritePlacementTruth(bundle::TruthPlacementPath(work),
                                                           {options.placement, table_from_reference}));
    } else {
      ROTOSCAN_RETURN_IF_ERROR(bundle::WriteTargetPoses(work / "truth" / "poses.csv", poses));
    }
    if (kind != SimulateKind::kCheckerboard) {
      std::vector<bundle::TableAngle> angles;
      for (const Job& job : jobs) angles.push_back({job.pose, job.step, job.angle, job.true_angle});
      ROTOSCAN_RETURN_IF_ERROR(bundle::WriteTableAngles(bundle::TruthTableAnglesPath(work), angles));
    }
  }

  ProgressScope scope(progress, "render", jobs.size());
  std::atomic<std::size_t> next{0};
  std::mutex error_mutex;
  Status first_error;
  std::atomic<bool> failed{false};
  auto worker = [&] {
    for (;;) {
      if (failed.load() || scope.Cancelled()) return;
      const std::size_t j = next.fetch_add(1);
      if (j >= jobs.size()) return;
      const Job& job = jobs[j];
      if (JobDone(*writer, job, options.truth)) {  // written before an interruption
        scope.Advance();
        continue;
      }
      const Renderer& renderer = *renderers[kind == SimulateKind::kCheckerboard ? job.pose : 0];
      const uint64_t seed = FrameSeed(scene.seed, job.pose, job.step, 0);
      RenderedStep rendered = renderer.RenderStep(job.true_angle, seed, job.mask);
      Status status;
      for (int f = 0; f < 4 && status.ok(); ++f) {
        if (!job.mask[f]) continue;
        bundle::FrameRecord record = JobFrame(job, f);
        const int frame_index = (std::max(job.pose, 0) * std::max(steps, 1) + job.step) * 4 + f;
        record.trigger_seq = static_cast<uint32_t>(frame_index);
        record.device_time_us = static_cast<uint64_t>(std::llround(frame_index * kFramePeriodUs));
        record.exposure_us = f == 3 ? scene.sensor.natural_exposure_us : scene.sensor.laser_exposure_us;
        status = writer->AddFrame(record, rendered.frames[f]);
        if (status.ok() && options.truth && f < 2) {
          const auto truth = renderer.LineTruth(static_cast<geometry::LaserId>(f), job.true_angle);
          status = bundle::WriteLineTruth(bundle::LineTruthPath(work, record), truth);
        }
      }
      if (!status.ok()) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (first_error.ok()) first_error = status;
        failed = true;
        return;
      }
      scope.Advance();
    }
  };
  int threads = options.threads > 0 ? options.threads : static_cast<int>(std::thread::hardware_concurrency());
  threads = std::clamp(threads, 1, std::max<int>(1, static_cast<int>(jobs.size())));
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(worker);
  worker();
  for (std::thread& t : pool) t.join();
  if (!first_error.ok()) return first_error;
  if (scope.Cancelled()) {
    return CancelledError("rendering was interrupted; " + std::to_string(writer->frame_count()) +
                          " frames are kept in " + writer->working_directory().string() +
                          ": run the same command with --resume to finish it");
  }
  return writer->Finish();
}

}  // namespace rotoscan::sim
