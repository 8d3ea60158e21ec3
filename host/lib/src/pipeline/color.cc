// The object's color from many natural frames with the lamp's shading divided out (color.h has the
// method). Observations are gathered view by view (one natural frame at a time, in parallel), then
// combined per point.
#include "rotoscan/pipeline/color.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>
#include <optional>
#include <random>
#include <sstream>
#include <thread>

#include <open3d/geometry/KDTreeFlann.h>
#include <Eigen/Eigenvalues>

#include "rotoscan/core/check.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/pipeline/process.h"

namespace rotoscan::pipeline {
namespace {

struct Observation {
  uint32_t point = 0;
  uint16_t view = 0;
  std::array<uint8_t, 3> rgb{};
  float cos_camera = 0;
  bool lamp_blocked = false;  // in the cloud's cast shadow (the shadow map, or truth_visibility's answer)
};

struct View {
  double angle = 0;
  Eigen::Matrix3f cam_from_table_rotation = Eigen::Matrix3f::Identity();
};

float Luminance(const std::array<uint8_t, 3>& c) {
  return (c[0] + c[1] + c[2]) / 3.0f;
}

float Shading(const Eigen::Vector3f& normal_in_cam, const Eigen::Vector3f& lamp) {
  return 1.0f + std::max(0.0f, normal_in_cam.dot(lamp));
}

// The cloud seen from the far lamp (an orthographic view along its direction, table frame, in cells of
// `cell_mm`, keeping the depth nearest the lamp): a point is in the cloud's cast shadow when something lies
// more than `margin_mm` nearer the lamp in its cell.
class ShadowMap {
 public:
  ShadowMap(const cloud::PointCloud& cloud, const Eigen::Vector3f& toward_lamp_in_table, float cell_mm)
      : toward_(toward_lamp_in_table.normalized()), cell_(cell_mm) {
    su_ = toward_.unitOrthogonal();
    sv_ = toward_.cross(su_);
    float u1 = -std::numeric_limits<float>::infinity(), v1 = u1;
    u0_ = v0_ = std::numeric_limits<float>::infinity();
    for (const cloud::CloudPoint& p : cloud.points) {
      const float u = su_.dot(p.position_in_table), v = sv_.dot(p.position_in_table);
      u0_ = std::min(u0_, u), u1 = std::max(u1, u), v0_ = std::min(v0_, v), v1 = std::max(v1, v);
    }
    w_ = std::min(8192, static_cast<int>((u1 - u0_) / cell_) + 1);
    h_ = std::min(8192, static_cast<int>((v1 - v0_) / cell_) + 1);
    depth_.assign(static_cast<size_t>(w_) * static_cast<size_t>(h_), -std::numeric_limits<float>::infinity());
    for (const cloud::CloudPoint& p : cloud.points) {
      int cx = 0, cy = 0;
      Cell(p.position_in_table, &cx, &cy);
      const float d = toward_.dot(p.position_in_table);
      for (int y = std::max(0, cy - 1); y <= std::min(h_ - 1, cy + 1); ++y) {
        for (int x = std::max(0, cx - 1); x <= std::min(w_ - 1, cx + 1); ++x) {
          float& m = depth_[static_cast<size_t>(y) * static_cast<size_t>(w_) + static_cast<size_t>(x)];
          m = std::max(m, d);
        }
      }
    }
  }
  bool Shadowed(const Eigen::Vector3f& p, float margin_mm) const {
    int cx = 0, cy = 0;
    Cell(p, &cx, &cy);
    return depth_[static_cast<size_t>(cy) * static_cast<size_t>(w_) + static_cast<size_t>(cx)] >
           toward_.dot(p) + margin_mm;
  }

