// A scanned cloud against the true surface of a virtual-scanner bundle (truth/object.ply, truth/rig.yaml):
// distance to the surface, coverage of the visible surface per laser (the paper's Fig. 9: two lasers
// leave fewer shadows than one) and color error against the true albedo.
//
// Distance: exact point-to-triangle distance to the true mesh (Open3D's RaycastingScene, Embree's point
// queries underneath; no surface sampling, so no sampling error).
//
// Visible surface: the true mesh sampled uniformly by area (one sample per spacing^2, fixed seed); a sample
// is visible when, at one of the bundle's table angles at least, it faces the camera, projects inside the
// image and nothing of the object lies between it and the camera centre (Embree occlusion ray). Samples
// less than `table_clearance_mm` above the table top are left out (the object's soles stand on it). The
// table top itself is not part of truth/object.ply, so it is neither sampled nor an occluder (the camera
// looks down at it, so it hides nothing above it).
//
// Coverage: the fraction of visible samples with a cloud point within `coverage_radius_mm`, for the points
// of the left laser, of the right laser and of both; and the fraction of the whole true surface (every
// sample above the table clearance, visible from these views or not: what a merged cloud of several
// placements covers). A scan samples the surface along laser lines one table step apart, so the radius must
// bridge half the gap between lines, and no more, so that coverage measures holes and not sampling: the
// automatic radius follows the scan's own point spacing, max(0.5 mm, 0.6 x the 95th percentile of the
// distance from a point to the nearest point of another laser line (another step or laser) of its own
// placement, for the coarsest placement of a merged cloud);
// for a cloud without that information, max(0.5 mm, 0.6 * r_max * step) with r_max the largest distance of
// the mesh from the table axis and step the median angle between the bundle's table angles. The report
// says which rule gave the radius. For per-laser figures, evaluate a cloud processed with --no-merge (the
// merge drops one laser's points where both saw the surface).
//
// Color: the true albedo (0..1) at the closest surface point of every point within `color_max_distance_mm`
// of the surface, times 255, against the point's 8-bit color after one least-squares gain per channel
// (g = sum(m t) / sum(m^2)): the natural image's exposure, sensor sensitivity and lamp brightness scale
// every color by one unknown factor per channel, which says nothing about the scanner. The lamp's shading
// (cos of incidence) and its cast shadows still vary from point to point and stay in the error. The true
// albedo is the scene's texture when the scene is given (exact: the renderer's own Mesh::Albedo at the
// closest point), else the barycentric interpolation of truth/object.ply's vertex colors, which for a
// textured mesh are texture samples at the vertices only (a blurred truth: use the scene).
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rotoscan/bundle/truth.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"
#include "rotoscan/geometry/camera.h"
#include "rotoscan/geometry/rig.h"

