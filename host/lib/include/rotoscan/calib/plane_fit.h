// Laser plane from 3D points: the paper's step 2 (§4.2, eq. 11-12) and two better estimators.
//
//  * FitPlanePaper: eq. 12, C = -(P^T P)^-1 P^T 1 for c . X + 1 = 0. It minimises the algebraic residual
//    c . X + 1, not the distance to the plane, and fails for a plane through the origin (here the camera
//    centre: a laser plane is never there, but the method weights points by their distance from it).
//    Kept for the paper comparison.
//  * FitPlaneTotalLeastSquares: the plane minimising the sum of squared orthogonal distances (normal =
//    the smallest principal axis of the centred points). This is the maximum-likelihood plane for isotropic
//    3D noise and is what the calibration uses for a clean point set.
//  * FitPlaneRobust: RANSAC on minimal 3-point samples with a fixed seed (deterministic), then a total least
//    squares refit on the inliers. Used for laser points, where reflections and extractor mistakes give
//    gross outliers that would tilt a least-squares plane. RANSAC rather than IRLS because a few far
//    outliers can pull an IRLS start into a wrong basin, while RANSAC only needs one clean sample.
//
// Frames: the points in any one frame (the camera frame in the calibration), mm; the plane is in that frame.
// Degenerate inputs (fewer than 3 points, collinear points) are kInvalidArgument.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "rotoscan/core/status.h"
#include "rotoscan/geometry/plane.h"

namespace rotoscan::calib {

struct PlaneFit {
  geometry::Plane plane;          // unit normal, offset in mm
  double rms_mm = 0.0;            // RMS orthogonal distance of the inliers
  double max_abs_mm = 0.0;        // largest |distance| of an inlier
  int inliers = 0;                // points used in the final fit
  std::vector<bool> inlier_mask;  // per input point (all true for the non-robust fits)
};

Result<PlaneFit> FitPlanePaper(const std::vector<Eigen::Vector3d>& points);
Result<PlaneFit> FitPlaneTotalLeastSquares(const std::vector<Eigen::Vector3d>& points);

struct RobustPlaneOptions {
  double inlier_threshold_mm = 0.5;  // |distance| under which a point supports a plane
  int iterations = 500;              // RANSAC samples
  std::uint32_t seed = 1;            // fixed seed: the same input gives the same plane
  double min_inlier_fraction = 0.5;  // below this the fit fails ("laser mostly off the target?")
  Status Check() const;
};

Result<PlaneFit> FitPlaneRobust(const std::vector<Eigen::Vector3d>& points,
                                const RobustPlaneOptions& options = {});

}  // namespace rotoscan::calib
