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

#include "cloud/cell_index.h"
#include "rotoscan/core/check.h"
#include "rotoscan/geometry/rig.h"
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
  Eigen::Vector3f normal = Eigen::Vector3f::Zero();  // of its face (the mesh's winding)
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
    const Eigen::Vector3d a = mesh.vertices[t[0]].cast<double>(), b = mesh.vertices[t[1]].cast<double>(),
                          c = mesh.vertices[t[2]].cast<double>();
    samples.push_back({p.cast<float>(), false, (b - a).cross(c - a).normalized().cast<float>()});
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
  PointGrid(const cloud::PointCloud& cloud, double cell)
      : cloud_(cloud), index_(cloud, AllPoints(cloud), cell) {}

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

  // Calls f(index) for every point within one cell of p (and some farther).
  template <typename F>
  void ForEachIndexNear(const Eigen::Vector3f& p, F f) const {
    index_.ForEachNear(p, f);
  }

  // Bit 0: a left-laser point within `radius` of p; bit 1: a right-laser point; bit 2: any point.
  int Near(const Eigen::Vector3f& p, double radius) const {
    const float r2 = static_cast<float>(radius * radius);
    int found = 0;
    index_.ForEachNear(p, [&](uint32_t i) {
      const cloud::CloudPoint& q = cloud_.points[i];
      if ((q.position_in_table - p).squaredNorm() <= r2)
        found |= 4 | (q.laser == 0 ? 1 : q.laser == 1 ? 2 : 0);
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

// The coverage radius: given, or from the scan's own line spacing, or from the table step (evaluate.h).
void AutomaticRadius(const cloud::PointCloud& cloud, const bundle::TruthMesh& mesh,
                     const EvaluationViews& views, const EvaluateOptions& options, CoverageStats* cov) {
  cov->radius_mm = options.coverage_radius_mm;
  cov->radius_rule = "given";
  if (cov->radius_mm > 0) return;
  cov->line_spacing_p95_mm = LineSpacingP95(cloud);
  if (cov->line_spacing_p95_mm > 0) {
    cov->radius_mm = std::max(0.5, 0.6 * cov->line_spacing_p95_mm);
    char rule[160];
    std::snprintf(rule, sizeof(rule),
                  "the scan's point spacing: 0.6 x %.3f mm (95th percentile of the gap "
                  "between laser lines), at least 0.5 mm",
                  cov->line_spacing_p95_mm);
    cov->radius_rule = rule;
  } else {
    double r_max = 0;
    for (const Eigen::Vector3f& v : mesh.vertices)
      r_max = std::max(r_max, std::hypot(static_cast<double>(v.x()), static_cast<double>(v.y())));
    cov->radius_mm = std::max(0.5, 0.6 * r_max * views.step_rad);
    cov->radius_rule =
        "the table step: 0.6 x the largest radius x the step, at least 0.5 mm (no line spacing)";
  }
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
  AutomaticRadius(cloud, mesh, views, options, &cov);
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

// ---- Reach: where coverage is lost (evaluate.h, EvaluateReach) ----

Result<ScanRig> LoadScanRig(const std::filesystem::path& bundle_dir,
                            const std::filesystem::path& scene_path) {
  if (scene_path.empty()) return InvalidArgumentError("the rig's reach needs the scene (--scene)");
  ROTOSCAN_ASSIGN_OR_RETURN(sim::Scene scene, sim::LoadScene(scene_path));
  int placement = 0;
  if (auto header = bundle::ReadBundle(bundle_dir, {false}); header.ok())
    placement = header->header.placement;
  Eigen::Isometry3d truth_from_reference;
  ROTOSCAN_ASSIGN_OR_RETURN(sim::Scene placed, sim::PlaceScene(scene, placement, &truth_from_reference));
  (void)placed;
  ScanRig rig;
  rig.rig = scene.rig;
  for (int l = 0; l < 2; ++l) rig.laser_origin_in_cam[l] = scene.laser[l].origin_in_cam;
  const int count = scene.placements.empty() ? 1 : static_cast<int>(scene.placements.size());
  for (int k = 0; k < count; ++k) {
    Eigen::Isometry3d table_from_reference;
    ROTOSCAN_ASSIGN_OR_RETURN(sim::Scene other, sim::PlaceScene(scene, k, &table_from_reference));
    (void)other;
    rig.placement_rotation.push_back(table_from_reference.linear() *
                                     truth_from_reference.linear().transpose());
  }
  return rig;
}

namespace {

// The pose that turns the truth frame by `rotation`, then stands the mesh on the table centred on the axis
// (sim::PlaceScene's rule).
Eigen::Isometry3d StandOnTable(const bundle::TruthMesh& mesh, const Eigen::Matrix3d& rotation) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (const Eigen::Vector3f& v : mesh.vertices) {
    const Eigen::Vector3d q = rotation * v.cast<double>();
    lo = lo.cwiseMin(q);
    hi = hi.cwiseMax(q);
  }
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = rotation;
  pose.translation() = Eigen::Vector3d(-(lo.x() + hi.x()) / 2, -(lo.y() + hi.y()) / 2, -lo.z());
  return pose;
}

// A rotation taking `up` (unit, truth frame) to the table's +z.
Eigen::Matrix3d RotationUp(const Eigen::Vector3d& up) {
  return Eigen::Quaterniond::FromTwoVectors(up, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

// Directions spread evenly over the sphere (Fibonacci lattice), the first one +z.
std::vector<Eigen::Vector3d> SphereDirections(int n) {
  std::vector<Eigen::Vector3d> out;
  const double golden = 3.14159265358979323846 * (3.0 - std::sqrt(5.0));
  for (int i = 0; i < n; ++i) {
    const double z = 1.0 - 2.0 * i / std::max(1, n - 1);
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    out.emplace_back(r * std::cos(golden * i), r * std::sin(golden * i), z);
  }
  return out;
}

// Whether the rig can scan truth-frame point p with the object in `pose` (evaluate.h, ScanRig).
bool Scannable(const Occluder& occluder, const ScanRig& s,
               const std::array<Eigen::Isometry3d, 3>& cam_from_table, const Eigen::Isometry3d& pose,
               double clearance_mm, double min_cos, const Sample& sample) {
  const Eigen::Vector3f& p = sample.point;
  const Eigen::Vector3d q = pose * p.cast<double>();
  const Eigen::Vector3d normal = pose.linear() * sample.normal.cast<double>();
  if (q.z() < clearance_mm) return false;
  const geometry::Rig& rig = s.rig;
  const Eigen::Matrix3d back = pose.linear().transpose();  // table -> truth directions
  for (int l = 0; l < 2; ++l) {
    const geometry::Plane& plane = rig.laser_plane[l];
    // The plane's signed distance of q seen at table angle t is A cos t + B sin t + C.
    // (cam_from_table: at 0, 90 and 180 degrees.)
    const double f0 = plane.SignedDistance(cam_from_table[0] * q),
                 f90 = plane.SignedDistance(cam_from_table[1] * q),
                 f180 = plane.SignedDistance(cam_from_table[2] * q);
    const double a = 0.5 * (f0 - f180), c = 0.5 * (f0 + f180), b = f90 - c;
    const double r = std::hypot(a, b);
    if (r < 1e-9 || std::abs(c) > r) continue;
    const double phi = std::atan2(b, a), half = std::acos(std::clamp(-c / r, -1.0, 1.0));
    for (double t : {phi + half, phi - half}) {
      const Eigen::Isometry3d world_from_cam = rig.WorldFromCamAtAngle(t);
      const Eigen::Vector3d in_cam = world_from_cam.inverse() * q;
      if (in_cam.z() <= 0 || !rig.camera.IsInside(rig.camera.Project(in_cam))) continue;
      const Eigen::Vector3d to_camera = (world_from_cam.translation() - q).normalized();
      const Eigen::Vector3d to_laser = (world_from_cam * s.laser_origin_in_cam[l] - q).normalized();
      if (normal.dot(to_camera) < min_cos || normal.dot(to_laser) < min_cos) continue;
      if (occluder.Occluded(p, (back * to_camera).cast<float>(), 1e-3f)) continue;
      if (occluder.Occluded(p, (back * to_laser).cast<float>(), 1e-3f)) continue;
      return true;
    }
  }
  return false;
}

// One bit per sample: scannable in `pose`.
std::vector<uint64_t> ScannableBits(const Occluder& occluder, const ScanRig& s, const Eigen::Isometry3d& pose,
                                    double clearance_mm, double max_incidence_deg,
                                    const std::vector<Sample>& samples, int threads) {
  const double min_cos = std::cos(max_incidence_deg * 3.14159265358979323846 / 180.0);
  const double pi = 3.14159265358979323846;
  const std::array<Eigen::Isometry3d, 3> cam_from_table = {s.rig.WorldFromCamAtAngle(0).inverse(),
                                                           s.rig.WorldFromCamAtAngle(pi / 2).inverse(),
                                                           s.rig.WorldFromCamAtAngle(pi).inverse()};
  std::vector<uint64_t> bits((samples.size() + 63) / 64, 0);
  const size_t words = bits.size();
  ParallelFor(words, threads, [&](size_t begin, size_t end) {
    for (size_t w = begin; w < end; ++w) {
      uint64_t word = 0;
      for (size_t i = 64 * w; i < std::min(samples.size(), 64 * w + 64); ++i) {
        if (Scannable(occluder, s, cam_from_table, pose, clearance_mm, min_cos, samples[i]))
          word |= uint64_t{1} << (i % 64);
      }
      bits[w] = word;
    }
  });
  return bits;
}

size_t CountUnion(const std::vector<uint64_t>& a, const std::vector<uint64_t>& b) {
  size_t n = 0;
  for (size_t w = 0; w < a.size(); ++w) n += static_cast<size_t>(__builtin_popcountll(a[w] | b[w]));
  return n;
}

bool Bit(const std::vector<uint64_t>& bits, size_t i) {
  return ((bits[i / 64] >> (i % 64)) & 1) != 0;
}

}  // namespace

Result<ReachReport> EvaluateReach(const cloud::PointCloud& cloud, const TruthSurface& truth,
                                  const EvaluationViews& views, const ScanRig& rig,
                                  const EvaluateOptions& options, const ReachOptions& reach,
                                  Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  const bundle::TruthMesh& mesh = truth.mesh;
  if (cloud.empty()) return InvalidArgumentError("the cloud has no points");
  if (mesh.faces.empty()) return InvalidArgumentError("the true mesh has no faces");
  if (reach.orientations < 0 || reach.orientations > 100000)
    return InvalidArgumentError("reach orientations must be in [0, 100000]");
  if (!(reach.max_incidence_deg > 0 && reach.max_incidence_deg <= 90))
    return InvalidArgumentError("reach max incidence must be in (0, 90] degrees");
  if (!(reach.search_spacing_mm >= options.sample_spacing_mm) || !(reach.region_link_mm > 0))
    return InvalidArgumentError("reach search spacing must be >= the sample spacing, the region link > 0");
  ROTOSCAN_RETURN_IF_ERROR(rig.rig.Validate());
  const int threads = ThreadCount(options.threads);
  ReachReport report;
  std::vector<bool> present(256, false);
  for (const cloud::CloudPoint& p : cloud.points) present[p.placement] = true;
  for (int k = 0; k < 256; ++k) {
    if (!present[static_cast<size_t>(k)]) continue;
    if (static_cast<size_t>(k) >= rig.placement_rotation.size())
      return InvalidArgumentError("the cloud has points of placement " + std::to_string(k) +
                                  ", which the scene does not define");
    report.placements.push_back(k);
  }
  Occluder occluder;
  ROTOSCAN_RETURN_IF_ERROR(occluder.Build(mesh));
  CoverageStats cov;
  AutomaticRadius(cloud, mesh, views, options, &cov);
  report.radius_mm = cov.radius_mm;

  // The search: every pose at the coarse spacing.
  EvaluateOptions coarse = options;
  coarse.sample_spacing_mm = reach.search_spacing_mm;
  size_t unused = 0;
  double area_per_sample = 0;
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<Sample> few, SampleSurface(mesh, coarse, &unused, &area_per_sample));
  std::vector<Eigen::Vector3d> ups = SphereDirections(reach.orientations);
  std::vector<Eigen::Vector3d> given_ups;
  for (int k : report.placements)
    given_ups.push_back(rig.placement_rotation[static_cast<size_t>(k)].transpose() *
                        Eigen::Vector3d::UnitZ());
  std::vector<std::vector<uint64_t>> bits;
  {
    ProgressScope scope(progress, "reach: poses", ups.size() + given_ups.size());
    for (const Eigen::Vector3d& up : given_ups) {
      bits.push_back(ScannableBits(occluder, rig, StandOnTable(mesh, RotationUp(up)),
                                   options.table_clearance_mm, reach.max_incidence_deg, few, threads));
      scope.Advance();
    }
    for (const Eigen::Vector3d& up : ups) {
      if (scope.Cancelled()) return CancelledError("evaluation cancelled");
      bits.push_back(ScannableBits(occluder, rig, StandOnTable(mesh, RotationUp(up)),
                                   options.table_clearance_mm, reach.max_incidence_deg, few, threads));
      scope.Advance();
    }
  }
  std::vector<Eigen::Vector3d> all_ups = given_ups;
  all_ups.insert(all_ups.end(), ups.begin(), ups.end());
  size_t best_second = 0, best_a = 0, best_b = 0, best_pair = 0;
  for (size_t j = 0; j < all_ups.size(); ++j) {
    const size_t n = CountUnion(bits[0], bits[j]);
    if (n > best_second) best_second = n, report.best_second_up = all_ups[j];
    for (size_t i = 0; i <= j; ++i) {
      const size_t m = CountUnion(bits[i], bits[j]);
      if (m > best_pair) best_pair = m, best_a = i, best_b = j;
    }
  }
  report.best_pair_up[0] = all_ups[best_a];
  report.best_pair_up[1] = all_ups[best_b];
  std::vector<uint64_t> any(bits[0].size(), 0);
  for (const auto& b : bits)
    for (size_t w = 0; w < any.size(); ++w) any[w] |= b[w];

  // The figures at full resolution: the given placements, the best poses, coverage by class.
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<Sample> samples,
                            SampleSurface(mesh, options, &unused, &area_per_sample));
  report.samples = samples.size();
  report.area_mm2 = static_cast<double>(samples.size()) * area_per_sample;
  if (samples.empty()) return report;
  const double n = static_cast<double>(samples.size());
  auto bits_at = [&](const Eigen::Vector3d& up) {
    return ScannableBits(occluder, rig, StandOnTable(mesh, RotationUp(up)), options.table_clearance_mm,
                         reach.max_incidence_deg, samples, threads);
  };
  std::vector<uint64_t> given(((samples.size() + 63) / 64), 0);
  std::vector<uint64_t> first;
  for (size_t k = 0; k < given_ups.size(); ++k) {
    std::vector<uint64_t> b = bits_at(given_ups[k]);
    if (k == 0) first = b;
    report.scannable_placement.push_back(static_cast<double>(CountUnion(b, b)) / n);
    for (size_t w = 0; w < given.size(); ++w) given[w] |= b[w];
  }
  report.best_second = static_cast<double>(CountUnion(first, bits_at(report.best_second_up))) / n;
  report.best_pair =
      static_cast<double>(CountUnion(bits_at(report.best_pair_up[0]), bits_at(report.best_pair_up[1]))) / n;
  // "Some pose" at full resolution: scannable in a given placement, or in a pose that scans that area at the
  // search's resolution (the nearest coarse sample).
  const PointGrid grid(cloud, cov.radius_mm);
  cloud::PointCloud coarse_cloud;
  for (const Sample& f : few) {
    cloud::CloudPoint p;
    p.position_in_table = f.point;
    coarse_cloud.points.push_back(p);
  }
  const double link = 2.0 * reach.search_spacing_mm;
  const PointGrid coarse_grid(coarse_cloud, link);
  size_t covered = 0, scannable = 0, covered_scannable = 0, covered_not = 0, scannable_any = 0;
  cloud::PointCloud lost;
  for (size_t i = 0; i < samples.size(); ++i) {
    const bool is_covered = (grid.Near(samples[i].point, cov.radius_mm) & 4) != 0;
    const bool in_given = Bit(given, i);
    // The nearest coarse sample decides "some pose" (within the link; none: not scannable).
    size_t nearest = few.size();
    float best = std::numeric_limits<float>::infinity();
    coarse_grid.ForEachIndexNear(samples[i].point, [&](uint32_t j) {
      const float d = (few[j].point - samples[i].point).squaredNorm();
      if (d < best) best = d, nearest = j;
    });
    const bool in_any = in_given || (nearest < few.size() && Bit(any, nearest));
    covered += is_covered;
    scannable += in_given;
    covered_scannable += is_covered && in_given;
    covered_not += is_covered && !in_given;
    scannable_any += in_any;
    if (is_covered) continue;
    report.uncovered.push_back(samples[i].point);
    report.uncovered_normal.push_back(samples[i].normal);
    report.uncovered_class.push_back(in_given ? 0 : in_any ? 1 : 2);
    cloud::CloudPoint p;
    p.position_in_table = samples[i].point;
    lost.points.push_back(p);
  }
  report.covered = static_cast<double>(covered) / n;
  report.scannable_given = static_cast<double>(scannable) / n;
  report.covered_of_scannable_given = scannable > 0 ? static_cast<double>(covered_scannable) / scannable : 0;
  report.covered_not_scannable = static_cast<double>(covered_not) / n;
  report.scannable_any = static_cast<double>(scannable_any) / n;

  // Regions: uncovered samples linked within region_link_mm (union-find).
  std::vector<uint32_t> parent(lost.size());
  std::iota(parent.begin(), parent.end(), uint32_t{0});
  auto root = [&](uint32_t i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  const PointGrid lost_grid(lost, reach.region_link_mm);
  const float link2 = static_cast<float>(reach.region_link_mm * reach.region_link_mm);
  for (uint32_t i = 0; i < lost.size(); ++i) {
    lost_grid.ForEachIndexNear(lost.points[i].position_in_table, [&](uint32_t j) {
      if (j <= i) return;
      if ((lost.points[i].position_in_table - lost.points[j].position_in_table).squaredNorm() > link2) return;
      parent[root(j)] = root(i);
    });
  }
  std::unordered_map<uint32_t, UncoveredRegion> by_root;
  std::unordered_map<uint32_t, size_t> counts;
  for (uint32_t i = 0; i < lost.size(); ++i) {
    const uint32_t r = root(i);
    UncoveredRegion& g = by_root[r];
    const Eigen::Vector3d p = lost.points[i].position_in_table.cast<double>();
    if (counts[r]++ == 0) g.lo = g.hi = p;
    g.lo = g.lo.cwiseMin(p);
    g.hi = g.hi.cwiseMax(p);
    g.centroid += p;
    g.scannable_given += report.uncovered_class[i] == 0;
    g.scannable_any += report.uncovered_class[i] <= 1;
  }
  for (auto& [r, g] : by_root) {
    const double c = static_cast<double>(counts[r]);
    g.centroid /= c;
    g.scannable_given /= c;
    g.scannable_any /= c;
    g.area_mm2 = c * area_per_sample;
    report.regions.push_back(g);
  }
  std::sort(report.regions.begin(), report.regions.end(),
            [](const UncoveredRegion& a, const UncoveredRegion& b) { return a.area_mm2 > b.area_mm2; });
  if (report.regions.size() > reach.max_regions) report.regions.resize(reach.max_regions);
  return report;
}

std::string ReachSummary(const ReachReport& r) {
  std::string out;
  char line[400];
  std::snprintf(
      line, sizeof(line),
      "reach (%zu samples, %.0f mm^2, radius %.2f mm): covered %.4f; scannable in the cloud's placements "
      "%.4f (covered %.4f of it; covered but not scannable %.4f); scannable in some pose %.4f\n",
      r.samples, r.area_mm2, r.radius_mm, r.covered, r.scannable_given, r.covered_of_scannable_given,
      r.covered_not_scannable, r.scannable_any);
  out += line;
  for (size_t k = 0; k < r.placements.size(); ++k) {
    std::snprintf(line, sizeof(line), "reach: placement %d alone: scannable %.4f\n", r.placements[k],
                  r.scannable_placement[k]);
    out += line;
  }
  std::snprintf(
      line, sizeof(line),
      "reach: best second pose after placement %d: up (%.3f %.3f %.3f) of the truth frame, scannable "
      "%.4f; best pair of poses: up (%.3f %.3f %.3f) and (%.3f %.3f %.3f), scannable %.4f\n",
      r.placements.empty() ? 0 : r.placements[0], r.best_second_up.x(), r.best_second_up.y(),
      r.best_second_up.z(), r.best_second, r.best_pair_up[0].x(), r.best_pair_up[0].y(),
      r.best_pair_up[0].z(), r.best_pair_up[1].x(), r.best_pair_up[1].y(), r.best_pair_up[1].z(),
      r.best_pair);
  out += line;
  for (const UncoveredRegion& g : r.regions) {
    std::snprintf(
        line, sizeof(line),
        "uncovered region: %.1f mm^2 (%.2f %% of the surface) around (%.1f %.1f %.1f) mm, box (%.1f "
        "%.1f %.1f)-(%.1f %.1f %.1f): scannable in the cloud's placements %.2f, in some pose %.2f\n",
        g.area_mm2, 100.0 * g.area_mm2 / std::max(1e-9, r.area_mm2), g.centroid.x(), g.centroid.y(),
        g.centroid.z(), g.lo.x(), g.lo.y(), g.lo.z(), g.hi.x(), g.hi.y(), g.hi.z(), g.scannable_given,
        g.scannable_any);
    out += line;
  }
  return out;
}

}  // namespace rotoscan::pipeline
