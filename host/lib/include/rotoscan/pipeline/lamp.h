// The lamp of the natural frames, calibrated from a scan of a matte white sphere (`rotoscan calibrate
// lamp`; data/scenes/lamp-sphere.json renders one), for the color pass (pipeline/color.h) to divide out.
//
// The lamp model is color.h's: far, Lambertian, fixed to the camera; a surface point of albedo a and
// normal n (camera frame) appears as I = a * (1 + max(0, n . L)) up to one global factor, where L is the
// direction towards the lamp times its diffuse / ambient ratio.
//
// Method: the bundle is processed (laser points only, no color) and a sphere is fitted to the points above
// the table (algebraic least squares, |p|^2 = 2 c . p + r^2 - |c|^2, then points further than 3 MADs or
// 0.3 mm from it dropped and the fit repeated; at least 80 % of the points must stay on it). In each of up to
// `max_frames` natural frames, every pixel whose ray meets the sphere gives the sphere's normal there, n = (p
// - c) / r in the camera frame, and its luminance. Pixels near the sphere's outline (the normal at less than
// `min_cos_view` to the ray: the image blur mixes them with the background) and saturated pixels are left
// out. Then
//   I = A + max(0, n . B)       (A = a, B = a L)
// is linear in (A, B) once each pixel is known to be lit (n . B > 0) or not: starting from the fit over all
// pixels, each pixel is classified by the current B, pixels within `terminator_band` of the terminator
// (n . B / |B| in [-band, band]: the blur mixes both sides there) are left out, and the linear least
// squares is solved again, until the classification no longer changes. L = B / A.
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>

#include <Eigen/Core>

#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"
#include "rotoscan/geometry/rig.h"

namespace rotoscan::pipeline {

struct LampCalibrationOptions {
  int max_frames = 8;             // natural frames used, spread over the bundle's steps
  double min_cos_view = 0.3;      // a pixel's sphere normal must face the camera at least this squarely
  double terminator_band = 0.08;  // pixels with |n . B| / |B| below this are left out
  int saturation = 250;           // 8-bit level at which a pixel counts as saturated
  double min_height_mm = 1.0;     // laser points lower than this above the table are not the sphere's
  int threads = 0;                // 0: all cores
  Status Check() const;
};

struct LampCalibration {
  Eigen::Vector3d lamp_in_cam = Eigen::Vector3d::Zero();  // L: direction (camera frame) x diffuse / ambient
  double ambient_level = 0;  // A: the sphere's unlit level (8-bit), for the report
  Eigen::Vector3d sphere_centre_in_table = Eigen::Vector3d::Zero();
  double sphere_radius_mm = 0;
  double sphere_rms_mm = 0;  // the points' RMS distance from the fitted sphere
  size_t sphere_points = 0;
  int frames = 0;           // natural frames used
  size_t pixels = 0;        // pixels in the final fit
  double relative_rms = 0;  // the fit's RMS residual / the mean level of its pixels
};

// kInvalidArgument for bad options; kNotFound / kCorruptData for an unreadable bundle;
// kFailedPrecondition when no sphere is found in the laser points (too few, or they do not lie on one),
// when no natural frame shows it, or when the fit is not well posed (too few lit pixels).
Result<LampCalibration> CalibrateLamp(const std::filesystem::path& bundle_dir, const geometry::Rig& rig,
                                      const LampCalibrationOptions& options, Progress* progress = nullptr);

std::string FormatLampCalibration(const LampCalibration& calibration);

// Writes `lamp_in_cam` into calib.yaml at `path` (key lamp, geometry/rig.h), keeping the file's other keys
// (the calibration report) as they were; replaces an earlier lamp. Atomic; the result is read back.
Status WriteLampIntoCalibration(const std::filesystem::path& path, const Eigen::Vector3d& lamp_in_cam);

}  // namespace rotoscan::pipeline
