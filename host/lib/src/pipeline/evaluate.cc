// Design notes (the metrics are defined in evaluate.h):
// - Open3D's RaycastingScene (Embree 3 underneath) gives the exact closest point on the true mesh, with
//   its triangle and barycentric coordinates, for the distance and the color truth in one query. Open3D
//   stays private to this file.
// - Occlusion rays go to Embree directly: Debian's Open3D 0.16 CastRays/TestOcclusions never report a hit
//   (its rays leave Embree's ray mask at 0 while Debian's Embree is built with ray masks; measured: a ray
//   straight at a triangle gives t_hit = inf), so visibility would be "everything".
// - Visibility is tested view by view only for samples not yet found visible, so the cost is about
//   (samples) + (never visible samples) x (views) rays.
// - Coverage looks up cloud points in a uniform grid of cell = radius (27 cells per sample: the cloud
//   module's CellIndex), built once over the points sorted by cell.
#include "rotoscan/pipeline/evaluate.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <numeric>
#include <random>
#include <thread>
#include <unordered_map>

#include <embree3/rtcore.h>
#include <open3d/core/Tensor.h>
#include <open3d/t/geometry/RaycastingScene.h>
#include <nlohmann/json.hpp>

#include "rotoscan/core/check.h"
#include "rotoscan/geometry/rig.h"
#include "cloud/cell_index.h"
#include "rotoscan/sim/scene.h"
#include "sim/mesh.h"

namespace rotoscan::pipeline {
namespace {

namespace o3c = open3d::core;
using open3d::t::geometry::RaycastingScene;

constexpr size_t kChunk = 1 << 16;  // points per query (progress and cancel granularity)

int ThreadCount(int requested) {
  if (requested > 0) return requested;
  return static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

// Runs body(begin, end) over [0, n) split in `threads` contiguous parts.
template <typename Body>
void ParallelFor(size_t n, int threads, const Body& body) {
  const size_t parts = std::min<size_t>(static_cast<size_t>(threads), std::max<size_t>(1, n / 4096));
  if (parts <= 1) {
    body(size_t{0}, n);
    return;
  }
  std::vector<std::thread> workers;
  for (size_t p = 0; p < parts; ++p) {
    workers.emplace_back([&, p] { body(n * p / parts, n * (p + 1) / parts); });
  }
  for (std::thread& w : workers) w.join();
}

std::unique_ptr<RaycastingScene> BuildScene(const bundle::TruthMesh& mesh, int threads) {
  std::vector<float> vertices;
  vertices.reserve(mesh.vertices.size() * 3);
  for (const Eigen::Vector3f& v : mesh.vertices) vertices.insert(vertices.end(), {v.x(), v.y(), v.z()});
  std::vector<uint32_t> faces;
  faces.reserve(mesh.faces.size() * 3);
  for (const Eigen::Vector3i& f : mesh.faces) {
    for (int k = 0; k < 3; ++k) faces.push_back(static_cast<uint32_t>(f[k]));
  }
  auto scene = std::make_unique<RaycastingScene>(threads);
  scene->AddTriangles(o3c::Tensor(vertices, {static_cast<int64_t>(mesh.vertices.size()), 3}, o3c::Float32),
                      o3c::Tensor(faces, {static_cast<int64_t>(mesh.faces.size()), 3}, o3c::UInt32));
  return scene;
}

// Embree occlusion queries against the true mesh.
class Occluder {
 public:
  Occluder() = default;
  ~Occluder() {
    if (scene_ != nullptr) rtcReleaseScene(scene_);
    if (device_ != nullptr) rtcReleaseDevice(device_);
  }
  Occluder(const Occluder&) = delete;
  Occluder& operator=(const Occluder&) = delete;

  Status Build(const bundle::TruthMesh& mesh) {
    device_ = rtcNewDevice(nullptr);
    if (device_ == nullptr) return InternalError("Embree device creation failed");
    scene_ = rtcNewScene(device_);
    RTCGeometry geometry = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(
        geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), mesh.vertices.size()));
    auto* indices = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
        geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), mesh.faces.size()));
    if (vertices == nullptr || indices == nullptr) {
      rtcReleaseGeometry(geometry);
      return InternalError("Embree buffer allocation failed");
    }
    for (size_t i = 0; i < mesh.vertices.size(); ++i) {
      for (int k = 0; k < 3; ++k) vertices[3 * i + k] = mesh.vertices[i][k];
    }
    for (size_t i = 0; i < mesh.faces.size(); ++i) {
      for (int k = 0; k < 3; ++k) indices[3 * i + k] = static_cast<unsigned>(mesh.faces[i][k]);
    }
    rtcCommitGeometry(geometry);
    rtcAttachGeometry(scene_, geometry);
    rtcReleaseGeometry(geometry);
    rtcCommitScene(scene_);
    if (rtcGetDeviceError(device_) != RTC_ERROR_NONE) return InternalError("Embree scene build failed");
    return Status::Ok();
  }

  // True when the mesh crosses the ray origin + t direction (unit), t in [tnear, inf). Thread-safe.
  bool Occluded(const Eigen::Vector3f& origin, const Eigen::Vector3f& direction, float tnear) const {
    RTCRay ray{};
    ray.org_x = origin.x(), ray.org_y = origin.y(), ray.org_z = origin.z();
    ray.dir_x = direction.x(), ray.dir_y = direction.y(), ray.dir_z = direction.z();
    ray.tnear = tnear;
    ray.tfar = std::numeric_limits<float>::infinity();
    ray.mask = 0xFFFFFFFF;
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    rtcOccluded1(scene_, &context, &ray);
    return ray.tfar < 0.0f;
  }

 private:
  RTCDevice device_ = nullptr;
  RTCScene scene_ = nullptr;
};