 private:
  void Cell(const Eigen::Vector3f& p, int* x, int* y) const {
    *x = std::clamp(static_cast<int>((su_.dot(p) - u0_) / cell_), 0, w_ - 1);
    *y = std::clamp(static_cast<int>((sv_.dot(p) - v0_) / cell_), 0, h_ - 1);
  }
  Eigen::Vector3f toward_, su_, sv_;
  float cell_;
  float u0_ = 0, v0_ = 0;
  int w_ = 1, h_ = 1;
  std::vector<float> depth_;
};

// One view: every point's observation there (facing, inside, unoccluded, unsaturated); with a known lamp
// (`lamp_in_cam` not null), each flagged when the cloud casts a shadow on it (a shadow map: the cloud seen
// from the far lamp, an orthographic view along its direction in cells of `shadow_cell_mm`, keeping the
// depth nearest the lamp; shadowed when something lies more than shadow_margin_mm nearer the lamp).
void Observe(const geometry::Rig& rig, const cloud::PointCloud& cloud,
             const std::vector<Eigen::Vector3f>& normals, const cv::Mat& natural, double angle, uint16_t view,
             const ColorOptions& options, const Eigen::Vector3f* lamp_in_cam, double shadow_cell_mm,
             std::vector<Observation>* out) {
  const geometry::CameraModel& camera = rig.camera;
  const Eigen::Isometry3d cam_from_table = rig.WorldFromCamAtAngle(angle).inverse();
  const Eigen::Matrix3f r = cam_from_table.linear().cast<float>();
  const Eigen::Vector3f t = cam_from_table.translation().cast<float>();
  const int cell = options.zbuffer_cell_px;
  const int gw = (camera.width + cell - 1) / cell, gh = (camera.height + cell - 1) / cell;
  std::vector<float> depth(static_cast<size_t>(gw) * static_cast<size_t>(gh),
                           std::numeric_limits<float>::infinity());
  std::vector<Eigen::Vector2f> pixel(cloud.size());
  std::vector<float> z(cloud.size(), -1.0f);
  const int k = options.zbuffer_splat_cells;
  for (size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3f p = r * cloud.points[i].position_in_table + t;
    if (p.z() <= 1.0f) continue;
    const Eigen::Vector2d px = camera.Project(p.cast<double>());
    if (!camera.IsInside(px)) continue;
    pixel[i] = px.cast<float>();
    const float range = p.norm();
    z[i] = range;
    const int cx = static_cast<int>(px.x()) / cell, cy = static_cast<int>(px.y()) / cell;
    for (int dy = -k; dy <= k; ++dy) {
      const int y = cy + dy;
      if (y < 0 || y >= gh) continue;
      for (int dx = -k; dx <= k; ++dx) {
        const int x = cx + dx;
        if (x < 0 || x >= gw) continue;
        float& d = depth[static_cast<size_t>(y) * static_cast<size_t>(gw) + static_cast<size_t>(x)];
        d = std::min(d, range);
      }
    }
  }
  const Eigen::Vector3f camera_in_table = -(r.transpose() * t);
  const float occlusion = static_cast<float>(options.occlusion_mm);
  const bool truth_hidden =
      options.truth_visibility && (options.truth_visibility_bits & kHidden) != 0;
  const bool truth_shadow =
      options.truth_visibility && (options.truth_visibility_bits & kLampBlocked) != 0;
  const bool use_map = lamp_in_cam != nullptr && lamp_in_cam->norm() > 0 && options.shadow_map &&
                       !truth_shadow && cloud.size() > 0;
  std::optional<ShadowMap> map;
  if (use_map) map.emplace(cloud, r.transpose() * *lamp_in_cam, static_cast<float>(shadow_cell_mm));
  const float shadow_margin = static_cast<float>(options.shadow_margin_mm);
  for (size_t i = 0; i < cloud.size(); ++i) {
    if (z[i] < 0) continue;
    const cloud::CloudPoint& p = cloud.points[i];
    if (normals[i].squaredNorm() < 0.5f) continue;
    const Eigen::Vector3f to_camera = (camera_in_table - p.position_in_table).normalized();
    const float cos_camera = normals[i].dot(to_camera);
    if (cos_camera < options.min_cos_camera) continue;
    bool lamp_blocked = false;
    const int truth = options.truth_visibility ? options.truth_visibility(i, angle) : 0;
    if (truth_hidden) {
      if ((truth & kHidden) != 0) continue;
    } else {
      const int cx = static_cast<int>(pixel[i].x()) / cell, cy = static_cast<int>(pixel[i].y()) / cell;
      if (z[i] >
          depth[static_cast<size_t>(cy) * static_cast<size_t>(gw) + static_cast<size_t>(cx)] + occlusion) {
        continue;  // hidden by a nearer surface
      }
    }
    if (truth_shadow) {
      lamp_blocked = (truth & kLampBlocked) != 0;
    } else if (map) {
      lamp_blocked = map->Shadowed(p.position_in_table, shadow_margin);
    }
    const std::array<uint8_t, 3> rgb = SampleRgb(natural, pixel[i].x(), pixel[i].y());
    if (*std::max_element(rgb.begin(), rgb.end()) >= options.saturation) continue;
    out->push_back({static_cast<uint32_t>(i), view, rgb, cos_camera, lamp_blocked});
  }
}

// The scan's spacing between laser lines: the median, over a sample of points, of the distance to the
// nearest point of another line (another step or laser). 0 when no point has one among its 48 nearest.
double LineSpacing(const cloud::PointCloud& cloud, const open3d::geometry::KDTreeFlann& tree,
                   const std::vector<Eigen::Vector3d>& positions) {
  std::vector<double> spacing;
  std::vector<int> found;
  std::vector<double> d2;
  const size_t stride = std::max<size_t>(1, cloud.size() / 2000);
  for (size_t i = 0; i < cloud.size(); i += stride) {
    tree.SearchKNN(positions[i], 48, found, d2);
    const cloud::CloudPoint& p = cloud.points[i];
    for (size_t k = 0; k < found.size(); ++k) {
      const cloud::CloudPoint& q = cloud.points[static_cast<size_t>(found[k])];
      if (q.step != p.step || q.laser != p.laser) {
        spacing.push_back(std::sqrt(d2[k]));
        break;
      }
    }
  }
  if (spacing.empty()) return 0;
  std::nth_element(spacing.begin(), spacing.begin() + static_cast<std::ptrdiff_t>(spacing.size() / 2),
                   spacing.end());
  return spacing[spacing.size() / 2];
}

// A point's own normal (from the scan grid), unit length, or zero when it has none.
Eigen::Vector3f OwnNormal(const cloud::CloudPoint& p) {
  return p.normal.squaredNorm() > 0.5f ? Eigen::Vector3f(p.normal.normalized()) : Eigen::Vector3f::Zero();
}

// Shading normals by PCA over `radius` (file comment in color.h), on the side of each point's own normal;
// a point with fewer than 6 neighbours, or without a normal, keeps its own (zero: no normal).
std::vector<Eigen::Vector3f> PcaNormals(const cloud::PointCloud& cloud, double radius, int threads,
                                        const open3d::geometry::KDTreeFlann& tree,
                                        const std::vector<Eigen::Vector3d>& positions) {
  std::vector<Eigen::Vector3f> normals(cloud.size());
  std::atomic<size_t> next{0};
  constexpr size_t kChunk = 1024;
  auto worker = [&] {
    std::vector<int> found;
    std::vector<double> d2;
    for (;;) {
      const size_t first = next.fetch_add(kChunk);
      if (first >= cloud.size()) return;
      for (size_t i = first; i < std::min(cloud.size(), first + kChunk); ++i) {
        normals[i] = OwnNormal(cloud.points[i]);
        if (normals[i].squaredNorm() == 0) continue;
        tree.SearchRadius(positions[i], radius, found, d2);
        if (found.size() < 6) continue;
        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
        for (const int k : found) mean += positions[static_cast<size_t>(k)];
        mean /= static_cast<double>(found.size());
        Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
        for (const int k : found) {
          const Eigen::Vector3d d = positions[static_cast<size_t>(k)] - mean;
          covariance += d * d.transpose();
        }
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
        Eigen::Vector3f n = solver.eigenvectors().col(0).cast<float>();  // the smallest eigenvalue's
        if (!n.allFinite() || n.squaredNorm() < 0.5f) continue;
        n.normalize();
        normals[i] = n.dot(normals[i]) < 0 ? Eigen::Vector3f(-n) : n;
      }
    }
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(worker);
  worker();
  for (std::thread& t : pool) t.join();
  return normals;
}

}  // namespace

Status ColorOptions::Check() const {
  if (max_views < 1 || max_views > 4096) return InvalidArgumentError("color: max_views must be in [1, 4096]");
  if (!(min_cos_camera >= 0 && min_cos_camera < 1))
    return InvalidArgumentError("color: min_cos_camera in [0, 1)");
  if (!(occlusion_mm > 0 && std::isfinite(occlusion_mm)))
    return InvalidArgumentError("color: occlusion_mm > 0");
  if (zbuffer_cell_px < 1 || zbuffer_cell_px > 64)
    return InvalidArgumentError("color: zbuffer_cell_px in [1, 64]");
  if (zbuffer_splat_cells < 0 || zbuffer_splat_cells > 8) {
    return InvalidArgumentError("color: zbuffer_splat_cells in [0, 8]");
  }
  if (!(shadow_ratio >= 0 && shadow_ratio < 1)) return InvalidArgumentError("color: shadow_ratio in [0, 1)");
  if (!(shadow_margin_mm > 0 && shadow_margin_mm < 100))
    return InvalidArgumentError("color: shadow_margin_mm in (0, 100)");
  if (saturation < 1 || saturation > 256) return InvalidArgumentError("color: saturation in [1, 256]");
  if (lamp_in_cam && (!lamp_in_cam->allFinite() || lamp_in_cam->norm() > 1e3)) {
    return InvalidArgumentError("color: the lamp vector must be finite (and below 1e3)");
  }
  if (threads < 0 || threads > 256) return InvalidArgumentError("color: threads in [0, 256]");
  if (estimate_shadow_rounds < 0 || estimate_shadow_rounds > 10)
    return InvalidArgumentError("color: estimate_shadow_rounds in [0, 10]");
  if (!std::isfinite(normal_radius_mm) || normal_radius_mm > 100)
    return InvalidArgumentError("color: normal_radius_mm must be finite and at most 100");
  if (!(normal_radius_lines > 0 && normal_radius_lines <= 50))
    return InvalidArgumentError("color: normal_radius_lines in (0, 50]");
  return Status::Ok();
}

Status ColorFromViews(const geometry::Rig& rig, const StepSource& source, const ColorOptions& options,
                      cloud::PointCloud* cloud, ColorSummary* summary, Progress* progress) {
  ROTOSCAN_CHECK(cloud != nullptr && summary != nullptr);
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  *summary = ColorSummary{};
  if (!options.enabled || cloud->empty()) return Status::Ok();
  if (cloud->size() >= (size_t{1} << 32)) return InvalidArgumentError("color: cloud too large");
  const int steps = source.StepCount();
  const int wanted = std::min(options.max_views, steps);
  std::vector<int> indices;
  for (int v = 0; v < wanted; ++v) {
    const int index = static_cast<int>(static_cast<int64_t>(v) * steps / wanted);
    if (indices.empty() || indices.back() != index) indices.push_back(index);
  }

  const int threads = options.threads > 0
                          ? options.threads
                          : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  // Shading normals (color.h).
  std::vector<Eigen::Vector3f> normals;
  double line_spacing = 0;
  if (options.normal_radius_mm >= 0) {
    std::vector<Eigen::Vector3d> positions(cloud->size());
    for (size_t i = 0; i < cloud->size(); ++i)
      positions[i] = cloud->points[i].position_in_table.cast<double>();
    // Open3D 0.16's KDTreeFlann keeps a map over the matrix it is given, not over its own copy
    // (SetRawData maps `data`, not `data_`): the matrix must outlive the tree. Passing a temporary (a
    // Map converted to MatrixXd) left the tree reading freed memory, which other threads' allocations
    // reused: the normals changed from run to run with 2 threads (and, unseen, with 1).
    const Eigen::MatrixXd matrix = Eigen::Map<const Eigen::MatrixXd>(
        positions.data()->data(), 3, static_cast<Eigen::Index>(positions.size()));
    open3d::geometry::KDTreeFlann tree;
    tree.SetMatrixData(matrix);
    line_spacing = LineSpacing(*cloud, tree, positions);
    double radius = options.normal_radius_mm;
    if (radius == 0) radius = options.normal_radius_lines * line_spacing;
    if (radius > 0) {
      normals = PcaNormals(*cloud, radius, threads, tree, positions);
      summary->normal_radius_mm = radius;
    }
  }
  if (normals.empty()) {
    normals.resize(cloud->size());
    for (size_t i = 0; i < cloud->size(); ++i) normals[i] = OwnNormal(cloud->points[i]);
  }

  // A lamp known before the views are read (given or calibrated) gives each view a shadow map.
  std::optional<Eigen::Vector3f> known_lamp;
  if (options.lamp_in_cam) {
    known_lamp = options.lamp_in_cam->cast<float>();
  } else if (options.use_calibrated_lamp && rig.lamp_in_cam) {
    known_lamp = rig.lamp_in_cam->cast<float>();
  }
  const Eigen::Vector3f* map_lamp = known_lamp && options.remove_shading ? &*known_lamp : nullptr;
  const double shadow_cell = line_spacing > 0 ? line_spacing : 0.5;

  // Observations, view by view (each thread its own natural frame and depth buffer).
  std::vector<std::vector<Observation>> per_view(indices.size());
  std::vector<View> views(indices.size());
  std::vector<char> have_view(indices.size(), 0);
  std::atomic<size_t> next{0};
  ProgressScope scope(progress, "color", indices.size());
  auto worker = [&] {
    for (;;) {
      if (scope.Cancelled()) return;
      const size_t v = next.fetch_add(1);
      if (v >= indices.size()) return;
      double angle = 0;
      auto natural = source.LoadNatural(indices[v], &angle);
      scope.Advance();
      if (!natural.ok() || natural->empty()) continue;
      const cv::Mat image = NaturalImageOf(source, *natural);
      if (image.cols != rig.camera.width || image.rows != rig.camera.height) continue;
      views[v].angle = angle;
      views[v].cam_from_table_rotation = rig.WorldFromCamAtAngle(angle).linear().transpose().cast<float>();
      have_view[v] = 1;
      Observe(rig, *cloud, normals, image, angle, static_cast<uint16_t>(v), options, map_lamp, shadow_cell,
              &per_view[v]);
    }
  };
  std::vector<std::thread> pool;
  for (int i = 1; i < std::min<int>(threads, static_cast<int>(indices.size())); ++i)
    pool.emplace_back(worker);
  worker();
  for (std::thread& t : pool) t.join();
  if (scope.Cancelled()) return CancelledError("coloring cancelled");
  for (char h : have_view) summary->views += h;
  if (summary->views == 0) {
    summary->note = "no natural frame: colors left as they were";
    return Status::Ok();
  }

  // Observations grouped by point (counting sort).
  const size_t n = cloud->size();
  std::vector<uint32_t> offset(n + 1, 0);
  for (const auto& list : per_view) {
    for (const Observation& o : list) ++offset[o.point + 1];
  }
  for (size_t i = 0; i < n; ++i) offset[i + 1] += offset[i];
  std::vector<Observation> obs(offset[n]);
  {
    std::vector<uint32_t> fill(offset.begin(), offset.end() - 1);
    for (auto& list : per_view) {
      for (const Observation& o : list) obs[fill[o.point]++] = o;
      std::vector<Observation>().swap(list);
    }
  }
  auto normal_in_cam = [&](const Observation& o) -> Eigen::Vector3f {
    return views[o.view].cam_from_table_rotation * normals[o.point];
  };
  const float shadow_ratio = static_cast<float>(options.shadow_ratio);
  const bool truth_shadows =
      options.truth_visibility && (options.truth_visibility_bits & kLampBlocked) != 0;
  bool map_shadows = map_lamp != nullptr && options.shadow_map && !truth_shadows;
  // Every observation's cast-shadow flag under lamp `l` (a shadow map per view), for an estimated lamp.
  bool estimate_flagged = false;
  auto FlagCastShadows = [&](const Eigen::Vector3f& l) {
    std::vector<std::optional<ShadowMap>> maps(views.size());
    for (size_t v = 0; v < views.size(); ++v) {
      if (have_view[v]) maps[v].emplace(*cloud, views[v].cam_from_table_rotation.transpose() * l,
                                        static_cast<float>(shadow_cell));
    }
    const float margin = static_cast<float>(options.shadow_margin_mm);
    for (Observation& o : obs) o.lamp_blocked = maps[o.view]->Shadowed(cloud->points[o.point].position_in_table, margin);
    map_shadows = true;
  };
  // Least-squares luminance albedo of point i under lamp L. With `shadow`, views darker than shadow_ratio x
  // the model against a reference taken high in the views' range (the 75th percentile of I / shading: cast
  // shadows only darken, so the bright views are the lit truth even when most views are shadowed) are
  // flagged and left out.
  std::vector<float> ratios;
  auto albedo = [&](size_t i, const Eigen::Vector3f& lamp, std::vector<char>* shadow) {
    double num = 0, den = 0;
    if (shadow != nullptr && truth_shadows) {
      for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) (*shadow)[k] = obs[k].lamp_blocked;
    } else if (shadow != nullptr) {
      ratios.clear();
      for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) {
        ratios.push_back(Luminance(obs[k].rgb) / Shading(normal_in_cam(obs[k]), lamp));
      }
      const size_t at = (ratios.size() * 3) / 4;
      std::nth_element(ratios.begin(), ratios.begin() + static_cast<std::ptrdiff_t>(at), ratios.end());
      const float reference = ratios[at];
      for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) {
        const float s = Shading(normal_in_cam(obs[k]), lamp);
        (*shadow)[k] =
            Luminance(obs[k].rgb) < shadow_ratio * reference * s || (map_shadows && obs[k].lamp_blocked);
      }
    }
    for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) {
      if (shadow != nullptr && (*shadow)[k]) continue;
      const double s = Shading(normal_in_cam(obs[k]), lamp);
      num += Luminance(obs[k].rgb) * s;
      den += s * s;
    }
    return den > 0 ? num / den : 0.0;
  };

  // The lamp, from a sample of points seen in several views: the L that explains their changes of
  // brightness best (least squares over all views with each point's own albedo, cast shadows left out),
  // searched over directions and strengths, then refined by a pattern search.
  Eigen::Vector3f lamp = Eigen::Vector3f::Zero();
  std::vector<char> shadow(obs.size(), 0);
  if (known_lamp) {
    lamp = *known_lamp;
    summary->shading_removed = options.remove_shading;
    summary->lamp_source = options.lamp_in_cam ? "given" : "calibrated";
  } else if (options.remove_shading) {
    summary->lamp_source = "estimated";
    std::vector<size_t> sample;
    for (size_t i = 0; i < n; ++i) {
      if (offset[i + 1] - offset[i] >= 6) sample.push_back(i);
    }
    std::mt19937_64 random(1);
    std::shuffle(sample.begin(), sample.end(), random);
    if (sample.size() > 4000) sample.resize(4000);
    if (sample.size() < 200) {
      summary->note = "too few points seen in 6 views or more to estimate the lamp: shading kept";
    } else {
      // The sample's luminances and normals (camera frame) once; then the relative residual of the model
      // under lamp L (1: explains nothing, 0: everything), cast shadows left out as in `albedo`.
      std::vector<float> ys;
      std::vector<Eigen::Vector3f> ns;
      std::vector<char> blocked;  // in the cloud's cast shadow under the lamp of the last round
      std::vector<uint32_t> begin{0};
      for (const size_t i : sample) {
        for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) {
          ys.push_back(Luminance(obs[k].rgb));
          ns.push_back(normal_in_cam(obs[k]));
          blocked.push_back(0);
        }
        begin.push_back(static_cast<uint32_t>(ys.size()));
      }
      std::vector<float> shading(ys.size()), ratio;
      auto cost = [&](const Eigen::Vector3f& l) {
        double residual = 0, total = 0;
        for (size_t j = 0; j + 1 < begin.size(); ++j) {
          ratio.clear();
          for (uint32_t k = begin[j]; k < begin[j + 1]; ++k) {
            shading[k] = Shading(ns[k], l);
            if (!blocked[k]) ratio.push_back(ys[k] / shading[k]);
          }
          if (ratio.empty()) continue;
          const size_t at = (ratio.size() * 3) / 4;
          std::nth_element(ratio.begin(), ratio.begin() + static_cast<std::ptrdiff_t>(at), ratio.end());
          const float floor = shadow_ratio * ratio[at];
          double num = 0, den = 0;
          for (uint32_t k = begin[j]; k < begin[j + 1]; ++k) {
            if (blocked[k] || ys[k] < floor * shading[k]) continue;
            num += ys[k] * shading[k];
            den += static_cast<double>(shading[k]) * shading[k];
          }
          const double a = den > 0 ? num / den : 0;
          for (uint32_t k = begin[j]; k < begin[j + 1]; ++k) {
            if (blocked[k] || ys[k] < floor * shading[k]) continue;
            const double e = ys[k] - a * shading[k];
            residual += e * e;
            total += static_cast<double>(ys[k]) * ys[k];
          }
        }
        return total > 0 ? residual / total : 1.0;
      };
      double best = cost(lamp);
      const double flat = best;
      const int directions = 120;
      for (int d = 0; d < directions; ++d) {  // a Fibonacci sphere
        const double z = 1.0 - (2.0 * d + 1.0) / directions, r = std::sqrt(std::max(0.0, 1.0 - z * z));
        const double phi = d * 2.399963229728653;
        const Eigen::Vector3f direction(static_cast<float>(r * std::cos(phi)),
                                        static_cast<float>(r * std::sin(phi)), static_cast<float>(z));
        for (const float strength : {0.5f, 1.5f, 4.0f}) {
          const double c = cost(strength * direction);
          if (c < best) {
            best = c;
            lamp = strength * direction;
          }
        }
      }
      auto refine = [&] {
        for (float step = 0.5f; step > 0.01f;) {
          bool improved = false;
          for (int axis = 0; axis < 3; ++axis) {
            for (const float sign : {-1.0f, 1.0f}) {
              Eigen::Vector3f trial = lamp;
              trial[axis] += sign * step * std::max(1.0f, lamp.norm());
              const double c = cost(trial);
              if (c < best) {
                best = c;
                lamp = trial;
                improved = true;
              }
            }
          }
          if (!improved) step *= 0.5f;
        }
      };
      refine();
      // Cast shadows darken views without the ratio test seeing them all, and pull the strength down: with
      // the lamp found, each view's shadow map flags them, and the lamp is refined without them (rounds).
      for (int round = 0; round < options.estimate_shadow_rounds && options.shadow_map &&
                          !options.truth_visibility && lamp.norm() > 0;
           ++round) {
        FlagCastShadows(lamp);
        size_t at = 0;
        for (const size_t i : sample) {
          for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) blocked[at++] = obs[k].lamp_blocked;
        }
        best = cost(lamp);
        refine();
        estimate_flagged = true;
      }
      // Well posed when the lamp explains a clear part of what the constant shading did not.
      if (lamp.allFinite() && lamp.norm() < 100.0f && best < 0.9 * flat) {
        summary->shading_removed = true;
        if (estimate_flagged) FlagCastShadows(lamp);  // the final lamp's shadows, for the albedo below
      } else {
        lamp = Eigen::Vector3f::Zero();
        summary->note =
            "the lamp could not be estimated (the views' brightness does not follow one): shading kept";
      }
    }
  }
  summary->lamp_in_cam = lamp.cast<double>();

  // Every point's albedo over its views, weighted by how squarely each faces it.
  std::vector<Eigen::Vector3f> color(n, Eigen::Vector3f::Constant(-1.0f));
  size_t dropped = 0, total = 0;
  for (size_t i = 0; i < n; ++i) {
    if (offset[i + 1] == offset[i]) continue;
    albedo(i, lamp, &shadow);  // flags the point's cast-shadow views
    Eigen::Vector3d num = Eigen::Vector3d::Zero();
    double den = 0;
    for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) {
      ++total;
      if (shadow[k]) {
        ++dropped;
        continue;
      }
      const double s = Shading(normal_in_cam(obs[k]), lamp);
      const double w = obs[k].cos_camera;
      num += w * s * Eigen::Vector3d(obs[k].rgb[0], obs[k].rgb[1], obs[k].rgb[2]);
      den += w * s * s;
    }
    if (den <= 0 && options.shadowed_ambient) {
      // Every view in a cast shadow: the lamp's diffuse light is blocked in all of them, so each shows the
      // albedo under the ambient light alone (shading 1), which is as well posed as a lit view, only darker.
      for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) {
        const double w = obs[k].cos_camera;
        num += w * Eigen::Vector3d(obs[k].rgb[0], obs[k].rgb[1], obs[k].rgb[2]);
        den += w;
      }
    }
    if (options.per_point) {
      int used = 0;
      for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) used += shadow[k] ? 0 : 1;
      options.per_point(i, static_cast<int>(offset[i + 1] - offset[i]), used);
    }
    if (den <= 0) continue;
    color[i] = (num / den).cast<float>();
    ++summary->points_colored;
  }
  summary->shadow_fraction = total > 0 ? static_cast<double>(dropped) / static_cast<double>(total) : 0;
  summary->mean_views_per_point =
      summary->points_colored > 0 ? static_cast<double>(total) / static_cast<double>(summary->points_colored)
                                  : 0;
  // Points with no usable view: their own step's color, its shading divided out the same way (the step's
  // angle from the views' uniform turn).
  double rate = 0;
  for (size_t v = 0; v < views.size(); ++v) {
    if (have_view[v] && indices[v] != 0) rate = views[v].angle / indices[v];
  }
  for (size_t i = 0; i < n; ++i) {
    if (color[i].x() >= 0) continue;
    const cloud::CloudPoint& p = cloud->points[i];
    const Eigen::Matrix3f r = rig.WorldFromCamAtAngle(rate * p.step).linear().transpose().cast<float>();
    const float s = normals[i].squaredNorm() > 0.5f ? Shading(r * normals[i], lamp) : 1.0f;
    color[i] = Eigen::Vector3f(p.color[0], p.color[1], p.color[2]) / s;
  }
  // One fixed factor, the same for every scan under the same lamp and exposure (so that placements merge
  // without a seam): the brightness of the albedo on a surface facing the lamp, 1 + |L| x ambient.
  const float scale = 1.0f + lamp.norm();
  for (size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) {
      cloud->points[i].color[static_cast<size_t>(c)] =
          static_cast<uint8_t>(std::clamp(std::lround(color[i][c] * scale), 0L, 255L));
    }
  }
  summary->done = true;
  return Status::Ok();
}

