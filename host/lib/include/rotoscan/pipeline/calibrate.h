// Calibrating the rig from calibration bundles (what `rotoscan calibrate BUNDLE...` runs): the bundles'
// frames turned into observations for calib/rig_calibration.h, the paper's three steps (§4) as the initial
// value, then the joint refinement; and the end-to-end accuracy of a rig calibrated from rendered bundles.
//
// Observations (ObservationsFromBundles): every (bundle, pose) is one placement of the target (a
// checkerboard, or the paper's two-plane calibration object, calib/calibration_object.h). The target's
// corners come from the natural frame (else the off frame) of each step; the laser pixels from the
// left/right frames against the off frame of the same step (laser/extract.h), kept only inside the board's
// outer corners, or inside one face of the object (the line also crosses the table top), each with the
// target plane it lies on (the rig calibration's LaserView::plane_in_target).
//
// Laser pixels next to a checker edge are dropped. The line's centre is the centroid of its profile along
// the image row, and where the target's albedo changes inside that profile (a black/white edge) the centroid
// is pulled towards the white side, by up to the line's half width. The bias is worst when the line runs
// along an edge of the checker (the laser planes contain the table axis and the checker's columns are
// parallel to it on an upright board, so at some table angle the whole line lies within a square's edge):
// on the demo's rendered bundles (2 placements x 24 angles), 390 pixels of two left-laser frames lay 2.3 px
// off the true line and made the left plane's residual 0.048 mm (right: 0.011) and its offset error
// 0.061 mm; without them, 0.007 mm for both. A pixel is kept only when its profile (+-1 FWHM + 1 px along
// the row, mapped onto the target plane by the homography of the view's corners, geometry/dlt.h) stays
// inside one square; pixels within the extractor's along-line smoothing window (+-smooth_half_rows) of a
// dropped one are dropped too, since the smoothing spreads its bias along the line.
//
// Units and frames: as calib/rig_calibration.h (mm, radians; the rig in the camera frame, the table frame's
// origin on the table top when the bundles give the target's height above it).
#pragma once

#include <array>
#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include "rotoscan/calib/rig_calibration.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"
#include "rotoscan/geometry/rig.h"

