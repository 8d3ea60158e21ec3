// The object's own color for every point of a scanned cloud: a pass over the scan's natural frames after
// triangulation (ProcessBundle calls it once the cloud is made; `process --color step` keeps the old
// color, the natural frame of the point's own step at its laser pixel).
//
// Why: the natural frame of one step carries the lamp's shading at that table angle (the lamp turns with
// the camera, not with the object), so neighbouring points found at different steps, or by the other
// laser, get different brightness (vertical bands on the mesh) and the color is the lamp's as much as the
// object's. Here every point is looked at in many natural frames and the shading is divided out:
//
// Views: up to `max_views` steps spread over the scan. In each, a point is a candidate when it faces the
// camera (cos between its normal and the ray to the camera >= min_cos_camera), projects inside the image,
// and is not hidden: a depth buffer of the whole cloud is splatted at 1/`zbuffer_cell_px` of the image's
// resolution, and the point must lie within `occlusion_mm` of the nearest depth there. Its color there is
// the bilinear sample of the natural frame at its projection (same camera: paper §3.3's point, at every
// step instead of one). Observations with a saturated channel (>= saturation) are dropped.
//
// Shading: the lamp is Lambertian and far (the virtual scanner's model, and a fair one for a desk lamp),
// fixed to the camera: a point of albedo a with normal n (camera frame at that step) appears as
//   I = a * (1 + max(0, n . L)),   L = (diffuse / ambient) * direction to the lamp (camera frame),
// up to one global factor. L is estimated from the scan itself: the same point seen at several table
// angles changes brightness only through n . L, so L is the vector that best explains those changes over a
// sample of points seen 6 times or more (least squares with each point's own albedo; views darker than
// 0.6 x the model against the point's bright views dropped as cast shadows), searched over 120 directions
// and 3 strengths, then refined by a pattern search. When that is not well posed (too few points with
// several views, or a lamp explaining less than 10 % of what a constant shading leaves), L = 0: the colors
// are then the views' average, still the same whatever step or laser found the point. A calibrated lamp
// (the rig's, from `rotoscan calibrate lamp`, pipeline/lamp.h) or a given one (ColorOptions::lamp_in_cam,
// `process --lamp`) skips the estimate.
//
// Normals: the scan grid's normals (cloud.h) come from a point's neighbours on its own and the next laser
// lines; their noise flattens the shading they should explain. The shading uses normals refit by PCA over
// every cloud point within a radius that follows the scan's spacing between laser lines (the smallest
// eigenvector of the neighbourhood's covariance, turned to the side of the point's own normal, which
// faces its camera); the cloud's own normals are left as they were.
//
// Each point's color is then the least-squares albedo over its views, weighted by how squarely it faces
// the camera, with its cast-shadow views dropped (a point in cast shadow in every view, as under a
// leg that the lamp never reaches, takes the albedo from those views under the ambient light alone:
// shading 1; before 2026-11-24 it fell back to its own step's frame divided by the lit shading, 88
// levels off on the nose-down scan's 10 % of such points), times one fixed factor, 1 + |L|: the brightness the
// albedo has on a surface facing the lamp (clipped at 255). The factor depends on nothing but the lamp, so
// scans of several placements under the same lamp and exposure get the same colors (pipeline/placements.h).
#pragma once

#include <cstddef>
#include <functional>
#include <optional>
#include <string>

#include <Eigen/Core>

#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"
#include "rotoscan/geometry/rig.h"

namespace rotoscan::pipeline {

class StepSource;

struct ColorOptions {
  bool enabled = true;                         // false: the point's own step's natural frame (the old color)
  int max_views = 72;                          // natural frames used, spread over the scan
  double min_cos_camera = 0.35;                // a view must face the point at least this squarely
  double occlusion_mm = 1.0;                   // hidden when further than this behind the depth buffer
  int zbuffer_cell_px = 6;                     // depth buffer cell (pixels)
  int zbuffer_splat_cells = 1;                 // each point covers (2k + 1)^2 cells
  int saturation = 250;                        // 8-bit level at which a channel counts as saturated
  bool remove_shading = true;                  // estimate L and divide the shading out
  // Shading normals (the file comment): PCA over the cloud's points within this radius (mm) of each point;
  // 0: normal_radius_lines x the scan's own spacing between laser lines; < 0: the cloud's own normals.
  double normal_radius_mm = 0;
  double normal_radius_lines = 4.0;
  std::optional<Eigen::Vector3d> lamp_in_cam;  // a given L (see the file comment); skips the estimate
  bool use_calibrated_lamp = true;             // the rig's calibrated lamp (Rig::lamp_in_cam) when it has one
  double shadow_ratio = 0.6;  // a view darker than this x the model is a cast shadow (0: no such test)
  bool shadow_map = true;     // with a known lamp, also the cloud's own cast shadows (a shadow map per view)
  double shadow_margin_mm = 4.0;  // shadowed when the cloud lies this much nearer the lamp at the same place
  // A point in cast shadow in all its views takes its albedo from those views under the ambient light
  // alone (shading 1); false: from its own step's frame with the lit shading divided out (the old way).
  bool shadowed_ambient = true;
  // An estimated lamp is refined this many times with each view's shadow map under the lamp found so far
  // (the cast shadows left out); 0: the ratio test alone.
  int estimate_shadow_rounds = 2;
  // Diagnostics only (bench/pipeline/color_diagnose: the virtual scanner's true mesh answers): when set,
  // called from several threads for every candidate observation (point index, the view's table angle)
  // and returns a TruthVisibility; it replaces the depth-buffer occlusion test and the cast-shadow test
  // (those of its answers named in truth_visibility_bits; the others stay the method's).
  std::function<int(size_t point, double table_angle_rad)> truth_visibility;
  int truth_visibility_bits = 3;  // kHidden | kLampBlocked
  // Diagnostics only: when set, called once per point (from one thread) with the views it was seen in
  // and how many of those were used (not cast shadows).
  std::function<void(size_t point, int views_seen, int views_used)> per_point;
  int threads = 0;                             // 0: all cores
  Status Check() const;
};

enum TruthVisibility : int { kVisibleLit = 0, kHidden = 1, kLampBlocked = 2 };

struct ColorSummary {
  bool done = false;
  int views = 0;              // natural frames used
  size_t points_colored = 0;  // points with at least one view (others keep their color)
  double mean_views_per_point = 0;
  bool shading_removed = false;
  double normal_radius_mm = 0;  // the PCA radius of the shading normals (0: the cloud's own normals)
  Eigen::Vector3d lamp_in_cam = Eigen::Vector3d::Zero();  // L (direction times diffuse / ambient)
  std::string lamp_source;  // "given", "calibrated" (the rig's) or "estimated" (from the scan)
  double shadow_fraction = 0;                             // observations dropped as cast shadows
  std::string note;                                       // why the shading was not removed, when it was not
};

// Recolors `cloud` (table frame, normals oriented outwards) from the natural frames of `source` seen
// with `rig`. kInvalidArgument for bad options; kCancelled when `progress` asks. Steps without a natural
// frame are not views; a cloud without any view is left as it is (summary.done false, with a note).
Status ColorFromViews(const geometry::Rig& rig, const StepSource& source, const ColorOptions& options,
                      cloud::PointCloud* cloud, ColorSummary* summary, Progress* progress = nullptr);

std::string FormatColorSummary(const ColorSummary& summary);

}  // namespace rotoscan::pipeline