std::string FormatColorSummary(const ColorSummary& s) {
  std::ostringstream out;
  out.setf(std::ios::fixed);
  out.precision(2);
  if (!s.done)
    return "color: from each point's own step" + (s.note.empty() ? std::string() : " (" + s.note + ")") +
           "\n";
  out << "color: " << s.views << " natural frames, " << s.points_colored << " points seen in "
      << s.mean_views_per_point << " views on average, " << 100 * s.shadow_fraction
      << " % of views in cast shadow; ";
  if (s.shading_removed) {
    const double strength = s.lamp_in_cam.norm();
    const Eigen::Vector3d d =
        strength > 0 ? Eigen::Vector3d(s.lamp_in_cam / strength) : Eigen::Vector3d::Zero();
    out << "lamp shading removed (" << s.lamp_source << " lamp: direction in the camera frame " << d.x()
        << " " << d.y() << " " << d.z() << ", diffuse/ambient " << strength << "; shading normals "
        << (s.normal_radius_mm > 0 ? "PCA over " + std::to_string(s.normal_radius_mm).substr(0, 4) + " mm"
                                   : std::string("the cloud's"))
        << ")\n";
  } else {
    out << "shading kept" << (s.note.empty() ? std::string() : " (" + s.note + ")") << "\n";
  }
  return out.str();
}

}  // namespace rotoscan::pipeline