struct Closest {
  Eigen::Vector3f point;
  uint32_t face;
  float u, v;
};

// Closest surface points of cloud points [begin, end).
std::vector<Closest> ClosestPoints(RaycastingScene& scene, const cloud::PointCloud& cloud, size_t begin,
                                   size_t end, int threads) {
  std::vector<float> query;
  query.reserve((end - begin) * 3);
  for (size_t i = begin; i < end; ++i) {
    const Eigen::Vector3f& p = cloud.points[i].position_in_table;
    query.insert(query.end(), {p.x(), p.y(), p.z()});
  }
  auto result = scene.ComputeClosestPoints(
      o3c::Tensor(query, {static_cast<int64_t>(end - begin), 3}, o3c::Float32), threads);
  const o3c::Tensor points = result.at("points").Contiguous();
  const o3c::Tensor ids = result.at("primitive_ids").Contiguous();
  const o3c::Tensor uvs = result.at("primitive_uvs").Contiguous();
  const float* p = points.GetDataPtr<float>();
  const uint32_t* id = ids.GetDataPtr<uint32_t>();
  const float* uv = uvs.GetDataPtr<float>();
  std::vector<Closest> out(end - begin);
  for (size_t i = 0; i < out.size(); ++i) {
    out[i] = {Eigen::Vector3f(p[3 * i], p[3 * i + 1], p[3 * i + 2]), id[i], uv[2 * i], uv[2 * i + 1]};
  }
  return out;
}

DistanceStats Stats(std::vector<double> d) {
  DistanceStats s;
  s.points = d.size();
  if (d.empty()) return s;
  double sum = 0, sum2 = 0;
  for (double x : d) sum += x, sum2 += x * x;
  s.mean_mm = sum / d.size();
  s.rms_mm = std::sqrt(sum2 / d.size());
  // 95th percentile: the smallest value with at least 95 % of the points at or below it.
  const size_t k = std::min(d.size() - 1, static_cast<size_t>(std::ceil(0.95 * d.size())) - 1);
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(k), d.end());
  s.p95_mm = d[k];
  const size_t half = (d.size() - 1) / 2;
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(half), d.end());
  s.median_mm = d[half];
  s.max_mm = *std::max_element(d.begin(), d.end());
  return s;
}

struct Sample {
  Eigen::Vector3f point;
  bool visible = false;
};

// Area-uniform random samples of the mesh (one per spacing^2), without those near the table top.
Result<std::vector<Sample>> SampleSurface(const bundle::TruthMesh& mesh, const EvaluateOptions& o,
                                          size_t* all_samples, double* area_per_sample) {
  std::vector<double> cumulative(mesh.faces.size());
  double area = 0;
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    const Eigen::Vector3i& t = mesh.faces[f];
    const Eigen::Vector3d a = mesh.vertices[t[0]].cast<double>(), b = mesh.vertices[t[1]].cast<double>(),
                          c = mesh.vertices[t[2]].cast<double>();
    area += 0.5 * (b - a).cross(c - a).norm();
    cumulative[f] = area;
  }
  if (!(area > 0)) return InvalidArgumentError("the true mesh has no area");
  const double wanted = std::ceil(area / (o.sample_spacing_mm * o.sample_spacing_mm));
  if (wanted > static_cast<double>(o.max_samples)) {
    return InvalidArgumentError("the true mesh (" + std::to_string(area) + " mm^2) needs " +
                                std::to_string(static_cast<size_t>(wanted)) + " samples at " +
                                std::to_string(o.sample_spacing_mm) + " mm spacing, more than max_samples " +
                                std::to_string(o.max_samples) + ": use a larger spacing");
  }
  const size_t n = static_cast<size_t>(wanted);
  *all_samples = n;
  *area_per_sample = area / static_cast<double>(n);
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::vector<Sample> samples;
  samples.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    const double pick = uniform(rng) * area;
    const size_t f =
        std::min<size_t>(static_cast<size_t>(std::lower_bound(cumulative.begin(), cumulative.end(), pick) -
                                             cumulative.begin()),
                         mesh.faces.size() - 1);
    const double r1 = std::sqrt(uniform(rng)), r2 = uniform(rng);
    const Eigen::Vector3i& t = mesh.faces[f];
    const Eigen::Vector3d p = (1 - r1) * mesh.vertices[t[0]].cast<double>() +
                              r1 * (1 - r2) * mesh.vertices[t[1]].cast<double>() +
                              r1 * r2 * mesh.vertices[t[2]].cast<double>();
    if (p.z() < o.table_clearance_mm) continue;
    samples.push_back({p.cast<float>(), false});
  }
  return samples;
}

