// What the calibrate command shares with other commands (bench): observations from calibration bundles,
// and the end-to-end accuracy of a calibration made from rendered bundles.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "rotoscan/calib/rig_calibration.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"

namespace rotoscan::cli {

// Corners and laser pixels of calibration bundles (checkerboards or the paper's calibration object): every
// (bundle, pose) is one placement.
Result<calib::CalibrationData> ObservationsFromBundles(const std::vector<std::string>& directories,
                                                       Progress* progress);

// The plane test of issue 4 (pipeline/accuracy.h) scanned with a rig calibrated from rendered calibration
// bundles, with the lens distortion k1 switched on in the virtual camera: once with the three-step result,
// once with the joint refinement, and once with the true rig for reference. The calibration target:
//  * kObject: the paper's object (data/scenes/calibration-object*.json placements); the three steps are the
//    paper's (DLT, no distortion). With board_poses > 0 a hand-held checkerboard bundle joins the
//    calibration (used by the joint refinement only, for distortion).
//  * kTableBoard: the demo's capture, the checkerboard standing on the table in the placements of
//    data/scenes/calibration.json, -2 and -3; the three steps then model distortion too (OpenCV's
//    calibrateCamera), and the joint refinement adds the table and laser constraints to it.
enum class CalibrationTarget { kObject, kTableBoard };
struct CalibratedAccuracyOptions {
  CalibrationTarget target = CalibrationTarget::kObject;
  double distance_mm = 300.0;
  double k1 = -0.2;
  int scan_steps = 4;         // table steps of the plane scan
  int calibration_steps = 9;  // table angles per placement (object: over a quarter turn; board: 120 degrees)
  int board_poses = 0;        // > 0: also a hand-held checkerboard bundle of that many poses
  std::filesystem::path work_dir;
};
struct CalibratedAccuracy {
  double three_step_rms_mm = 0.0, joint_rms_mm = 0.0, true_rig_rms_mm = 0.0;
  double three_step_mean_mm = 0.0, joint_mean_mm = 0.0, true_rig_mean_mm = 0.0;
  std::size_t points = 0;
  calib::RigCalibrationSummary three_step, joint;
};
Result<CalibratedAccuracy> RunCalibratedPlaneAccuracy(const CalibratedAccuracyOptions& options,
                                                      Progress* progress);

}  // namespace rotoscan::cli