namespace rotoscan::pipeline {

// Corners and laser pixels of calibration bundles (checkerboards or the paper's calibration object), every
// (bundle, pose) one placement, numbered densely in the order of the bundles. Errors: an unreadable bundle,
// a scan bundle, a target that is not a calibration target, bundles of different image sizes or table
// steps, no bundle with a table step (kInvalidArgument naming the bundle). Views where the target is not
// found are left out with one warning per bundle (logging.h; each frame's reason at debug level).
Result<calib::CalibrationData> ObservationsFromBundles(const std::vector<std::filesystem::path>& bundle_dirs,
                                                       Progress* progress = nullptr);

struct CalibrateOptions {
  calib::RigCalibrationOptions calibration;  // the three steps and the joint refinement
};

// How far a rig lies from the true one (a virtual scanner's truth/rig.yaml).
struct RigError {
  double fx_percent = 0.0;             // 100 (fx / true fx - 1), signed
  std::array<double, 2> normal_deg{};  // angle between each laser plane's normal and the truth's
  std::array<double, 2> offset_mm{};   // |offset - true offset| of each plane (canonical form)
  double axis_offset_mm = 0.0;         // distance of the true axis point from the axis, across it
  double axis_angle_deg = 0.0;         // angle between the axis directions
  double table_top_mm = 0.0;           // |along-axis offset| of the table frame's origin
};
RigError CompareRigs(const geometry::Rig& estimate, const geometry::Rig& truth);

// The outcome of CalibrateFromBundles. The rig to use is calibration.estimate.rig; calibration.summary is
// the report (pass/fail, residuals, standard deviations) that calib.yaml and --report carry.
struct BundleCalibration {
  calib::RigCalibration calibration;                // the joint refinement
  calib::RigEstimate three_step;                    // its initial value (the paper's three steps)
  calib::RigCalibrationSummary three_step_summary;  // residuals of `three_step` on the same observations
  // Virtual-scanner bundles carry the true rig: the last bundle's truth/rig.yaml (the others should hold
  // the same rig) and each estimate's error from it. has_truth false: no bundle has one.
  bool has_truth = false;
  std::filesystem::path truth_path;
  RigError three_step_error, joint_error;
};

// Observations from `bundle_dirs`, the three steps and the joint refinement (calib::CalibrateThreeStep,
// calib::RefineRig). A calibration that fails its checks is a result (summary.passed false, the reasons
// in summary.failures), not an error; errors are what ObservationsFromBundles and the calibration steps
// return (no bundle, the target seen too little to solve: kInvalidArgument saying what to capture;
// kNotConverged).
Result<BundleCalibration> CalibrateFromBundles(const std::vector<std::filesystem::path>& bundle_dirs,
                                               const CalibrateOptions& options = {},
                                               Progress* progress = nullptr);

// Writes the report as JSON to `report_json` (when not empty) and then calib.yaml to `calib_yaml`, each
// atomically: a failure writing the report leaves no calib.yaml that looks like a finished run.
Status WriteBundleCalibration(const BundleCalibration& result, const std::filesystem::path& calib_yaml,
                              const std::filesystem::path& report_json = {});

// One line per figure (intrinsics, residuals, predicted point error, notes, the three-step residuals, the
// errors from the truth when known), for the CLI and logs; the pass/fail verdict is left to the caller.
std::string FormatCalibrationSummary(const BundleCalibration& result);

// The plane test of issue 4 (pipeline/accuracy.h) scanned with a rig calibrated from rendered calibration
// bundles, with the lens distortion k1 switched on in the virtual camera: once with the three-step result,
// once with the joint refinement, and once with the true rig for reference (what `rotoscan bench accuracy
// --calib` runs). The calibration target:
//  * kObject: the paper's object (data/scenes/calibration-object*.json placements); the three steps are the
//    paper's (DLT, no distortion). With board_poses > 0 a hand-held checkerboard bundle joins the
//    calibration (used by the joint refinement only, for distortion).
//  * kTableBoard: the demo's capture, the checkerboard standing on the table in the placements of
//    data/scenes/calibration.json, -2 and -3; the three steps then model distortion too (OpenCV's
//    calibrateCamera), and the joint refinement adds the table and laser constraints to it.
enum class CalibrationTarget { kObject, kTableBoard };
struct CalibratedAccuracyOptions {
  CalibrationTarget target = CalibrationTarget::kObject;
  double distance_mm = 300.0;  // plane from the camera, mm
  double k1 = -0.2;            // radial distortion of the virtual camera (normalised coordinates)
  int scan_steps = 4;          // table steps of the plane scan
  int calibration_steps = 9;   // table angles per placement (object: over a quarter turn; board: 120 degrees)
  int board_poses = 0;         // > 0: also a hand-held checkerboard bundle of that many poses
  std::filesystem::path work_dir;  // the bundles are rendered here (overwritten)
};
struct CalibratedAccuracy {
  // RMS and mean signed distance (mm) of the plane's points from the true plane, scanned with each rig.
  double three_step_rms_mm = 0.0, joint_rms_mm = 0.0, true_rig_rms_mm = 0.0;
  double three_step_mean_mm = 0.0, joint_mean_mm = 0.0, true_rig_mean_mm = 0.0;
  std::size_t points = 0;  // points of the jointly refined rig's cloud within 5 mm of the true plane
  calib::RigCalibrationSummary three_step, joint;
};
Result<CalibratedAccuracy> RunCalibratedPlaneAccuracy(const CalibratedAccuracyOptions& options,
                                                      Progress* progress = nullptr);

}  // namespace rotoscan::pipeline