// Marks the samples that some view sees.
Status MarkVisible(const Occluder& occluder, const EvaluationViews& views, const EvaluateOptions& o,
                   std::vector<Sample>& samples, Progress* progress) {
  ProgressScope scope(progress, "visibility", views.cam_from_table.size());
  const int threads = ThreadCount(o.threads);
  for (const Eigen::Isometry3d& cam_from_table : views.cam_from_table) {
    if (scope.Cancelled()) return CancelledError("evaluation cancelled");
    const Eigen::Vector3d camera_in_table = cam_from_table.inverse().translation();
    ParallelFor(samples.size(), threads, [&](size_t begin, size_t end) {
      for (size_t i = begin; i < end; ++i) {
        if (samples[i].visible) continue;
        const Eigen::Vector3d point = samples[i].point.cast<double>();
        const Eigen::Vector3d point_in_cam = cam_from_table * point;
        if (point_in_cam.z() <= 0 || !views.camera.IsInside(views.camera.Project(point_in_cam))) continue;
        // The ray starts 1 µm off the surface (float positions within ±100 mm are exact to ~0.01 µm).
        const Eigen::Vector3f direction = (camera_in_table - point).normalized().cast<float>();
        if (!occluder.Occluded(samples[i].point, direction, 1e-3f)) samples[i].visible = true;
      }
    });
    scope.Advance();
  }
  return Status::Ok();
}

// Cloud points by grid cell of size `cell` (cloud/cell_index.h).
class PointGrid {
 public:
  PointGrid(const cloud::PointCloud& cloud, double cell) : cloud_(cloud), index_(cloud, AllPoints(cloud), cell) {}

  // The distance from p to the nearest point within one cell for which `other(point)` holds (inf: none).
  template <typename Other>
  float NearestWhere(const Eigen::Vector3f& p, Other other) const {
    float best = std::numeric_limits<float>::infinity();
    index_.ForEachNear(p, [&](uint32_t i) {
      const cloud::CloudPoint& q = cloud_.points[i];
      if (other(q)) best = std::min(best, (q.position_in_table - p).squaredNorm());
    });
    return std::sqrt(best);
  }

  // Bit 0: a left-laser point within `radius` of p; bit 1: a right-laser point; bit 2: any point.
  int Near(const Eigen::Vector3f& p, double radius) const {
    const float r2 = static_cast<float>(radius * radius);
    int found = 0;
    index_.ForEachNear(p, [&](uint32_t i) {
      const cloud::CloudPoint& q = cloud_.points[i];
      if ((q.position_in_table - p).squaredNorm() <= r2) found |= 4 | (q.laser == 0 ? 1 : q.laser == 1 ? 2 : 0);
      return found != 7;
    });
    return found;
  }

 private:
  static std::vector<uint32_t> AllPoints(const cloud::PointCloud& cloud) {
    std::vector<uint32_t> all(cloud.size());
    std::iota(all.begin(), all.end(), uint32_t{0});
    return all;
  }

  const cloud::PointCloud& cloud_;
  cloud::internal::CellIndex index_;
};

Eigen::Vector3f InterpolatedColor(const bundle::TruthMesh& mesh, const Closest& c) {
  const Eigen::Vector3i& t = mesh.faces[c.face];
  Eigen::Vector3f color = Eigen::Vector3f::Zero();
  const float w[3] = {1 - c.u - c.v, c.u, c.v};
  for (int k = 0; k < 3; ++k) {
    const auto& rgb = mesh.colors[static_cast<size_t>(t[k])];
    color += w[k] * Eigen::Vector3f(rgb[0], rgb[1], rgb[2]) / 255.f;
  }
  return color;
}

double CoverageRadius(const bundle::TruthMesh& mesh, const EvaluationViews& views, const EvaluateOptions& o) {
  if (o.coverage_radius_mm > 0) return o.coverage_radius_mm;
  double r_max = 0;
  for (const Eigen::Vector3f& v : mesh.vertices)
    r_max = std::max(r_max, std::hypot(static_cast<double>(v.x()), static_cast<double>(v.y())));
  return std::max(0.5, 0.6 * r_max * views.step_rad);
}

}  // namespace

Status EvaluateOptions::Check() const {
  auto positive = [](double v) { return std::isfinite(v) && v > 0; };
  if (!positive(sample_spacing_mm)) return InvalidArgumentError("sample_spacing_mm must be > 0");
  if (!std::isfinite(coverage_radius_mm) || coverage_radius_mm < 0)
    return InvalidArgumentError("coverage_radius_mm must be >= 0 (0: automatic)");
  if (coverage_radius_mm > 0 && coverage_radius_mm < 0.05)
    return InvalidArgumentError("coverage_radius_mm must be at least 0.05 mm");
  if (!std::isfinite(table_clearance_mm)) return InvalidArgumentError("table_clearance_mm must be finite");
  if (!positive(color_max_distance_mm)) return InvalidArgumentError("color_max_distance_mm must be > 0");
  if (!(std::isfinite(color_tolerance) && color_tolerance >= 0))
    return InvalidArgumentError("color_tolerance must be >= 0");
  if (max_samples == 0) return InvalidArgumentError("max_samples must be > 0");
  if (threads < 0) return InvalidArgumentError("threads must be >= 0");
  return Status::Ok();
}

