// The paper's step 1 (§4.1): the 3x4 projection matrix T (eq. 3) from 3D-2D correspondences by the Direct
// Linear Transform (eq. 8-10), its decomposition into K [R | t], and the paper's triangulation of a laser
// pixel with T and a laser plane (eq. 6).
//
// Frames and units: `points_in_object` are in the calibration object's frame (mm); pixels are (column, row)
// as in camera.h. The DLT models a pinhole without distortion: feed it undistorted pixels when the lens
// distorts (the paper neglects distortion for its 20 degree lens).
//
// Estimation: eq. 9 stacks two rows per correspondence into A (2N x 12) and eq. 10 takes the unit X
// minimising |A X|, the right singular vector of the smallest singular value. Plain eq. 9 on pixel and mm
// coordinates is badly conditioned (entries from 1 to 1e5), so the points are first normalised as Hartley
// & Zisserman (Multiple View Geometry, §4.4.4) prescribe: 2D points to centroid 0 and mean distance sqrt(2),
// 3D points to centroid 0 and mean distance sqrt(3); T is de-normalised afterwards.
//
// Degenerate inputs (returned as kInvalidArgument, never a silent bad matrix): fewer than 6 points (11
// unknowns, 2 equations per point), coplanar or collinear object points (the DLT then has a family of
// solutions -- the paper's object has two orthogonal planes for this reason), and a rank-deficient A
// (e.g. all pixels identical).
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rotoscan/core/status.h"
#include "rotoscan/geometry/plane.h"

namespace rotoscan::geometry {

using ProjectionMatrix = Eigen::Matrix<double, 3, 4>;

struct DltEstimate {
  ProjectionMatrix projection;  // T of eq. 3, scaled so that |T(2, 0:3)| = 1 and points in front have w > 0
  double rms_px = 0.0;          // reprojection RMS of the input correspondences, pixels
  double max_px = 0.0;          // largest reprojection error, pixels
};

// T from N >= 6 correspondences (eq. 8-10 with Hartley normalisation).
Result<DltEstimate> EstimateProjectionDlt(const std::vector<Eigen::Vector3d>& points_in_object,
                                          const std::vector<Eigen::Vector2d>& pixels);

// Pixel of a point under T (eq. 3); the point must not lie on T's principal plane (w != 0).
Eigen::Vector2d ProjectWithMatrix(const ProjectionMatrix& projection, const Eigen::Vector3d& point_in_object);

struct ProjectionDecomposition {
  Eigen::Matrix3d K;                  // upper triangular, K(2, 2) = 1, positive diagonal; K(0, 1) is the skew
  Eigen::Isometry3d cam_from_object;  // rotation (det +1) and translation (mm)
};

// T = s K [R | t] by RQ decomposition of T's left 3x3 block. kInvalidArgument when that block is singular
// (not a finite camera).
Result<ProjectionDecomposition> DecomposeProjection(const ProjectionMatrix& projection);

// The paper's eq. 6: the object point seen at `pixel` that lies on `plane_in_object` (n . X + d = 0 in the
// object frame; the paper's c of eq. 5 is n / d). Solves the 3x3 system of eq. 6 written with n and d so
// that it also holds for a plane through the origin. kInvalidArgument when the viewing ray is parallel to
// the plane (the system is singular).
Result<Eigen::Vector3d> TriangulateWithPlane(const ProjectionMatrix& projection, const Plane& plane_in_object,
                                             const Eigen::Vector2d& pixel);

// The plane-to-plane homography H (3x3, up to scale) with to ~ H from, by the same normalised DLT: two rows
// per correspondence, the unit h minimising |A h|. Units are the caller's (e.g. pixels to mm on a target
// plane). kInvalidArgument for fewer than 4 correspondences, non-finite input, points that all
// coincide, or a rank-deficient system (e.g. three of four points on one line); lists of different sizes
// are a broken precondition.
Result<Eigen::Matrix3d> EstimateHomographyDlt(const std::vector<Eigen::Vector2d>& from,
                                              const std::vector<Eigen::Vector2d>& to);

}  // namespace rotoscan::geometry