namespace rotoscan::pipeline {

struct TruthSurface {
  bundle::TruthMesh mesh;  // table frame, mm; vertex colors optional
  // True albedo RGB (0..1) at face `face`, barycentric (u, v) with p = (1-u-v) v0 + u v1 + v v2, position
  // `point_in_table`. Empty: interpolated vertex colors (no colors at all: color error is not measured).
  std::function<Eigen::Vector3f(int face, float u, float v, const Eigen::Vector3d& point_in_table)> albedo;
  std::string color_source = "vertex colors";  // for the report
};

// The views the visible surface is defined by: the camera and cam_from_table at every table angle.
struct EvaluationViews {
  geometry::CameraModel camera;
  std::vector<Eigen::Isometry3d> cam_from_table;
  double step_rad = 0.0;  // median angle between consecutive views (for the automatic radius), 0: unknown
};

struct EvaluateOptions {
  double sample_spacing_mm = 0.25;     // one surface sample per spacing^2 of area
  double coverage_radius_mm = 0.0;     // 0: automatic (file comment)
  double table_clearance_mm = 0.5;     // samples lower than this are on the table top
  double color_max_distance_mm = 1.0;  // points further from the surface get no color error
  double color_tolerance = 10.0;       // 8-bit levels, for the "within" fraction
  uint64_t seed = 1;
  size_t max_samples = 20'000'000;
  int threads = 0;  // 0: all cores
  // OK, or kInvalidArgument naming the option.
  Status Check() const;
};

struct DistanceStats {
  size_t points = 0;
  double rms_mm = 0, mean_mm = 0, median_mm = 0, p95_mm = 0, max_mm = 0;
};

struct CoverageStats {
  double radius_mm = 0;
  size_t surface_samples = 0;  // all samples of the mesh
  size_t visible_samples = 0;  // the visible surface
  double visible_area_mm2 = 0;
  double left = 0, right = 0, both = 0;  // fractions of the visible samples
  // The whole true surface (above the table clearance), seen or not from these views: what several
  // placements together cover (pipeline/placements.h).
  size_t whole_samples = 0;
  double whole_area_mm2 = 0;
  double whole = 0;                // fraction of all samples with a point within the radius
  double line_spacing_p95_mm = 0;  // the scan's own spacing between laser lines (automatic radius), 0: none
  std::string radius_rule;         // how the radius was chosen (for the report)
};

struct ColorStats {
  size_t points = 0;                               // points compared (with colors, near the surface)
  Eigen::Vector3d gain = Eigen::Vector3d::Ones();  // least-squares gain per channel (R G B)
  Eigen::Vector3d mean_abs_error = Eigen::Vector3d::Zero();  // per channel, 8-bit levels, after the gain
  double mean_abs_error_all = 0;                             // mean over points and channels
  double tolerance = 10;                                     // levels (EvaluateOptions::color_tolerance)
  double within_tolerance = 0;  // fraction of points whose three channels are all within it
  // The same with one gain per point instead (g_i = m_i.t_i / m_i.m_i): removes the lamp's shading, which
  // scales the three channels of a point alike, and leaves the hue error (color sampled at a wrong place).
  double mean_abs_error_per_point_gain = 0;
  double within_tolerance_per_point_gain = 0;
  std::string truth_source;
};

// Truth -> mesh, for a scanned mesh: the visible true surface's samples (those of the coverage) against
// the mesh's triangles (exact point-to-triangle distance, so a hole counts by its area, not by how many
// vertices are missing near it).
struct TruthToMeshStats {
  double radius_mm = 0;          // the coverage radius
  size_t visible_samples = 0;
  double visible_area_mm2 = 0;
  DistanceStats distance;        // of each visible sample to the nearest point of the mesh
  double hole_fraction = 0;      // share of the visible area farther than radius_mm from the mesh
  double hole_area_mm2 = 0;
};

struct EvaluationReport {
  size_t points = 0, left_points = 0, right_points = 0;
  DistanceStats distance, distance_left, distance_right;
  CoverageStats coverage;
  bool has_color = false;  // the truth has colors
  ColorStats color;
  bool has_truth_to_mesh = false;  // set by the caller from EvaluateTruthToMesh, for a mesh
  TruthToMeshStats truth_to_mesh;
};

// Evaluates `cloud` against `truth` seen from `views`. kInvalidArgument for an empty cloud, a mesh
// without faces, no views or bad options; kCancelled when `progress` asks.
Result<EvaluationReport> EvaluateCloud(const cloud::PointCloud& cloud, const TruthSurface& truth,
                                       const EvaluationViews& views, const EvaluateOptions& options = {},
                                       Progress* progress = nullptr);

// The truth -> mesh figures of a scanned mesh (vertices in the table frame, mm; triangles index them).
// kInvalidArgument for an empty mesh, a bad index, no views or bad options.
Result<TruthToMeshStats> EvaluateTruthToMesh(const std::vector<Eigen::Vector3f>& vertices,
                                             const std::vector<Eigen::Vector3i>& triangles,
                                             const TruthSurface& truth, const EvaluationViews& views,
                                             const EvaluateOptions& options = {}, Progress* progress = nullptr);

// The truth of a virtual-scanner bundle: truth/object.ply, and with `scene_path` (the scene JSON the bundle
// was rendered from) the scene's exact albedo (textures, patterns). kNotFound naming the file when truth/
// is missing, kInvalidArgument when the scene's meshes are not the bundle's.
Result<TruthSurface> LoadTruthSurface(const std::filesystem::path& bundle_dir,
                                      const std::filesystem::path& scene_path = {});
// The views of a bundle: truth/rig.yaml and the distinct table angles of its frames.
Result<EvaluationViews> LoadEvaluationViews(const std::filesystem::path& bundle_dir);

// Where coverage is lost, and what any placement could gain (EvaluateReach). A point of the surface is
// scannable in a pose of the object when, at the table angle where a laser's plane crosses it (solved
// exactly, not only at the scan's steps), the camera sees it (inside the image, nothing of the object on the
// ray to the camera centre) and that laser lights it (nothing on the ray to the laser's origin), and it is
// higher than the table clearance in that pose. This ignores what the extraction loses (grazing incidence,
// dark albedo) and the step sampling, so it is an upper bound of what a scan in that pose covers. A pose is
// an orientation of the object stood on the table and centred on the axis as sim::PlaceScene does; a turn
// about the table axis changes nothing over a whole turn, so the orientations tried are the directions of
// the object that point up (a Fibonacci sphere).
struct ScanRig {
  geometry::Rig rig;                       // the true rig
  Eigen::Vector3d laser_origin_in_cam[2];  // the lasers' origins (scene "lasers.*.origin_mm")
  // Each placement's rotation from the truth mesh's frame (the bundle's placement) to that placement's
  // (indexed by the scene's placement index).
  std::vector<Eigen::Matrix3d> placement_rotation;
};

struct ReachOptions {
  int orientations = 200;           // up directions tried for the best pair (0: no search)
  double search_spacing_mm = 0.75;  // the surface sample spacing of the search (the final figures: 0.25 mm)
  double region_link_mm = 1.0;      // uncovered samples this close are one region
  // The largest angle between the surface's normal and the rays to the camera and to the laser (90: the
  // geometric bound; a line at grazing incidence is too faint and wide to extract).
  double max_incidence_deg = 90.0;
  size_t max_regions = 12;  // the largest regions reported
};

struct UncoveredRegion {
  double area_mm2 = 0;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero(), lo = Eigen::Vector3d::Zero(),
                  hi = Eigen::Vector3d::Zero();
  double scannable_given = 0;  // share of its area scannable in one of the cloud's placements
  double scannable_any = 0;    // share scannable in some pose
};

struct ReachReport {
  double radius_mm = 0;  // the coverage radius (as EvaluateCloud's)
  size_t samples = 0;    // of the whole surface above the table clearance
  double area_mm2 = 0;
  std::vector<int> placements;              // the cloud's placements
  std::vector<double> scannable_placement;  // fraction of the whole surface scannable in each
  double covered = 0;                       // EvaluateCloud's coverage.whole
  double scannable_given = 0;               // in one of the cloud's placements at least
  double covered_of_scannable_given = 0;    // coverage of that part
  double covered_not_scannable = 0;         // covered but scannable in none of them (a check: near 0)
  double scannable_any = 0;                 // in one of the poses tried or the placements' (upper bound)
  // The best second pose for the cloud's first placement, and the best pair of any poses (up directions in
  // the truth frame) with their scannable fractions (search resolution, then at full resolution).
  Eigen::Vector3d best_second_up = Eigen::Vector3d::UnitZ();
  double best_second = 0;
  Eigen::Vector3d best_pair_up[2] = {Eigen::Vector3d::UnitZ(), Eigen::Vector3d::UnitZ()};
  double best_pair = 0;
  std::vector<UncoveredRegion> regions;  // largest first
  // Every uncovered sample: position (truth frame) and class: 0 scannable in a given placement (missed by
  // the scan), 1 only in another pose, 2 in no pose tried (self-occluded).
  std::vector<Eigen::Vector3f> uncovered;
  std::vector<Eigen::Vector3f> uncovered_normal;  // the true surface's (its face's)
  std::vector<uint8_t> uncovered_class;
};

// The scene's rig and placements for a bundle rendered from `scene_path` (the bundle's placement gives the
// truth frame). kInvalidArgument / kNotFound as LoadTruthSurface.
Result<ScanRig> LoadScanRig(const std::filesystem::path& bundle_dir, const std::filesystem::path& scene_path);

// The whole surface's coverage by `cloud` split by reach (above). A point's `placement` k is taken as the
// scene's placement k (rotoscan merge numbers the clouds in the order given: merge them in the scene's
// order). kInvalidArgument for a cloud whose placements the rig does not have, and as EvaluateCloud.
Result<ReachReport> EvaluateReach(const cloud::PointCloud& cloud, const TruthSurface& truth,
                                  const EvaluationViews& views, const ScanRig& rig,
                                  const EvaluateOptions& options = {}, const ReachOptions& reach = {},
                                  Progress* progress = nullptr);
std::string ReachSummary(const ReachReport& report);

// The report as JSON (numbers in mm, fractions 0..1, colors in 8-bit levels) and as one line per metric.
std::string EvaluationJson(const EvaluationReport& report);
std::string EvaluationSummary(const EvaluationReport& report);

}  // namespace rotoscan::pipeline