// The scan's own point spacing across its laser lines: for a sample of points, the distance to the nearest
// point of another line (another step or laser) of the same placement within kSpacingCellMm; the 95th
// percentile, for the coarsest placement of a merged cloud (where only it saw the surface, that is its
// spacing). 0 when fewer than half the sampled points have another line that close (not a scan of laser
// lines).
constexpr double kSpacingCellMm = 4.0;
double LineSpacingP95(const cloud::PointCloud& all) {
  std::array<cloud::PointCloud, 256> parts;
  for (const cloud::CloudPoint& p : all.points) parts[p.placement].points.push_back(p);
  double widest = 0;
  for (const cloud::PointCloud& cloud : parts) {
    if (cloud.size() < 100) continue;
    const PointGrid grid(cloud, kSpacingCellMm);
    const size_t stride = std::max<size_t>(1, cloud.size() / 20000);
    std::vector<float> gaps;
    size_t sampled = 0;
    for (size_t i = 0; i < cloud.size(); i += stride, ++sampled) {
      const cloud::CloudPoint& p = cloud.points[i];
      const float d = grid.NearestWhere(p.position_in_table, [&](const cloud::CloudPoint& q) {
        return q.step != p.step || q.laser != p.laser;
      });
      if (std::isfinite(d)) gaps.push_back(d);
    }
    if (gaps.size() < 10 || 2 * gaps.size() < sampled) continue;
    const size_t at = static_cast<size_t>(0.95 * static_cast<double>(gaps.size() - 1));
    std::nth_element(gaps.begin(), gaps.begin() + static_cast<std::ptrdiff_t>(at), gaps.end());
    widest = std::max(widest, static_cast<double>(gaps[at]));
  }
  return widest;
}

