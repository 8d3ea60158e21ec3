// RunCalibratedPlaneAccuracy (pipeline/calibrate.h): render calibration bundles and a plane scan on the
// virtual scanner, calibrate from the bundles, and measure the plane scanned with each rig.
#include <string>
#include <vector>

#include "rotoscan/pipeline/accuracy.h"
#include "rotoscan/pipeline/calibrate.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"

namespace rotoscan::pipeline {
namespace {

// Renders the scene `json` into work_dir/name and appends the bundle to `bundles`.
Status Render(const std::string& json, const std::string& what, const CalibratedAccuracyOptions& options,
              const std::string& name, sim::SimulateKind kind, int steps, Progress* progress,
              std::vector<std::filesystem::path>* bundles) {
  ROTOSCAN_ASSIGN_OR_RETURN(const sim::Scene scene, sim::ParseScene(json, options.work_dir, what));
  sim::SimulateOptions simulate;
  simulate.out = options.work_dir / name;
  simulate.kind = kind;
  simulate.steps = steps;
  simulate.overwrite = true;
  ROTOSCAN_RETURN_IF_ERROR(sim::Simulate(scene, simulate, progress));
  bundles->push_back(simulate.out);
  return Status::Ok();
}

// The calibration bundles of `options.target` (and the hand-held board's) with distortion `camera`.
Result<std::vector<std::filesystem::path>> RenderCalibrationBundles(const CalibratedAccuracyOptions& options,
                                                                    const std::string& camera,
                                                                    Progress* progress) {
  std::vector<std::filesystem::path> bundles;
  // One calibration bundle of `object` (a JSON object without its closing brace) standing at `placement`.
  auto render = [&](int seed, const std::string& object, const char* placement, const std::string& name,
                    sim::SimulateKind kind) -> Status {
    const std::string json = "{\"seed\": " + std::to_string(seed) + ", " + camera + ", \"objects\": [" +
                             object + ", " + placement + "}]}";
    return Render(json, "calibration scene", options, name, kind, options.calibration_steps, progress,
                  &bundles);
  };
  if (options.target == CalibrationTarget::kObject) {
    // The placements of data/scenes/calibration-object.json and calibration-object-2.json.
    const char* placements[] = {"\"position_mm\": [0, 20, 0]",
                                "\"position_mm\": [-30, 60, 0], \"rotation_deg\": [0, 0, 30]"};
    for (int p = 0; p < 2; ++p) {
      ROTOSCAN_RETURN_IF_ERROR(render(p + 1, "{\"type\": \"calibration_object\", \"square_mm\": 10",
                                      placements[p], "calibration-object-" + std::to_string(p + 1),
                                      sim::SimulateKind::kCalibrationObject));
    }
  } else {
    // The placements of data/scenes/calibration.json, calibration-2.json and calibration-3.json.
    const char* placements[] = {"\"position_mm\": [20, 20, 0]", "\"position_mm\": [-20, -20, 0]",
                                "\"position_mm\": [0, 25, 0], \"rotation_deg\": [-25, 0, 0]"};
    for (int p = 0; p < 3; ++p) {
      ROTOSCAN_RETURN_IF_ERROR(render(
          p + 1, "{\"type\": \"checkerboard\", \"cols\": 15, \"rows\": 12, \"square_mm\": 4", placements[p],
          "table-board-" + std::to_string(p + 1), sim::SimulateKind::kTableCheckerboard));
    }
  }
  if (options.board_poses > 0) {
    // A checkerboard held over the whole field of view: it fixes the lens distortion, which the object
    // (in the middle of the image) leaves loose. The three-step result does not use it (the paper's DLT
    // models no distortion); the joint refinement does.
    const std::string json = "{\"seed\": 3, " + camera +
                             ", \"objects\": [{\"type\": \"checkerboard\", \"cols\": 9, \"rows\": 6, "
                             "\"square_mm\": 7}]}";
    ROTOSCAN_RETURN_IF_ERROR(Render(json, "board scene", options, "checkerboard",
                                    sim::SimulateKind::kCheckerboard, options.board_poses, progress,
                                    &bundles));
  }
  return bundles;
}

}  // namespace

Result<CalibratedAccuracy> RunCalibratedPlaneAccuracy(const CalibratedAccuracyOptions& options,
                                                      Progress* progress) {
  if (options.work_dir.empty()) return InvalidArgumentError("no work directory");
  const std::string camera = "\"camera\": {\"distortion\": [" + std::to_string(options.k1) + ", 0, 0, 0, 0]}";
  ROTOSCAN_ASSIGN_OR_RETURN(const std::vector<std::filesystem::path> bundles,
                            RenderCalibrationBundles(options, camera, progress));
  ROTOSCAN_ASSIGN_OR_RETURN(const BundleCalibration calibrated, CalibrateFromBundles(bundles, {}, progress));

  const std::string json = "{" + camera + ", \"objects\": [{\"type\": \"plane\", \"distance_mm\": " +
                           std::to_string(options.distance_mm) +
                           ", \"angle_deg\": 20, \"size_mm\": [150, 120], \"color\": [0.9, 0.9, 0.9]}]}";
  std::vector<std::filesystem::path> plane;
  ROTOSCAN_RETURN_IF_ERROR(Render(json, "plane scene", options, "plane", sim::SimulateKind::kScan,
                                  options.scan_steps, progress, &plane));
  ROTOSCAN_ASSIGN_OR_RETURN(const sim::Scene scene, sim::ParseScene(json, options.work_dir, "plane scene"));
  ProcessOptions process;
  process.merge = false;  // both lasers measure the same plane; keep every point
  // A calibrated rig may put the plane a few millimetres off: points within 5 mm of the true plane count
  // (the true rig's, within the test's usual 2 mm).
  constexpr double kCalibratedWindowMm = 5.0;
  Result<PlaneAccuracy> a3 =
      MeasurePlaneAccuracy(plane[0], calibrated.three_step.rig, process, kCalibratedWindowMm);
  if (!a3.ok()) return a3.status().WithContext("plane scanned with the three-step rig");
  Result<PlaneAccuracy> aj =
      MeasurePlaneAccuracy(plane[0], calibrated.calibration.estimate.rig, process, kCalibratedWindowMm);
  if (!aj.ok()) return aj.status().WithContext("plane scanned with the jointly refined rig");
  ROTOSCAN_ASSIGN_OR_RETURN(const PlaneAccuracy at, MeasurePlaneAccuracy(plane[0], scene.rig, process));
  CalibratedAccuracy out;
  out.three_step_rms_mm = a3->rms_mm;
  out.three_step_mean_mm = a3->mean_mm;
  out.joint_rms_mm = aj->rms_mm;
  out.joint_mean_mm = aj->mean_mm;
  out.true_rig_rms_mm = at.rms_mm;
  out.true_rig_mean_mm = at.mean_mm;
  out.points = aj->points;
  out.three_step = calibrated.three_step_summary;
  out.joint = calibrated.calibration.summary;
  return out;
}

}  // namespace rotoscan::pipeline
