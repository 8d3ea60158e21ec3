// Renders whole bundles on the virtual scanner (what `rotoscan simulate` runs):
//
//  * kScan: per table step (angle = step * step_deg) the frames left, right, off, natural; truth/ with
//    rig.yaml, object.ply and the line truth of every laser frame.
//  * kCalibrationObject: the paper's calibration object (two orthogonal planes with a 10 mm checker, Fig. 6)
//    standing on the table axis, at `steps` table angles spread over a quarter turn, each with left,
//    right, off and natural frames. Target frame: origin at the foot of the corner line, z up the corner
//    line, one plane y = 0 (x >= 0), the other x = 0 (y >= 0). truth/poses.csv has cam_from_target.
//  * kCheckerboard: a checkerboard (OpenCV's target frame: origin at the first inner corner, x along the
//    columns, y along the rows, z into the board) held at `steps` poses in front of the camera (pose index
//    = the frame's pose, step 0), natural frames only, for intrinsics. truth/poses.csv.
//  * kTableCheckerboard: the checkerboard standing upright on the table at the axis (as Ciclop/Horus
//    calibrate), turned through `steps` angles over a half turn centred on facing the camera, with left,
//    right, off and natural frames: laser planes and table axis. truth/poses.csv.
// Calibration kinds take their target from the scene's objects when it has one of the right type, and
// render with at least 2 x 2 supersampling (their checker patterns are also box-filtered analytically).
//
// Placements (scan kind): SimulateOptions::placement renders the scene put in that placement (PlaceScene);
// bundle.json records the index and truth/placement.csv the true table_from_reference.
//
// A table that slips (table_slip_deg > 0; scan, calib-object and table-checkerboard kinds): every table
// position is rendered at its commanded angle plus a deviation drawn uniformly in +-table_slip_deg (from the
// scene seed and the step, independent of the step count and the thread count), as a real turntable that
// misses or overshoots steps (issue 15: a real sweep stepped 2.9 or 4.05 degrees for a commanded 3.6).
// bundle.json keeps the commanded angle; the truth (truth/table_angles.csv, truth/poses.csv, the line
// truth) is at the true one. With SlipMode::kCumulative the deviations add up instead (a table that loses
// or gains steps does not find them again): position i of a pose stands at its commanded angle plus the sum
// of the deviations drawn for positions 0..i, a random walk that drifts away from the commanded angles.
//
// Frames are rendered in parallel (std::thread, one step at a time per thread); every frame's noise comes
// from FrameSeed(scene.seed, pose, step, frame), so the output does not depend on the thread count.
#pragma once

#include <filesystem>

#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::sim {

enum class SimulateKind { kScan, kCalibrationObject, kCheckerboard, kTableCheckerboard };

// How a slipping table's deviations behave (see the file comment): each position off on its own, or the
// deviations accumulating from position to position.
enum class SlipMode { kIndependent, kCumulative };
// "independent", "cumulative".
Result<SlipMode> ParseSlipMode(const std::string& name);

// "scan", "calib-object", "checkerboard", "table-checkerboard".
Result<SimulateKind> ParseSimulateKind(const std::string& name);

struct SimulateOptions {
  std::filesystem::path out;       // bundle directory to create
  SimulateKind kind = SimulateKind::kScan;
  int steps = 0;                   // 0: scene.steps for scans; 1, 12, 8 for the calibration kinds
  int threads = 0;                 // 0: all cores
  bool overwrite = false;
  bool resume = false;             // continue an interrupted bundle at `out` (same scene and options)
  bool truth = true;               // write truth/
  double table_slip_deg = 0.0;     // >= 0: largest deviation of a true table angle from the commanded one
                                   // (cumulative: the largest deviation added at one position)
  SlipMode table_slip_mode = SlipMode::kIndependent;
  // Scans: the object's placement on the table (Scene::placements, PlaceScene); recorded in bundle.json and,
  // with the truth, as truth/placement.csv.
  int placement = 0;
  double step_deg = 0.0;           // > 0: the table's step for this run instead of the scene's (scans)
};

Status Simulate(const Scene& scene, const SimulateOptions& options, Progress* progress);

}  // namespace rotoscan::sim