Result<EvaluationReport> EvaluateCloud(const cloud::PointCloud& cloud, const TruthSurface& truth,
                                       const EvaluationViews& views, const EvaluateOptions& options,
                                       Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  const bundle::TruthMesh& mesh = truth.mesh;
  if (cloud.empty()) return InvalidArgumentError("the cloud has no points");
  if (mesh.faces.empty()) return InvalidArgumentError("the true mesh has no faces");
  if (cloud.size() > std::numeric_limits<uint32_t>::max())
    return InvalidArgumentError("the cloud has more than 2^32 points");
  if (!mesh.colors.empty() && mesh.colors.size() != mesh.vertices.size())
    return InvalidArgumentError("the true mesh has " + std::to_string(mesh.colors.size()) + " colors for " +
                                std::to_string(mesh.vertices.size()) + " vertices");
  for (const Eigen::Vector3i& f : mesh.faces) {
    if (f.minCoeff() < 0 || static_cast<size_t>(f.maxCoeff()) >= mesh.vertices.size())
      return InvalidArgumentError("the true mesh has a face with a vertex index out of range");
  }
  if (views.cam_from_table.empty()) return InvalidArgumentError("no views to define the visible surface");
  ROTOSCAN_RETURN_IF_ERROR(views.camera.Validate());
  const int threads = ThreadCount(options.threads);
  std::unique_ptr<RaycastingScene> scene = BuildScene(mesh, threads);

  EvaluationReport report;
  report.points = cloud.size();
  report.has_color = static_cast<bool>(truth.albedo) || !mesh.colors.empty();

  // Distance and color truth.
  std::vector<double> distance(cloud.size()), distance_left, distance_right;
  std::vector<std::array<double, 3>> measured, expected;
  {
    ProgressScope scope(progress, "distance", cloud.size());
    for (size_t begin = 0; begin < cloud.size(); begin += kChunk) {
      if (scope.Cancelled()) return CancelledError("evaluation cancelled");
      const size_t end = std::min(cloud.size(), begin + kChunk);
      const std::vector<Closest> closest = ClosestPoints(*scene, cloud, begin, end, threads);
      for (size_t i = begin; i < end; ++i) {
        const cloud::CloudPoint& p = cloud.points[i];
        const Closest& c = closest[i - begin];
        const double d = (p.position_in_table - c.point).cast<double>().norm();
        distance[i] = d;
        if (p.laser == 0) distance_left.push_back(d);
        if (p.laser == 1) distance_right.push_back(d);
        if (!report.has_color || d > options.color_max_distance_mm) continue;
        if (c.face >= mesh.faces.size()) continue;  // Open3D's invalid id (cannot happen with faces)
        const Eigen::Vector3f albedo =
            truth.albedo ? truth.albedo(static_cast<int>(c.face), c.u, c.v, c.point.cast<double>())
                         : InterpolatedColor(mesh, c);
        measured.push_back({static_cast<double>(p.color[0]), static_cast<double>(p.color[1]),
                            static_cast<double>(p.color[2])});
        expected.push_back({255.0 * albedo.x(), 255.0 * albedo.y(), 255.0 * albedo.z()});
      }
      scope.Advance(end - begin);
    }
  }
  report.left_points = distance_left.size();
  report.right_points = distance_right.size();
  report.distance = Stats(std::move(distance));
  report.distance_left = Stats(std::move(distance_left));
  report.distance_right = Stats(std::move(distance_right));

  // Color: one least-squares gain per channel, then absolute errors.
  if (report.has_color) {
    ColorStats& cs = report.color;
    cs.truth_source = truth.albedo ? truth.color_source : "vertex colors";
    cs.points = measured.size();
    cs.tolerance = options.color_tolerance;
    if (cs.points > 0) {
      for (int ch = 0; ch < 3; ++ch) {
        double mt = 0, mm = 0;
        for (size_t i = 0; i < measured.size(); ++i) {
          mt += measured[i][ch] * expected[i][ch];
          mm += measured[i][ch] * measured[i][ch];
        }
        cs.gain[ch] = mm > 0 ? mt / mm : 1.0;
      }
      size_t within = 0, within_per_point = 0;
      for (size_t i = 0; i < measured.size(); ++i) {
        double worst = 0;
        for (int ch = 0; ch < 3; ++ch) {
          const double e = std::abs(cs.gain[ch] * measured[i][ch] - expected[i][ch]);
          cs.mean_abs_error[ch] += e;
          worst = std::max(worst, e);
        }
        if (worst <= options.color_tolerance) ++within;
        const Eigen::Vector3d m(measured[i][0], measured[i][1], measured[i][2]);
        const Eigen::Vector3d t(expected[i][0], expected[i][1], expected[i][2]);
        const double g = m.squaredNorm() > 0 ? m.dot(t) / m.squaredNorm() : 1.0;
        const Eigen::Vector3d e = (g * m - t).cwiseAbs();
        cs.mean_abs_error_per_point_gain += e.mean();
        if (e.maxCoeff() <= options.color_tolerance) ++within_per_point;
      }
      cs.mean_abs_error_per_point_gain /= static_cast<double>(cs.points);
      cs.within_tolerance_per_point_gain =
          static_cast<double>(within_per_point) / static_cast<double>(cs.points);
      cs.mean_abs_error /= static_cast<double>(cs.points);
      cs.mean_abs_error_all = cs.mean_abs_error.mean();
      cs.within_tolerance = static_cast<double>(within) / static_cast<double>(cs.points);
    }
  }

  // Coverage of the visible surface.
  CoverageStats& cov = report.coverage;
  double area_per_sample = 0;
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<Sample> samples,
                            SampleSurface(mesh, options, &cov.surface_samples, &area_per_sample));
  Occluder occluder;
  ROTOSCAN_RETURN_IF_ERROR(occluder.Build(mesh));
  ROTOSCAN_RETURN_IF_ERROR(MarkVisible(occluder, views, options, samples, progress));
  cov.radius_mm = options.coverage_radius_mm;
  cov.radius_rule = "given";
  if (cov.radius_mm == 0) {
    cov.line_spacing_p95_mm = LineSpacingP95(cloud);
    if (cov.line_spacing_p95_mm > 0) {
      cov.radius_mm = std::max(0.5, 0.6 * cov.line_spacing_p95_mm);
      char rule[160];
      std::snprintf(rule, sizeof(rule),
                    "the scan's point spacing: 0.6 x %.3f mm (95th percentile of the gap "
                    "between laser lines), at least 0.5 mm",
                    cov.line_spacing_p95_mm);
      cov.radius_rule = rule;
    } else {
      double r_max = 0;
      for (const Eigen::Vector3f& v : mesh.vertices)
        r_max = std::max(r_max, std::hypot(static_cast<double>(v.x()), static_cast<double>(v.y())));
      cov.radius_mm = std::max(0.5, 0.6 * r_max * views.step_rad);
      cov.radius_rule =
          "the table step: 0.6 x the largest radius x the step, at least 0.5 mm (no line spacing)";
    }
  }
  {
    ProgressScope scope(progress, "coverage", samples.size());
    const PointGrid grid(cloud, cov.radius_mm);
    std::atomic<size_t> visible{0}, left{0}, right{0}, any{0}, whole{0};
    ParallelFor(samples.size(), threads, [&](size_t begin, size_t end) {
      size_t v = 0, l = 0, r = 0, a = 0, w = 0;
      for (size_t i = begin; i < end; ++i) {
        const int near = grid.Near(samples[i].point, cov.radius_mm);
        w += (near & 4) != 0;
        if (!samples[i].visible) continue;
        ++v;
        l += (near & 1) != 0;
        r += (near & 2) != 0;
        a += (near & 4) != 0;
      }
      visible += v, left += l, right += r, any += a, whole += w;
    });
    cov.whole_samples = samples.size();
    cov.whole_area_mm2 = static_cast<double>(samples.size()) * area_per_sample;
    if (!samples.empty()) cov.whole = static_cast<double>(whole.load()) / static_cast<double>(samples.size());
    scope.Advance(samples.size());
    cov.visible_samples = visible;
    cov.visible_area_mm2 = static_cast<double>(visible) * area_per_sample;
    if (visible > 0) {
      const double n = static_cast<double>(visible.load());
      cov.left = static_cast<double>(left.load()) / n;
      cov.right = static_cast<double>(right.load()) / n;
      cov.both = static_cast<double>(any.load()) / n;
    }
  }
  return report;
}

