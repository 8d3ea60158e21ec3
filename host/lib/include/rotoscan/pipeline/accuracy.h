// Accuracy of the line extraction against the virtual scanner's ground truth (bundle/truth.h,
// truth/lines/<frame>.csv: the exact sub-pixel column of (laser plane ∩ surface) per image row).
//
// An extracted point is matched to the nearest true crossing of its row; within `outlier_px` it counts
// toward the error statistics, further away it is an outlier (a reflection, a wrong peak). True rows with
// no extracted point are missed (too dark, rejected); extracted rows without truth are spurious.
//
// Measured along the row, the error of a steep line (one that runs along the rows: a surface seen at a
// grazing angle) is its error across the line times the slope, and a point that lies on the true line at
// another height is no error in 3D (it triangulates onto the true surface). So each point is also
// measured across the line: its distance to the true line, the polyline through the truth of nearby rows
// (the across_* figures).
#pragma once

#include <cmath>
#include <cstddef>
#include <filesystem>
#include <map>
#include <vector>

#include "rotoscan/bundle/truth.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"
#include "rotoscan/geometry/plane.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/laser/extract.h"
#include "rotoscan/pipeline/process.h"

namespace rotoscan::pipeline {

struct LineAccuracy {
  size_t frames = 0;
  size_t truth_rows = 0;  // rows with at least one true crossing
  size_t extracted = 0;
  size_t matched = 0;
  size_t outliers = 0;  // extracted, truth in the row, but further than outlier_px
  size_t spurious = 0;  // extracted where the truth has nothing
  size_t missed = 0;    // truth rows without an extracted point
  double sum_error = 0, sum_squared = 0, max_abs = 0;  // over matched points, px
  // Across the line (see above), over the extracted points with truth in their row: further than
  // outlier_px from the true line, or within it (and their squared distances, px^2).
  size_t across_outliers = 0, across_matched = 0;
  double across_sum_squared = 0;

  double rms_px() const { return matched > 0 ? std::sqrt(sum_squared / matched) : 0.0; }
  double across_rms_px() const { return across_matched > 0 ? std::sqrt(across_sum_squared / across_matched) : 0.0; }
  double mean_px() const { return matched > 0 ? sum_error / matched : 0.0; }
  void Add(const LineAccuracy& other);
};

// The distance (px) from (column, row) to the true line given as its crossings by row: the polyline
// through each true crossing and the nearest crossing of the next row (a pair more than 64 px apart is
// not one line), over the rows within 4; also to the crossings themselves (a line's end).
double DistanceAcrossLine(double column, int row, const std::map<int, std::vector<double>>& truth_by_row);

LineAccuracy CompareWithTruth(const laser::Line& line, const std::vector<bundle::LinePoint>& truth,
                              double outlier_px = 2.0);

// The same split by what the true line lies on. A row is the object's where any object's line crosses it,
// the table's where only the table top's line does (truth object 0); the two add up to `all`. A point is
// counted in its row's part (its errors still against the nearest true crossing in the row, whichever
// object's). The table's points are no less a user's than the object's: `rotoscan process` keeps every
// triangulated point, the table top's included.
struct LineAccuracyParts {
  LineAccuracy all, object, table;
  void Add(const LineAccuracyParts& other);
};
LineAccuracyParts CompareWithTruthByPart(const laser::Line& line, const std::vector<bundle::LinePoint>& truth,
                                         double outlier_px = 2.0);

// Extracts every laser frame of a scan bundle with truth/ (at most `max_frames`, 0 = all) and compares.
Result<LineAccuracy> MeasureLineAccuracy(const std::filesystem::path& bundle_dir,
                                         const laser::ExtractOptions& options, size_t max_frames = 0,
                                         double outlier_px = 2.0, Progress* progress = nullptr);
// The same, split by part (CompareWithTruthByPart).
Result<LineAccuracyParts> MeasureLineAccuracyByPart(const std::filesystem::path& bundle_dir,
                                                    const laser::ExtractOptions& options, size_t max_frames = 0,
                                                    double outlier_px = 2.0, Progress* progress = nullptr);

// The paper's Table 1 test: the cloud of a plane against the true plane. The true plane is fitted to the
// truth/lines points of object 1 (exact points of the rendered plane); the cloud points within
// `max_distance_mm` of it (the plane, not the table) give the RMS distance. Both are compared in the table
// frame at angle 0, where the cloud is: a calibrated rig has its origin on the table top too (calibration
// bundles carry the target's height above it, calib PlaceTableOrigin).
struct PlaneAccuracy {
  size_t points = 0;           // cloud points used
  double rms_mm = 0;           // RMS distance to the true plane
  double mean_mm = 0;          // mean signed distance (bias)
  geometry::Plane true_plane;  // table frame at angle 0
};
Result<PlaneAccuracy> MeasurePlaneAccuracy(const std::filesystem::path& bundle_dir, const geometry::Rig& rig,
                                           const ProcessOptions& options, double max_distance_mm = 2.0);

// Simulates the plane scene (data/scenes/plane-300mm.json with the plane at `distance_mm`, `steps` table
// steps, virtual scanner defaults: noise and speckle) into `work_dir`, processes it with the true rig and
// measures it. `scene_overrides` is extra scene JSON merged at the top level (e.g. "\"seed\": 3").
Result<PlaneAccuracy> RunPlaneAccuracy(double distance_mm, const std::filesystem::path& work_dir,
                                       int steps = 4, const std::string& scene_overrides = "",
                                       Progress* progress = nullptr);

}  // namespace rotoscan::pipeline
