// Several placements of one object, aligned and merged into one cloud (`rotoscan merge`): a turntable scan
// never sees what faces the table, and sees the top of the object at grazing angles only, so the object is
// scanned again lying on its side (bundle.json "placement") and the clouds are aligned here.
//
// Alignment of a source cloud onto a target cloud (AlignClouds), in three stages:
//  1. Global registration, robust to partial overlap: both clouds thinned on a voxel grid (voxel_mm),
//     FPFH features (Rusu et al., ICRA 2009) on them, RANSAC over mutual feature matches with edge-length
//     and distance checks (Open3D's pipelines::registration, Debian's libopen3d-dev). With a hint
//     (AlignOptions::hint) this stage is skipped and the hint is the start.
//  2. Point-to-plane ICP from that start, coarse to fine (correspondence distance 8, 2, then
//     icp_distance_mm; the last stage on the clouds thinned to fine_voxel_mm), then the same last stage
//     robust (unless tukey_constant is 0): Tukey's biweight on the point-to-plane residuals with
//     c = tukey_constant x their robust scale (1.4826 x the median |residual|, ~0.019 mm on the demo's
//     scans; 4.685: 95 % efficiency for Gaussian residuals), the scale estimated again after each round
//     (at most 3). Plain least squares is pulled by the pairs that are not the same surface (a source point
//     where the target has a hole or an edge is paired up to icp_distance_mm away): on the demo's Spot
//     (upright + nose down, 200 + 200 steps) the error against the true pose fell from 0.0060 mm / 0.013°
//     to 0.0034 mm / 0.008°, on the best pair of poses from 0.010 mm / 0.026° to 0.0047 mm / 0.008°.
//  3. Ambiguity: on the clouds thinned to 2 x voxel_mm, from the refined alignment turned by each of the
//     24 rotations of a cube and by `random_starts` random rotations (about the source's centroid), ICP
//     again; an alignment that ends more than distinct_deg / distinct_mm from the best and scores (its
//     overlap within 2 x voxel_mm) at least ambiguity_ratio x the best's is a second answer as good as the
//     first: the object is (nearly) symmetric (a sphere, a cylinder) and the alignment is refused
//     (kFailedPrecondition) unless a hint was given, which then decides: the hint's rotation is kept (it
//     cannot be observed) and the translation alone is fitted (point-to-plane).
//
// Overlap: the fraction of the (thinned) source points that have a target point within icp_distance_mm
// after the alignment; below min_overlap the alignment is refused (too little in common to trust it).
// Residual: the RMS of the point-to-point distances of those pairs (mm).
//
// Merge (MergePlacements): cloud 0 is the reference frame (its table frame); every other cloud is aligned
// onto all the clouds merged before it and moved into that frame (points and normals), every point keeps
// its placement (cloud::CloudPoint::placement, the PLY property `placement`). Nothing is dropped or
// averaged: where placements overlap both are kept (meshing fuses them). The disagreement of each
// placement with the others is measured like the two lasers' (cloud/merge.h).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rotoscan/cloud/cloud.h"
#include "rotoscan/cloud/merge.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"

namespace rotoscan::pipeline {

struct AlignOptions {
  double voxel_mm = 1.0;           // thinning for features, global registration and the ambiguity test
  double fine_voxel_mm = 0.3;      // thinning for the last ICP stage (0: every point)
  double feature_radius_mm = 5.0;  // FPFH support radius
  int ransac_iterations = 100000;
  double ransac_confidence = 0.999;
  double icp_distance_mm = 0.5;   // last ICP stage and the overlap's distance
  double tukey_constant = 4.685;  // robust last stage: Tukey's c in residual scales (0: none)
  double min_overlap = 0.15;      // fraction of the source; less is refused
  double ambiguity_ratio = 0.85;  // a distinct alternative scoring at least this x the best: ambiguous
  double distinct_deg = 3.0;      // alternatives closer than this (and distinct_mm) are the same answer
  double distinct_mm = 1.0;
  int random_starts = 6;  // random rotations tried besides the cube's 24 (ambiguity test)
  uint64_t seed = 1;
  // A rough target_from_source from the user (skips the global registration; decides an ambiguity).
  std::optional<Eigen::Isometry3d> hint;
  Status Check() const;
};

struct AlignResult {
  Eigen::Isometry3d target_from_source = Eigen::Isometry3d::Identity();
  double overlap = 0;      // fraction of source points with a target point within icp_distance_mm
  double residual_mm = 0;  // RMS distance of those pairs
  double residual_scale_mm = 0;  // robust scale of the point-to-plane residuals (0: no robust stage)
  bool from_hint = false;
  double global_fitness = 0;  // RANSAC's fitness (fraction of source points with an inlier), 0 with a hint
  // The ambiguity test's scores (overlap on the 2 x voxel_mm clouds within 2 x voxel_mm):
  // the answer's, and the best alternative's distinct from it, with how far that one is.
  double coarse_overlap = 0;
  double alternative_overlap = 0;
  double alternative_deg = 0, alternative_mm = 0;
  int alternatives_tried = 0;
};

// Aligns `source` onto `target` (both with normals; the result maps source points into the target frame).
// kInvalidArgument for bad options or a cloud with fewer than 100 points; kFailedPrecondition, with the
// figures in the message, when the alignment is ambiguous or the overlap too small.
Result<AlignResult> AlignClouds(const cloud::PointCloud& target, const cloud::PointCloud& source,
                                const AlignOptions& options, Progress* progress = nullptr);

struct PlacementReport {
  int placement = 0;  // index in the merged cloud (the order of the inputs)
  size_t points = 0;
  AlignResult alignment;                  // identity for placement 0
  cloud::LaserDisagreement disagreement;  // this placement against all the others, after alignment
};

struct MergePlacementsResult {
  cloud::PointCloud cloud;  // in placement 0's table frame; CloudPoint::placement set
  std::vector<PlacementReport> placements;
};

// Aligns clouds[1..] onto clouds[0] (each onto everything merged before it) and merges them. `hints`
// empty or one per cloud (hints[0] ignored; nullopt: automatic): a rough reference_from_cloud.
// `overlap_radius_mm`: the disagreement's pairing radius. Errors of AlignClouds name the cloud.
Result<MergePlacementsResult> MergePlacements(const std::vector<cloud::PointCloud>& clouds,
                                              const AlignOptions& options,
                                              const std::vector<std::optional<Eigen::Isometry3d>>& hints = {},
                                              double overlap_radius_mm = 2.0, Progress* progress = nullptr);

// The error of an estimated target_from_source against the true one over a surface (vertices and faces
// in the source frame): the area-weighted RMS of |estimated(p) - true(p)| over the faces' centroids (mm)
// and the angle of estimated^-1 * true (degrees).
struct AlignmentError {
  double rms_mm = 0;
  double angle_deg = 0;
  double translation_mm = 0;  // of estimated^-1 * true at the surface's centroid
};
AlignmentError MeasureAlignmentError(const Eigen::Isometry3d& estimated, const Eigen::Isometry3d& truth,
                                     const std::vector<Eigen::Vector3f>& vertices,
                                     const std::vector<Eigen::Vector3i>& faces);

// "rx,ry,rz,tx,ty,tz" (degrees about x, then y, then z; mm) or a file holding a 4x4 matrix (16 numbers,
// row-major) or those 6 numbers: a rough target_from_source. kInvalidArgument naming what is wrong.
Result<Eigen::Isometry3d> ParsePoseHint(const std::string& text);

// One line per placement: alignment figures and disagreement.
std::string FormatPlacementReport(const MergePlacementsResult& result);

}  // namespace rotoscan::pipeline