Result<TruthToMeshStats> EvaluateTruthToMesh(const std::vector<Eigen::Vector3f>& vertices,
                                             const std::vector<Eigen::Vector3i>& triangles,
                                             const TruthSurface& truth, const EvaluationViews& views,
                                             const EvaluateOptions& options, Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  const bundle::TruthMesh& mesh = truth.mesh;
  if (vertices.empty() || triangles.empty()) return InvalidArgumentError("the mesh has no triangles");
  for (const Eigen::Vector3i& t : triangles) {
    if (t.minCoeff() < 0 || static_cast<size_t>(t.maxCoeff()) >= vertices.size())
      return InvalidArgumentError("the mesh has a triangle with a vertex index out of range");
  }
  for (const Eigen::Vector3f& v : vertices) {
    if (!v.allFinite()) return InvalidArgumentError("the mesh has a non-finite vertex");
  }
  if (mesh.faces.empty()) return InvalidArgumentError("the true mesh has no faces");
  for (const Eigen::Vector3i& f : mesh.faces) {
    if (f.minCoeff() < 0 || static_cast<size_t>(f.maxCoeff()) >= mesh.vertices.size())
      return InvalidArgumentError("the true mesh has a face with a vertex index out of range");
  }
  if (views.cam_from_table.empty()) return InvalidArgumentError("no views to define the visible surface");
  ROTOSCAN_RETURN_IF_ERROR(views.camera.Validate());
  const int threads = ThreadCount(options.threads);
  TruthToMeshStats stats;
  double area_per_sample = 0;
  size_t all_samples = 0;
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<Sample> samples, SampleSurface(mesh, options, &all_samples, &area_per_sample));
  Occluder occluder;
  ROTOSCAN_RETURN_IF_ERROR(occluder.Build(mesh));
  ROTOSCAN_RETURN_IF_ERROR(MarkVisible(occluder, views, options, samples, progress));
  stats.radius_mm = CoverageRadius(mesh, views, options);
  // The visible samples as a "cloud", against the scanned mesh as the surface.
  cloud::PointCloud visible;
  for (const Sample& s : samples) {
    if (!s.visible) continue;
    cloud::CloudPoint p;
    p.position_in_table = s.point;
    visible.points.push_back(p);
  }
  stats.visible_samples = visible.size();
  stats.visible_area_mm2 = static_cast<double>(visible.size()) * area_per_sample;
  if (visible.empty()) return stats;
  bundle::TruthMesh scanned;
  scanned.vertices = vertices;
  scanned.faces = triangles;
  std::unique_ptr<RaycastingScene> scene = BuildScene(scanned, threads);
  std::vector<double> distance(visible.size());
  size_t far = 0;
  ProgressScope scope(progress, "truth to mesh", visible.size());
  for (size_t begin = 0; begin < visible.size(); begin += kChunk) {
    if (scope.Cancelled()) return CancelledError("evaluation cancelled");
    const size_t end = std::min(visible.size(), begin + kChunk);
    const std::vector<Closest> closest = ClosestPoints(*scene, visible, begin, end, threads);
    for (size_t i = begin; i < end; ++i) {
      distance[i] = (visible.points[i].position_in_table - closest[i - begin].point).cast<double>().norm();
      far += distance[i] > stats.radius_mm ? 1 : 0;
    }
    scope.Advance(end - begin);
  }
  stats.distance = Stats(std::move(distance));
  stats.hole_fraction = static_cast<double>(far) / static_cast<double>(visible.size());
  stats.hole_area_mm2 = static_cast<double>(far) * area_per_sample;
  return stats;
}

Result<TruthSurface> LoadTruthSurface(const std::filesystem::path& bundle_dir,
                                      const std::filesystem::path& scene_path) {
  const std::filesystem::path mesh_path = bundle::TruthMeshPath(bundle_dir);
  std::error_code ec;
  if (!std::filesystem::is_regular_file(mesh_path, ec))
    return NotFoundError(mesh_path.string() +
                         " not found: the bundle has no true mesh (render it with truth)");
  TruthSurface truth;
  ROTOSCAN_ASSIGN_OR_RETURN(truth.mesh, bundle::ReadPlyMesh(mesh_path));
  if (scene_path.empty()) return truth;

  ROTOSCAN_ASSIGN_OR_RETURN(sim::Scene given, sim::LoadScene(scene_path));
  // The scene in the bundle's placement (sim::PlaceScene): where its objects were when it was rendered.
  int placement = 0;
  if (auto header = bundle::ReadBundle(bundle_dir, {false}); header.ok())
    placement = header->header.placement;
  ROTOSCAN_ASSIGN_OR_RETURN(sim::Scene scene, sim::PlaceScene(given, placement, nullptr));
  auto meshes = std::make_shared<std::vector<sim::internal::Mesh>>();
  std::vector<int> first_face;  // of each object in the concatenated mesh
  size_t vertices = 0, faces = 0;
  for (const sim::ObjectSpec& spec : scene.objects) {
    ROTOSCAN_ASSIGN_OR_RETURN(sim::internal::Mesh m, sim::internal::MakeObject(spec, scene));
    first_face.push_back(static_cast<int>(faces));
    vertices += m.vertices.size();
    faces += m.faces.size();
    meshes->push_back(std::move(m));
  }
  // The scene must be the one the bundle was rendered from: same vertices, same faces.
  bool same = vertices == truth.mesh.vertices.size() && faces == truth.mesh.faces.size();
  double worst_mm = 0;
  for (size_t i = 0, base = 0, f0 = 0; same && i < meshes->size(); ++i) {
    const sim::internal::Mesh& m = (*meshes)[i];
    for (size_t v = 0; v < m.vertices.size(); ++v) {
      worst_mm =
          std::max(worst_mm, static_cast<double>((m.vertices[v] - truth.mesh.vertices[base + v]).norm()));
    }
    for (size_t f = 0; same && f < m.faces.size(); ++f) {
      same = m.faces[f] + Eigen::Vector3i::Constant(static_cast<int>(base)) == truth.mesh.faces[f0 + f];
    }
    base += m.vertices.size();
    f0 += m.faces.size();
  }
  if (!same || worst_mm > 1e-3) {
    char worst[64];
    std::snprintf(worst, sizeof(worst), "%.4g", worst_mm);
    return InvalidArgumentError("scene " + scene_path.string() + " is not the scene of bundle " +
                                bundle_dir.string() + ": its objects (" + std::to_string(vertices) +
                                " vertices, " + std::to_string(faces) + " faces) differ from " +
                                mesh_path.string() + " (" + std::to_string(truth.mesh.vertices.size()) +
                                " vertices, " + std::to_string(truth.mesh.faces.size()) +
                                " faces; vertices up to " + worst + " mm apart)");
  }
  truth.color_source = "scene albedo (" + scene_path.filename().string() + ")";
  truth.albedo = [meshes, first_face](int face, float u, float v, const Eigen::Vector3d& point_in_table) {
    const size_t object = static_cast<size_t>(std::upper_bound(first_face.begin(), first_face.end(), face) -
                                              first_face.begin() - 1);
    return (*meshes)[object].Albedo(static_cast<unsigned>(face - first_face[object]), u, v, point_in_table);
  };
  return truth;
}

Result<EvaluationViews> LoadEvaluationViews(const std::filesystem::path& bundle_dir) {
  bundle::ReadOptions read_options;
  read_options.verify_frames = false;
  ROTOSCAN_ASSIGN_OR_RETURN(bundle::Bundle b, bundle::ReadBundle(bundle_dir, read_options));
  const std::filesystem::path rig_path = bundle::TruthRigPath(bundle_dir);
  std::error_code ec;
  if (!std::filesystem::is_regular_file(rig_path, ec))
    return NotFoundError(rig_path.string() + " not found: the bundle has no true rig (render it with truth)");
  ROTOSCAN_ASSIGN_OR_RETURN(geometry::Rig rig, geometry::ReadRigYaml(rig_path));
  std::vector<double> angles;
  for (const bundle::FrameRecord& f : b.frames) angles.push_back(f.table_angle_rad);
  std::sort(angles.begin(), angles.end());
  angles.erase(
      std::unique(angles.begin(), angles.end(), [](double a, double c) { return std::abs(a - c) < 1e-9; }),
      angles.end());
  if (angles.empty()) return InvalidArgumentError(bundle_dir.string() + "/bundle.json lists no frames");
  EvaluationViews views;
  views.camera = rig.camera;
  for (double a : angles) views.cam_from_table.push_back(rig.WorldFromCamAtAngle(a).inverse());
  std::vector<double> gaps;
  for (size_t i = 1; i < angles.size(); ++i) gaps.push_back(angles[i] - angles[i - 1]);
  if (!gaps.empty()) {
    std::nth_element(gaps.begin(), gaps.begin() + static_cast<std::ptrdiff_t>(gaps.size() / 2), gaps.end());
    views.step_rad = gaps[gaps.size() / 2];
  }
  return views;
}

std::string EvaluationJson(const EvaluationReport& r) {
  using json = nlohmann::json;
  auto distance = [](const DistanceStats& d) {
    return json{{"points", d.points},       {"rms_mm", d.rms_mm}, {"mean_mm", d.mean_mm},
                {"median_mm", d.median_mm}, {"p95_mm", d.p95_mm}, {"max_mm", d.max_mm}};
  };
  json j;
  j["format"] = "rotoscan evaluation 1";
  j["points"] = {{"all", r.points}, {"left", r.left_points}, {"right", r.right_points}};
  j["distance"] = distance(r.distance);
  j["distance_left"] = distance(r.distance_left);
  j["distance_right"] = distance(r.distance_right);
  const CoverageStats& c = r.coverage;
  j["coverage"] = {{"radius_mm", c.radius_mm},
                   {"radius_rule", c.radius_rule},
                   {"line_spacing_p95_mm", c.line_spacing_p95_mm},
                   {"whole_samples", c.whole_samples},
                   {"whole_area_mm2", c.whole_area_mm2},
                   {"whole", c.whole},
                   {"surface_samples", c.surface_samples},
                   {"visible_samples", c.visible_samples},
                   {"visible_area_mm2", c.visible_area_mm2},
                   {"left", c.left},
                   {"right", c.right},
                   {"both", c.both}};
  if (r.has_truth_to_mesh) {
    const TruthToMeshStats& m = r.truth_to_mesh;
    j["truth_to_mesh"] = {{"radius_mm", m.radius_mm},
                          {"visible_samples", m.visible_samples},
                          {"visible_area_mm2", m.visible_area_mm2},
                          {"distance", distance(m.distance)},
                          {"hole_fraction", m.hole_fraction},
                          {"hole_area_mm2", m.hole_area_mm2}};
  }
  if (r.has_color) {
    const ColorStats& k = r.color;
    j["color"] = {{"truth", k.truth_source},
                  {"points", k.points},
                  {"gain_rgb", {k.gain[0], k.gain[1], k.gain[2]}},
                  {"mean_abs_error_rgb", {k.mean_abs_error[0], k.mean_abs_error[1], k.mean_abs_error[2]}},
                  {"mean_abs_error", k.mean_abs_error_all},
                  {"tolerance_levels", k.tolerance},
                  {"within_tolerance", k.within_tolerance},
                  {"mean_abs_error_per_point_gain", k.mean_abs_error_per_point_gain},
                  {"within_tolerance_per_point_gain", k.within_tolerance_per_point_gain}};
  } else {
    j["color"] = nullptr;
  }
  return j.dump(2) + "\n";
}

std::string EvaluationSummary(const EvaluationReport& r) {
  char line[512];
  std::string out;
  std::snprintf(
      line, sizeof(line),
      "distance: %zu points (left %zu, right %zu): rms=%.4f mm mean=%.4f mm median=%.4f mm p95=%.4f mm "
      "max=%.4f mm\n",
      r.points, r.left_points, r.right_points, r.distance.rms_mm, r.distance.mean_mm, r.distance.median_mm,
      r.distance.p95_mm, r.distance.max_mm);
  out += line;
  const CoverageStats& c = r.coverage;
  std::snprintf(line, sizeof(line),
                "coverage: radius %.2f mm, %zu visible samples (%.0f mm^2): left=%.4f right=%.4f both=%.4f\n",
                c.radius_mm, c.visible_samples, c.visible_area_mm2, c.left, c.right, c.both);
  out += line;
  std::snprintf(line, sizeof(line),
                "coverage of the whole true surface (every view, every placement): %.4f of %zu samples (%.0f "
                "mm^2), radius %.2f mm from %s\n",
                c.whole, c.whole_samples, c.whole_area_mm2, c.radius_mm, c.radius_rule.c_str());
  out += line;
  if (r.has_color) {
    const ColorStats& k = r.color;
    std::snprintf(line, sizeof(line),
                  "color: %zu points vs %s, gain r=%.3f g=%.3f b=%.3f: mean abs error=%.2f levels "
                  "(r %.2f g %.2f b %.2f), within %g levels=%.4f\n",
                  k.points, k.truth_source.c_str(), k.gain[0], k.gain[1], k.gain[2], k.mean_abs_error_all,
                  k.mean_abs_error[0], k.mean_abs_error[1], k.mean_abs_error[2], k.tolerance,
                  k.within_tolerance);
    out += line;
    std::snprintf(line, sizeof(line),
                  "color, one gain per point (lamp shading removed): mean abs error=%.2f levels, within %g "
                  "levels=%.4f\n",
                  k.mean_abs_error_per_point_gain, k.tolerance, k.within_tolerance_per_point_gain);
    out += line;
  } else {
    out += "color: not measured (the truth has no colors)\n";
  }
  if (r.has_truth_to_mesh) {
    const TruthToMeshStats& m = r.truth_to_mesh;
    std::snprintf(line, sizeof(line),
                  "truth to mesh: %zu visible samples (%.0f mm^2): median=%.4f mm p95=%.4f mm max=%.3f mm; holes: "
                  "%.4f of the visible area (%.1f mm^2) is farther than %.2f mm from the mesh\n",
                  m.visible_samples, m.visible_area_mm2, m.distance.median_mm, m.distance.p95_mm, m.distance.max_mm,
                  m.hole_fraction, m.hole_area_mm2, m.radius_mm);
    out += line;
  }
  return out;
}

}  // namespace rotoscan::pipeline
