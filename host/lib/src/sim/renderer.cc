#include "rotoscan/sim/renderer.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "mesh.h"
#include "rotoscan/core/check.h"

namespace rotoscan::sim {

using internal::Mesh;

uint64_t FrameSeed(uint64_t scene_seed, int pose, int step, int frame) {
  auto mix = [](uint64_t z) {
    z += 0x9e3779b97f4a7c15ULL;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
  };
  uint64_t h = mix(scene_seed);
  h = mix(h ^ static_cast<uint64_t>(static_cast<uint32_t>(pose)));
  h = mix(h ^ static_cast<uint64_t>(static_cast<uint32_t>(step)));
  return mix(h ^ static_cast<uint64_t>(frame));
}

constexpr int kScatterSpacing = 8;  // px between the nodes of the interreflection grid

struct Renderer::Impl {
  RTCDevice device = nullptr;
  RTCScene rtc_scene = nullptr;
  std::vector<Mesh> meshes;  // 0: table top
  // Camera ray (z = 1) through pixel centres on a grid with a one-pixel border: (width + 2) x (height + 2).
  std::shared_ptr<const std::vector<Eigen::Vector3f>> ray_grid;  // shared by renderers of one camera
  const std::vector<Eigen::Vector3f>& rays() const { return *ray_grid; }
  int grid_width = 0;

  ~Impl() {
    if (rtc_scene != nullptr) rtcReleaseScene(rtc_scene);
    if (device != nullptr) rtcReleaseDevice(device);
  }

  // Ray direction (camera frame, z = 1) at continuous pixel position (x, y), bilinear between centres.
  Eigen::Vector3f RayAt(float x, float y) const {
    const float gx = x + 1, gy = y + 1;
    const std::vector<Eigen::Vector3f>& rays = *ray_grid;
    const int grid_height = static_cast<int>(rays.size()) / grid_width;
    const int x0 = std::clamp(static_cast<int>(std::floor(gx)), 0, grid_width - 2);
    const int y0 = std::clamp(static_cast<int>(std::floor(gy)), 0, grid_height - 2);
    const float fx = gx - x0, fy = gy - y0;
    auto at = [&](int yy, int xx) -> const Eigen::Vector3f& { return rays[yy * grid_width + xx]; };
    if (fx == 0.0f && fy == 0.0f) return at(y0, x0);
    return (1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x0 + 1)) +
           fy * ((1 - fx) * at(y0 + 1, x0) + fx * at(y0 + 1, x0 + 1));
  }
  // The same at the centre of pixel (x, y) (0 <= x < width, 0 <= y < height): a node of the grid.
  const Eigen::Vector3f& RayAtCentre(int x, int y) const {
    return (*ray_grid)[(y + 1) * grid_width + (x + 1)];
  }

  // One diffuse bounce of a laser's line (renderer.h, "Interreflection"), on the grid of camera pixels
  // every kScatterSpacing px.
  struct ScatterGrid {
    int spacing = 0, cols = 0, rows = 0;
    std::vector<float> irradiance;  // per node, renderer units (multiplied by the albedo when shaded)
    std::vector<unsigned> geom;     // the mesh each node's camera ray hits (RTC_INVALID_GEOMETRY_ID: none)
    // Bilinear at pixel (x, y) over the four surrounding nodes on the same mesh `geom_id` (0 when none
    // is): the bounce does not leak across an object's silhouette.
    float At(float x, float y, unsigned geom_id) const;
  };
  ScatterGrid Scatter(const Scene& sc, int laser, const Eigen::Isometry3d& table_from_cam,
                      const Eigen::Vector3d& laser_origin, const Eigen::Vector3d& laser_normal,
                      double threshold) const;

  // True when something lies on the segment from `from` towards `to` (table frame), excluding `gap` mm
  // at each end.
  bool Occluded(const Eigen::Vector3d& from, const Eigen::Vector3d& to, double gap) const {
    const Eigen::Vector3d d = to - from;
    const double length = d.norm();
    if (length <= 2 * gap) return false;
    RTCRay ray;
    ray.org_x = static_cast<float>(from.x());
    ray.org_y = static_cast<float>(from.y());
    ray.org_z = static_cast<float>(from.z());
    ray.dir_x = static_cast<float>(d.x() / length);
    ray.dir_y = static_cast<float>(d.y() / length);
    ray.dir_z = static_cast<float>(d.z() / length);
    ray.tnear = static_cast<float>(gap);
    ray.tfar = static_cast<float>(length - gap);
    ray.mask = 0xFFFFFFFF;
    ray.time = 0.0f;
    ray.flags = 0;
    ray.id = 0;
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    rtcOccluded1(rtc_scene, &context, &ray);
    return ray.tfar < 0.0f;
  }
};

namespace {

// Camera rays (z = 1) through the pixel centres with a one-pixel border, (width + 2) x (height + 2). The
// inverse lens model is iterative and this grid takes about a second at 1288x964, so renderers of the
// same camera (one per board pose in a calibration bundle) share it.
std::shared_ptr<const std::vector<Eigen::Vector3f>> RayGrid(const geometry::CameraModel& camera) {
  static std::mutex mutex;
  static std::weak_ptr<const std::vector<Eigen::Vector3f>> last;
  static geometry::CameraModel last_camera;
  std::lock_guard<std::mutex> lock(mutex);
  const bool same = camera.width == last_camera.width && camera.height == last_camera.height &&
                    camera.Intrinsics() == last_camera.Intrinsics() &&
                    camera.distortion == last_camera.distortion;
  if (auto cached = last.lock(); cached && same) return cached;
  const int grid_width = camera.width + 2;
  auto grid = std::make_shared<std::vector<Eigen::Vector3f>>(static_cast<std::size_t>(grid_width) *
                                                             (camera.height + 2));
  for (int y = -1; y <= camera.height; ++y) {
    for (int x = -1; x <= camera.width; ++x) {
      (*grid)[(y + 1) * grid_width + (x + 1)] = camera.PixelToRay(Eigen::Vector2d(x, y)).cast<float>();
    }
  }
  last = grid;
  last_camera = camera;
  return grid;
}

}  // namespace

float Renderer::Impl::ScatterGrid::At(float x, float y, unsigned geom_id) const {
  const float gx = x / static_cast<float>(spacing), gy = y / static_cast<float>(spacing);
  const int i0 = std::clamp(static_cast<int>(std::floor(gx)), 0, cols - 2);
  const int j0 = std::clamp(static_cast<int>(std::floor(gy)), 0, rows - 2);
  const float fx = std::clamp(gx - static_cast<float>(i0), 0.0f, 1.0f);
  const float fy = std::clamp(gy - static_cast<float>(j0), 0.0f, 1.0f);
  float sum = 0.0f, weights = 0.0f;
  for (int dj = 0; dj < 2; ++dj) {
    for (int di = 0; di < 2; ++di) {
      const std::size_t node = static_cast<std::size_t>(j0 + dj) * cols + (i0 + di);
      if (geom[node] != geom_id) continue;
      const float w = (di != 0 ? fx : 1.0f - fx) * (dj != 0 ? fy : 1.0f - fy);
      sum += w * irradiance[node];
      weights += w;
    }
  }
  return weights > 0.0f ? sum / weights : 0.0f;
}

Renderer::Impl::ScatterGrid Renderer::Impl::Scatter(const Scene& sc, int k, const Eigen::Isometry3d& table_from_cam,
                                                    const Eigen::Vector3d& laser_origin,
                                                    const Eigen::Vector3d& laser_normal, double threshold) const {
  constexpr double kPi = 3.14159265358979323846;
  constexpr int kEmitters = 1024;                 // rays of the fan
  constexpr double kHalfFan = 40.0 * kPi / 180;  // +-40 deg about the ray to the axis 40 mm above the table
  constexpr double kMinDistanceMm = 2.0;          // nearer pairs skipped: the primary line covers them
  const LaserModel& laser = sc.laser[k];
  const geometry::CameraModel& camera = sc.rig.camera;
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  auto intersect = [&](const Eigen::Vector3d& from, const Eigen::Vector3d& dir, RTCRayHit* rh) {
    rh->ray.org_x = static_cast<float>(from.x());
    rh->ray.org_y = static_cast<float>(from.y());
    rh->ray.org_z = static_cast<float>(from.z());
    rh->ray.dir_x = static_cast<float>(dir.x());
    rh->ray.dir_y = static_cast<float>(dir.y());
    rh->ray.dir_z = static_cast<float>(dir.z());
    rh->ray.tnear = 1.0f;
    rh->ray.tfar = std::numeric_limits<float>::infinity();
    rh->ray.mask = 0xFFFFFFFF;
    rh->ray.time = 0.0f;
    rh->ray.flags = 0;
    rh->ray.id = 0;
    rh->hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh->hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(rtc_scene, &context, rh);
    return rh->hit.geomID != RTC_INVALID_GEOMETRY_ID;
  };
  // The emitters: where a fan of rays in the laser plane first meets the scene. Each ray of angular width
  // d_theta carries the flux power * 300 * sqrt(2 pi) sigma * d_theta (the renderer's fan: radiance
  // power * G(s) * 300 / range over a cross-section range * d_theta by the Gaussian's thickness), whatever
  // the surface's slant; the surface reflects its red albedo's share of it, Lambertian.
  struct Emitter {
    Eigen::Vector3d p, n;
    double flux;
  };
  std::vector<Emitter> emitters;
  Eigen::Vector3d ahead = Eigen::Vector3d(0, 0, 40) - laser_origin;
  ahead -= laser_normal.dot(ahead) * laser_normal;
  ahead.normalize();
  const Eigen::Vector3d across = laser_normal.cross(ahead);
  const double d_theta = 2.0 * kHalfFan / kEmitters;
  const double ray_flux = laser.power * 300.0 * std::sqrt(2.0 * kPi) * laser.sigma_mm * d_theta;
  for (int i = 0; i < kEmitters; ++i) {
    const double theta = -kHalfFan + (i + 0.5) * d_theta;
    const Eigen::Vector3d dir = std::cos(theta) * ahead + std::sin(theta) * across;
    RTCRayHit rh;
    if (!intersect(laser_origin, dir, &rh)) continue;
    Eigen::Vector3d n(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
    n.normalize();
    if (n.dot(dir) > 0) n = -n;  // the lit side
    const Eigen::Vector3d p = laser_origin + static_cast<double>(rh.ray.tfar) * dir;
    const double albedo = meshes[rh.hit.geomID].Albedo(rh.hit.primID, rh.hit.u, rh.hit.v, p)[0];
    if (albedo > 0) emitters.push_back({p, n, ray_flux * albedo});
  }
  // The receivers: the first camera hit at every node; E = sum flux cos_e cos_r / (pi d^2) over the
  // emitters that see the node (one occlusion ray per pair, only at nodes whose unoccluded sum, times
  // their albedo, reaches `threshold`; below it the node gets nothing).
  ScatterGrid grid;
  grid.spacing = kScatterSpacing;
  grid.cols = (camera.width - 1) / kScatterSpacing + 2;
  grid.rows = (camera.height - 1) / kScatterSpacing + 2;
  grid.irradiance.assign(static_cast<std::size_t>(grid.cols) * grid.rows, 0.0f);
  grid.geom.assign(grid.irradiance.size(), RTC_INVALID_GEOMETRY_ID);
  const Eigen::Vector3d cam_centre = table_from_cam.translation();
  const Eigen::Matrix3d rotation = table_from_cam.linear();
  std::vector<std::pair<int, double>> seen;
  for (int j = 0; j < grid.rows; ++j) {
    for (int i = 0; i < grid.cols; ++i) {
      const int x = std::min(i * kScatterSpacing, camera.width - 1), y = std::min(j * kScatterSpacing, camera.height - 1);
      const Eigen::Vector3d dir = rotation * RayAtCentre(x, y).cast<double>();
      RTCRayHit rh;
      if (!intersect(cam_centre, dir, &rh)) continue;
      const std::size_t node = static_cast<std::size_t>(j) * grid.cols + i;
      grid.geom[node] = rh.hit.geomID;
      Eigen::Vector3d n(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
      n.normalize();
      if (n.dot(dir) > 0) n = -n;  // towards the camera
      const Eigen::Vector3d q = cam_centre + static_cast<double>(rh.ray.tfar) * dir;
      seen.clear();
      double total = 0;
      for (std::size_t e = 0; e < emitters.size(); ++e) {
        const Eigen::Vector3d v = emitters[e].p - q;
        const double d2 = v.squaredNorm();
        if (d2 < kMinDistanceMm * kMinDistanceMm) continue;
        const double cos_r = n.dot(v), cos_e = -emitters[e].n.dot(v);  // both times d
        if (cos_r <= 0 || cos_e <= 0) continue;
        const double contribution = emitters[e].flux * cos_r * cos_e / (kPi * d2 * d2);
        seen.emplace_back(static_cast<int>(e), contribution);
        total += contribution;
      }
      const double albedo = meshes[rh.hit.geomID].Albedo(rh.hit.primID, rh.hit.u, rh.hit.v, q)[0];
      if (total * albedo < threshold) continue;
      double visible = 0;
      for (const auto& [e, contribution] : seen) {
        if (!Occluded(q, emitters[static_cast<std::size_t>(e)].p, 1e-2)) visible += contribution;
      }
      grid.irradiance[node] = static_cast<float>(visible);
    }
  }
  return grid;
}

Renderer::Renderer(const Scene& scene, std::unique_ptr<Impl> impl) : scene_(scene), impl_(std::move(impl)) {}
Renderer::~Renderer() = default;

Result<std::unique_ptr<Renderer>> Renderer::Create(const Scene& scene) {
  ROTOSCAN_RETURN_IF_ERROR(scene.rig.Validate().WithContext("scene rig"));
  // NaN rays abort Embree.
  ROTOSCAN_RETURN_IF_ERROR(scene.rig.camera.CheckInvertible().WithContext("scene camera"));
  auto impl = std::make_unique<Impl>();
  impl->meshes.push_back(internal::MakeTableTop(scene.table_radius_mm, scene.table_albedo));
  for (std::size_t i = 0; i < scene.objects.size(); ++i) {
    auto mesh = internal::MakeObject(scene.objects[i], scene);
    if (!mesh.ok()) return mesh.status().WithContext("objects[" + std::to_string(i) + "]");
    impl->meshes.push_back(std::move(mesh).value());
  }
  impl->device = rtcNewDevice("threads=1");
  if (impl->device == nullptr) return InternalError("Embree device could not be created");
  impl->rtc_scene = rtcNewScene(impl->device);
  rtcSetSceneBuildQuality(impl->rtc_scene, RTC_BUILD_QUALITY_HIGH);
  for (std::size_t i = 0; i < impl->meshes.size(); ++i) {
    const Mesh& m = impl->meshes[i];
    RTCGeometry geometry = rtcNewGeometry(impl->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(
        geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), m.vertices.size()));
    auto* indices = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
        geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), m.faces.size()));
    if (vertices == nullptr || indices == nullptr) {
      rtcReleaseGeometry(geometry);
      return InternalError("Embree buffers could not be allocated");
    }
    for (std::size_t v = 0; v < m.vertices.size(); ++v) {
      for (int k = 0; k < 3; ++k) vertices[3 * v + k] = m.vertices[v][k];
    }
    for (std::size_t f = 0; f < m.faces.size(); ++f) {
      for (int k = 0; k < 3; ++k) indices[3 * f + k] = static_cast<unsigned>(m.faces[f][k]);
    }
    rtcCommitGeometry(geometry);
    rtcAttachGeometryByID(impl->rtc_scene, geometry, static_cast<unsigned>(i));
    rtcReleaseGeometry(geometry);
  }
  rtcCommitScene(impl->rtc_scene);
  if (rtcGetDeviceError(impl->device) != RTC_ERROR_NONE) return InternalError("Embree scene build failed");

  const geometry::CameraModel& camera = scene.rig.camera;
  impl->grid_width = camera.width + 2;
  impl->ray_grid = RayGrid(camera);
  return std::unique_ptr<Renderer>(new Renderer(scene, std::move(impl)));
}

std::size_t Renderer::TriangleCount() const {
  std::size_t n = 0;
  for (const Mesh& m : impl_->meshes) n += m.faces.size();
  return n;
}

Eigen::Isometry3d Renderer::TableFromObject(std::size_t i) const {
  ROTOSCAN_CHECK(i + 1 < impl_->meshes.size());
  return impl_->meshes[i + 1].table_from_object;
}

bundle::TruthMesh Renderer::ObjectMesh() const {
  bundle::TruthMesh out;
  for (std::size_t i = 1; i < impl_->meshes.size(); ++i) {
    const Mesh& m = impl_->meshes[i];
    const int base = static_cast<int>(out.vertices.size());
    out.vertices.insert(out.vertices.end(), m.vertices.begin(), m.vertices.end());
    std::vector<Eigen::Vector3f> colors(m.vertices.size(), m.color);
    if (!m.colors.empty()) colors = m.colors;
    for (std::size_t f = 0; f < m.faces.size(); ++f) {
      out.faces.push_back(m.faces[f] + Eigen::Vector3i::Constant(base));
      if (!m.texture.empty() && !m.uv.empty()) {
        for (int k = 0; k < 3; ++k) {
          const float u = k == 1 ? 1.f : 0.f, v = k == 2 ? 1.f : 0.f;
          colors[m.faces[f][k]] = m.Albedo(static_cast<unsigned>(f), u, v, Eigen::Vector3d::Zero());
        }
      }
    }
    for (const Eigen::Vector3f& c : colors) {
      out.colors.push_back({static_cast<uint8_t>(std::clamp(c.x(), 0.f, 1.f) * 255.f + 0.5f),
                            static_cast<uint8_t>(std::clamp(c.y(), 0.f, 1.f) * 255.f + 0.5f),
                            static_cast<uint8_t>(std::clamp(c.z(), 0.f, 1.f) * 255.f + 0.5f)});
    }
  }
  return out;
}

namespace {

// Standard normal deviates for the shot/read noise and the speckle. cv::RNG's fill took ~55 instructions
// per deviate, which made the noise of one frame (3.7 M deviates) cost as much as its ray casting; these
// take ~25 and no unpredictable branch (a branch on the random sign alone cost ~15 ms per frame). A
// deviate is a function of (stream key, index) alone: 32 bits from a SplitMix64 hash of the index (two
// deviates per hash), the low bit the sign and the other 31 a two-sided tail probability w, uniform on
// [2^-32, 1] (the midpoints of 2^31 equal cells), then |z| = Φ⁻¹(1 - w/2) from a table. The table is
// indexed by w's float exponent and top 6 mantissa bits (64 bins per octave over 32 octaves: the tails
// get as fine bins as the centre) and interpolates linearly in w inside a bin; the interpolation error is
// below 1e-5 everywhere and |z| reaches 6.3 (w = 2^-32). Deterministic for a key, independent of thread
// and block size.
class NormalTable {
 public:
  static const NormalTable& Get() {
    static const NormalTable table;
    return table;
  }

  float operator()(uint32_t bits) const {
    const float w = static_cast<float>(static_cast<int32_t>(bits >> 1)) * 0x1p-31f + 0x1p-32f;
    uint32_t w_bits;
    std::memcpy(&w_bits, &w, sizeof w_bits);
    const uint32_t bin = (w_bits >> 17) - (kLowestExponent << 6);  // exponent and 6 mantissa bits
    const float z = intercept_[bin] + slope_[bin] * w;
    // The sign from the low bit, without a branch (it would be mispredicted half the time).
    uint32_t z_bits;
    std::memcpy(&z_bits, &z, sizeof z_bits);
    z_bits ^= bits << 31;
    float signed_z;
    std::memcpy(&signed_z, &z_bits, sizeof signed_z);
    return signed_z;
  }

 private:
  static constexpr uint32_t kLowestExponent = 127 - 32;  // biased float exponent of 2^-32
  static constexpr int kBins = 32 * 64 + 1;              // the last bin is w = 1 alone (z = 0)

  NormalTable() {
    // |z| for a two-sided tail probability w: sqrt(2) erfc⁻¹(w), by bisection on erfc (exact to double).
    auto inverse = [](double w) {
      double lo = 0.0, hi = 10.0;  // erfc(10) = 2e-45
      for (int it = 0; it < 100; ++it) {
        const double mid = 0.5 * (lo + hi);
        (std::erfc(mid) > w ? lo : hi) = mid;
      }
      return std::sqrt(2.0) * 0.5 * (lo + hi);
    };
    auto bin_start = [](int bin) {
      return std::ldexp(1.0 + (bin % 64) / 64.0, static_cast<int>(kLowestExponent) - 127 + bin / 64);
    };
    double w0 = bin_start(0), z0 = inverse(w0);
    for (int bin = 0; bin + 1 < kBins; ++bin) {
      const double w1 = bin_start(bin + 1), z1 = inverse(w1);
      const double slope = (z1 - z0) / (w1 - w0);
      slope_[bin] = static_cast<float>(slope);
      intercept_[bin] = static_cast<float>(z0 - slope * w0);
      w0 = w1;
      z0 = z1;
    }
    slope_[kBins - 1] = 0.0f;
    intercept_[kBins - 1] = 0.0f;
  }

  std::array<float, kBins> intercept_{}, slope_{};
};

uint64_t Mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

// Deviates number first .. first + count - 1 of the stream `key` (first even) into out.
void FillNormal(uint64_t key, uint64_t first, float* out, int count) {
  const NormalTable& table = NormalTable::Get();
  const uint64_t base = Mix64(key);
  for (int i = 0; i < count; i += 2) {
    const uint64_t h = Mix64(base + ((first + static_cast<uint64_t>(i)) >> 1) * 0x9e3779b97f4a7c15ULL);
    out[i] = table(static_cast<uint32_t>(h));
    if (i + 1 < count) out[i + 1] = table(static_cast<uint32_t>(h >> 32));
  }
}

// The sensor model of scene.h on `scale` * `electrons` (CV_32FC3, BGR, mean electrons per pixel; the scale
// is applied here to save a pass over the image), which is used as scratch space and left undefined. The
// noise is added block by block (the inner loops have a fixed trip count and vectorise); sqrt needs no errno
// there, hence -fno-math-errno on this file.
cv::Mat SensorResponse(const SensorModel& s, cv::Mat& electrons, float scale, uint64_t seed,
                       cv::Mat& raw_scratch) {
  ROTOSCAN_CHECK(electrons.type() == CV_32FC3 && electrons.isContinuous());
  const int rows = electrons.rows, cols = electrons.cols;
  cv::Mat raw;  // electrons, 1 or 3 channels
  if (s.bayer) {
    // RGGB: R at (even row, even col), B at (odd, odd); BGR memory order.
    raw_scratch.create(rows, cols, CV_32FC1);
    raw = raw_scratch;
    for (int y = 0; y < rows; ++y) {
      const cv::Vec3f* in = electrons.ptr<cv::Vec3f>(y);
      float* out = raw.ptr<float>(y);
      const int first = (y % 2 == 0) ? 2 : 1, second = (y % 2 == 0) ? 1 : 0;
      for (int x = 0; x + 1 < cols; x += 2) {
        out[x] = in[x][first];
        out[x + 1] = in[x + 1][second];
      }
      if (cols % 2 == 1) out[cols - 1] = in[cols - 1][first];
    }
  } else {
    raw = electrons;
  }
  const int n = static_cast<int>(raw.total()) * raw.channels();  // both are continuous
  float* e = raw.ptr<float>();
  // Saturation at the full well (and at the top code), gain, rounding, clipping at 0: convertTo rounds
  // to nearest and saturates, so clipping the electrons at min(full well, top code / gain) first is enough.
  const float k = static_cast<float>(s.DnPerElectron());
  const float ceiling = std::min(static_cast<float>(s.full_well_e), static_cast<float>(s.MaxDn()) / k);
  if (s.noise) {
    // Shot noise (Poisson as a Gaussian of variance = mean) plus read noise, then the ceiling.
    const float read2 = static_cast<float>(s.read_noise_e * s.read_noise_e);
    constexpr int kBlock = 512;
    alignas(32) float g[kBlock];
    int i = 0;
    for (; i + kBlock <= n; i += kBlock) {
      FillNormal(seed, static_cast<uint64_t>(i), g, kBlock);
      float* b = e + i;
      for (int j = 0; j < kBlock; ++j) {
        const float scaled = scale * b[j];
        const float mean = scaled > 0.0f ? scaled : 0.0f;
        const float v = mean + std::sqrt(mean + read2) * g[j];
        b[j] = v < ceiling ? v : ceiling;
      }
    }
    FillNormal(seed, static_cast<uint64_t>(i), g, n - i);
    for (int j = 0; i + j < n; ++j) {
      const float scaled = scale * e[i + j];
      const float mean = scaled > 0.0f ? scaled : 0.0f;
      const float v = mean + std::sqrt(mean + read2) * g[j];
      e[i + j] = v < ceiling ? v : ceiling;
    }
  } else {
    for (int i = 0; i < n; ++i) e[i] = std::min(scale * e[i], ceiling);
  }
  const int depth = s.bit_depth > 8 ? CV_16U : CV_8U;
  cv::Mat dn;
  raw.convertTo(dn, depth, k);
  cv::Mat color;
  if (s.bayer) {
    // OpenCV names Bayer patterns by the second row: an RGGB sensor is COLOR_BayerBG2BGR.
    cv::cvtColor(dn, color, cv::COLOR_BayerBG2BGR);
  } else {
    color = dn;
  }
  const bool identity_matrix = s.color_matrix == std::array<double, 9>{1, 0, 0, 0, 1, 0, 0, 0, 1};
  if (identity_matrix) return color;
  // The color matrix acts on RGB; in BGR order it is reversed in both indices.
  cv::Matx33f m;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m(2 - i, 2 - j) = static_cast<float>(s.color_matrix[3 * i + j]);
  }
  cv::Mat out;
  cv::transform(color, out, m);  // saturating cast to the same depth
  return out;
}

// Scratch images of one thread, reused from step to step: allocating ~100 MB of fresh pages per step
// (page faults and zeroing) cost more than the ray casting.
struct Workspace {
  cv::Mat ambient, lamp, laser[2], electrons, speckle, raw;
};

// Multiplies the laser image `line` by a speckle field: white Gaussian noise blurred to the speckle size,
// scaled to the laser's speckle contrast, mean 1, clipped at 0. Only the band of columns the line covers
// (plus the blur's reach) gets a field: elsewhere the line is zero and speckle changes nothing, and the
// band is typically a tenth of the image.
void ApplySpeckle(const LaserModel& laser, double pixel_size_um, uint64_t seed, cv::Mat& line, cv::Mat& scratch) {
  int first = line.cols, last = -1;
  for (int y = 0; y < line.rows; ++y) {
    const float* l = line.ptr<float>(y);
    for (int x = 0; x < first; ++x) {
      if (l[x] != 0.0f) {
        first = x;
        break;
      }
    }
    for (int x = line.cols - 1; x > last; --x) {
      if (l[x] != 0.0f) {
        last = x;
        break;
      }
    }
  }
  if (last < first) return;  // no laser in view
  if (laser.f_number > 0) {
    // Fully developed speckle (renderer.h): each pixel the mean of its cells' intensity.
    const int m = SpeckleOversampling(pixel_size_um, laser.wavelength_nm, laser.f_number);
    const int x0 = std::max(0, first - 8), x1 = std::min(line.cols, last + 9);
    const cv::Mat cells =
        SpeckleIntensity(line.rows, x1 - x0, pixel_size_um, laser.wavelength_nm, laser.f_number, m, seed);
    cv::resize(cells, scratch, cv::Size(x1 - x0, line.rows), 0, 0, cv::INTER_AREA);  // m x m box means
    for (int y = 0; y < line.rows; ++y) {
      const float* f = scratch.ptr<float>(y);
      float* l = line.ptr<float>(y) + x0;
      for (int x = 0; x < x1 - x0; ++x) l[x] *= f[x];
    }
    return;
  }
  // The band is widened to at least 64 columns so that the field's standard deviation is well estimated.
  const int reach = static_cast<int>(std::ceil(4.0 * laser.speckle_size_px)) + 32;
  const int x0 = std::max(0, first - reach), x1 = std::min(line.cols, last + 1 + reach);
  const cv::Rect band(x0, 0, x1 - x0, line.rows);
  scratch.create(band.size(), CV_32FC1);
  FillNormal(seed, 0, scratch.ptr<float>(), static_cast<int>(scratch.total()));
  cv::GaussianBlur(scratch, scratch, cv::Size(0, 0), laser.speckle_size_px, laser.speckle_size_px,
                   cv::BORDER_REFLECT);
  cv::Scalar mean, stddev;
  cv::meanStdDev(scratch, mean, stddev);
  const float gain = static_cast<float>(laser.speckle_contrast / std::max(1e-12, stddev[0]));
  for (int y = 0; y < line.rows; ++y) {
    const float* f = scratch.ptr<float>(y);
    float* l = line.ptr<float>(y) + x0;
    for (int x = 0; x < band.width; ++x) {
      const float factor = f[x] * gain + 1.0f;
      l[x] *= factor > 0.0f ? factor : 0.0f;
    }
  }
}

}  // namespace

int SpeckleOversampling(double pixel_size_um, double wavelength_nm, double f_number) {
  ROTOSCAN_CHECK(pixel_size_um > 0 && wavelength_nm > 0 && f_number > 0);
  const double nyquist_um = 0.5 * wavelength_nm * 1e-3 * f_number;
  return std::clamp(static_cast<int>(std::ceil(pixel_size_um / nyquist_um - 1e-9)), 1, 16);
}

cv::Mat SpeckleIntensity(int rows, int cols, double pixel_size_um, double wavelength_nm, double f_number,
                         int oversampling, uint64_t seed) {
  ROTOSCAN_CHECK(rows > 0 && cols > 0 && oversampling >= 1 && pixel_size_um > 0 && wavelength_nm > 0 &&
                 f_number > 0);
  const int h = rows * oversampling, w = cols * oversampling;
  // The DFT grid: at least the image plus a margin of a few grains (the field is periodic on it, so
  // opposite edges would otherwise be correlated), of a size the DFT handles fast.
  const double cell_um = pixel_size_um / oversampling;
  const double lambda_n_um = wavelength_nm * 1e-3 * f_number;
  const int margin = static_cast<int>(std::ceil(4.0 * lambda_n_um / cell_um));
  const int gh = cv::getOptimalDFTSize(h + margin), gw = cv::getOptimalDFTSize(w + margin);
  // The pupil, as the coherent transfer function: spatial frequencies up to 1 / (2 wavelength N) cycles
  // per µm, i.e. gw * cell / (2 wavelength N) bins along x (gh along y). (The incoherent cutoff 1 /
  // (wavelength N) would make grains half as large: SpeckleTest measures the grain against 1.22 lambda N.)
  const double fx = gw * cell_um / (2.0 * lambda_n_um), fy = gh * cell_um / (2.0 * lambda_n_um);
  cv::Mat spectrum(gh, gw, CV_32FC2, cv::Scalar::all(0));
  std::vector<float> deviates(static_cast<size_t>(2 * gw));
  int64_t pupil_bins = 0;
  for (int v = 0; v < gh; ++v) {
    const double ky = (v <= gh / 2 ? v : v - gh) / fy;
    if (std::abs(ky) > 1.0) continue;
    FillNormal(seed, static_cast<uint64_t>(2 * gw) * v, deviates.data(), 2 * gw);
    cv::Vec2f* row = spectrum.ptr<cv::Vec2f>(v);
    for (int u = 0; u < gw; ++u) {
      const double kx = (u <= gw / 2 ? u : u - gw) / fx;
      if (kx * kx + ky * ky <= 1.0) {
        row[u] = cv::Vec2f(deviates[2 * u], deviates[2 * u + 1]);
        ++pupil_bins;
      }
    }
  }
  cv::Mat field;
  cv::dft(spectrum, field, cv::DFT_INVERSE | cv::DFT_COMPLEX_OUTPUT);
  cv::Mat intensity(h, w, CV_32FC1);
  // Mean 1: each pupil bin adds a deviate of E|X|^2 = 2 (unscaled inverse DFT), so E|field|^2 = 2 bins.
  const float inverse_mean = 1.0f / static_cast<float>(2.0 * std::max<int64_t>(pupil_bins, 1));
  for (int y = 0; y < h; ++y) {
    const cv::Vec2f* f = field.ptr<cv::Vec2f>(y);
    float* out = intensity.ptr<float>(y);
    for (int x = 0; x < w; ++x) out[x] = (f[x][0] * f[x][0] + f[x][1] * f[x][1]) * inverse_mean;
  }
  return intensity;
}

cv::Mat Renderer::ApplySensor(const cv::Mat& electrons, uint64_t seed) const {
  ROTOSCAN_CHECK(electrons.type() == CV_32FC3);
  cv::Mat scratch = electrons.clone(), raw;
  return SensorResponse(scene_.sensor, scratch, 1.0f, seed, raw);
}

RenderedStep Renderer::RenderStep(double table_angle, uint64_t seed, const FrameMask& mask) const {
  const Scene& sc = scene_;
  const geometry::CameraModel& camera = sc.rig.camera;
  const int width = camera.width, height = camera.height;
  const int ss = sc.sensor.supersampling;
  const Eigen::Isometry3d table_from_cam = sc.rig.WorldFromCamAtAngle(table_angle);
  const Eigen::Matrix3f rotation = table_from_cam.linear().cast<float>();
  const Eigen::Vector3d cam_centre = table_from_cam.translation();
  const Eigen::Vector3d light = (table_from_cam.linear() * sc.light_direction_in_cam).normalized();
  const bool want_laser[2] = {mask[0], mask[1]};
  const bool lamp_shadows = mask[3] && sc.lamp_shadows;
  constexpr float kLampDistanceMm = 2000.0f;  // the lamp is far (directional light); shadow rays end there
  Eigen::Vector3d laser_origin[2], laser_normal[2];
  double laser_offset[2];
  for (int k = 0; k < 2; ++k) {
    laser_origin[k] = table_from_cam * sc.laser[k].origin_in_cam;
    laser_normal[k] = table_from_cam.linear() * sc.rig.laser_plane[k].normal;
    laser_offset[k] =
        -laser_normal[k].dot(table_from_cam * (-sc.rig.laser_plane[k].offset * sc.rig.laser_plane[k].normal));
  }

  // Interreflection (renderer.h): each laser's bounce on a coarse grid, before the pixels are shaded. A
  // node is skipped where the bounce would add less than a quarter of a DN.
  std::unique_ptr<Impl::ScatterGrid> scatter[2];
  if (sc.laser_interreflection) {
    for (int k = 0; k < 2; ++k) {
      if (!want_laser[k]) continue;
      const double dn_per_unit = sc.sensor.laser_exposure_us * sc.sensor.sensitivity_e_per_us *
                                 std::max(1e-6, sc.laser[k].response.maxCoeff()) * sc.sensor.DnPerElectron();
      scatter[k] = std::make_unique<Impl::ScatterGrid>(
          impl_->Scatter(sc, k, table_from_cam, laser_origin[k], laser_normal[k], 0.25 / dn_per_unit));
    }
  }

  thread_local Workspace ws;
  // Only the images the masked frames use are accumulated: ambient for the laser and off frames, lamp for
  // the natural frame.
  const bool want_ambient = mask[0] || mask[1] || mask[2], want_lamp = mask[3];
  auto zeroed = [&](cv::Mat& m, int type, bool wanted) -> cv::Mat& {
    m.create(height, width, type);
    if (wanted) m.setTo(cv::Scalar::all(0));
    return m;
  };
  cv::Mat& ambient = zeroed(ws.ambient, CV_32FC3, want_ambient);  // albedo * ambient, BGR
  cv::Mat& lamp = zeroed(ws.lamp, CV_32FC3, want_lamp);           // albedo * (ambient + lamp), BGR
  cv::Mat laser_img[2] = {zeroed(ws.laser[0], CV_32FC1, want_laser[0]),
                          zeroed(ws.laser[1], CV_32FC1, want_laser[1])};
  const float weight = 1.0f / static_cast<float>(ss * ss);
  const float ambient_weight = weight * static_cast<float>(sc.ambient);
  const float diffuse_weight = weight * static_cast<float>(sc.diffuse);
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  const Eigen::Vector3f origin = cam_centre.cast<float>();
  const Eigen::Vector3f light_f = light.cast<float>();
  // Per mesh: a uniform albedo needs no lookup per hit (Mesh::Albedo would return `color`).
  std::vector<char> uniform(impl_->meshes.size());
  for (std::size_t i = 0; i < uniform.size(); ++i) uniform[i] = impl_->meshes[i].UniformAlbedo();
  // Camera rays go to Embree in packets of 8, tiles of 4 x 2 sub-samples (coherent, much faster than
  // single rays, and fewer BVH nodes per packet than 8 x 1); each hit is then shaded on its own.
  constexpr int kPacket = 8, kTileWidth = 4;
  const int sample_cols = width * ss, sample_rows = height * ss;
  for (int first_row = 0; first_row < sample_rows; first_row += kPacket / kTileWidth) {
    auto shade = [&](int x, int y, float px, float py, const Eigen::Vector3f& dir, float t,
                     const Eigen::Vector3f& ng, unsigned geom_id, unsigned prim_id, float hit_u, float hit_v,
                     bool lamp_blocked) {
      const Mesh& mesh = impl_->meshes[geom_id];
      Eigen::Vector3f n = ng.normalized();
      if (!mesh.corner_normals.empty()) {
        // Smooth shading (Mesh::corner_normals), on the geometric normal's side.
        const Eigen::Vector3f* c = &mesh.corner_normals[3 * static_cast<size_t>(prim_id)];
        const Eigen::Vector3f smooth =
            ((1.0f - hit_u - hit_v) * c[0] + hit_u * c[1] + hit_v * c[2]).normalized();
        if (smooth.allFinite()) n = smooth.dot(n) < 0 ? -smooth : smooth;
      }
      if (ng.dot(dir) > 0) n = -n;  // towards the camera
      // The hit point (double: the laser's Gaussian is evaluated at 0.01 mm scales 300 mm away), when used.
      Eigen::Vector3d p = Eigen::Vector3d::Zero();
      if (uniform[geom_id] == 0 || want_laser[0] || want_laser[1]) {
        p = cam_centre + static_cast<double>(t) * dir.cast<double>();
      }
      Eigen::Vector3f albedo;
      if (uniform[geom_id] != 0) {
        albedo = mesh.color;
      } else {
        Eigen::Vector3d footprint_x = Eigen::Vector3d::Zero(), footprint_y = Eigen::Vector3d::Zero();
        if (mesh.pattern != internal::Pattern::kNone) {
          // Ray differentials: where the rays one sub-sample right and down meet the hit's plane.
          const Eigen::Vector3d nd = n.cast<double>();
          const float step = 1.0f / static_cast<float>(ss);
          const Eigen::Vector3d dir_x = (rotation * impl_->RayAt(px + step, py)).cast<double>();
          const Eigen::Vector3d dir_y = (rotation * impl_->RayAt(px, py + step)).cast<double>();
          const double along = nd.dot(p - cam_centre);
          footprint_x = cam_centre + along / nd.dot(dir_x) * dir_x - p;
          footprint_y = cam_centre + along / nd.dot(dir_y) * dir_y - p;
        }
        albedo = mesh.Albedo(prim_id, hit_u, hit_v, p, footprint_x, footprint_y);
      }
      if (want_ambient) {
        cv::Vec3f& amb = ambient.ptr<cv::Vec3f>(y)[x];
        for (int c = 0; c < 3; ++c) amb[2 - c] += ambient_weight * albedo[c];
      }
      if (want_lamp) {
        // The lamp: Lambertian, unless the scene blocks it (cast and self shadows).
        const float lamp_cos = lamp_blocked ? 0.0f : std::max(0.0f, n.dot(light_f));
        const float lit = ambient_weight + diffuse_weight * lamp_cos;
        float highlight = 0.0f;  // the glossy lobe (Blinn-Phong), white
        if (mesh.specular > 0.0f && lamp_cos > 0.0f) {
          const Eigen::Vector3f half = (light_f - dir.normalized()).normalized();
          highlight = diffuse_weight * mesh.specular * std::pow(std::max(0.0f, n.dot(half)), mesh.shininess);
        }
        cv::Vec3f& lit_pixel = lamp.ptr<cv::Vec3f>(y)[x];
        for (int c = 0; c < 3; ++c) lit_pixel[2 - c] += lit * albedo[c] + highlight;
      }
      for (int k = 0; k < 2; ++k) {
        if (!want_laser[k]) continue;
        if (scatter[k] != nullptr) {  // the bounce, on the red albedo like the direct line
          const float bounce = scatter[k]->At(px, py, geom_id);
          if (bounce > 0.0f) laser_img[k].ptr<float>(y)[x] += weight * albedo[0] * bounce;
        }
        const LaserModel& laser = sc.laser[k];
        const double s = laser_normal[k].dot(p) + laser_offset[k];
        if (std::abs(s) > 6.0 * laser.sigma_mm) continue;
        const Eigen::Vector3d nd = n.cast<double>();
        const Eigen::Vector3d to_laser = laser_origin[k] - p;
        const double range = to_laser.norm();
        const double cos_incidence = nd.dot(to_laser) / range;
        if (cos_incidence <= 0.0) continue;
        if (impl_->Occluded(p, laser_origin[k], 1e-2)) continue;  // shadowed from this laser
        const double irradiance = laser.power * std::exp(-0.5 * s * s / (laser.sigma_mm * laser.sigma_mm)) *
                                  cos_incidence * 300.0 / range;
        double reflected = irradiance * albedo[0];  // red reflectance
        if (mesh.specular > 0.0f) {  // the glossy lobe (Blinn-Phong), white
          const Eigen::Vector3d half = (to_laser / range - dir.cast<double>().normalized()).normalized();
          const double nh = std::max(0.0, nd.dot(half));
          reflected += irradiance * mesh.specular * std::pow(nh, static_cast<double>(mesh.shininess));
        }
        laser_img[k].ptr<float>(y)[x] += weight * static_cast<float>(reflected);
      }
    };
    for (int first_col = 0; first_col < sample_cols; first_col += kTileWidth) {
      alignas(32) int valid[kPacket];
      alignas(32) RTCRayHit8 packet;
      Eigen::Vector3f dirs[kPacket];
      float pxs[kPacket], pys[kPacket];
      int xs[kPacket], ys[kPacket];
      for (int l = 0; l < kPacket; ++l) {
        const int col = first_col + l % kTileWidth, row = first_row + l / kTileWidth;
        valid[l] = col < sample_cols && row < sample_rows ? -1 : 0;
        const int i = std::min(col, sample_cols - 1), j = std::min(row, sample_rows - 1);
        xs[l] = ss == 1 ? i : i / ss;
        ys[l] = ss == 1 ? j : j / ss;
        if (ss == 1) {
          // One ray per pixel: through its centre, a node of the ray grid.
          pxs[l] = static_cast<float>(i);
          pys[l] = static_cast<float>(j);
          dirs[l] = rotation * impl_->RayAtCentre(i, j);
        } else {
          // A regular grid of sub-samples: with the box-filtered patterns their footprints tile the pixel.
          pxs[l] = xs[l] + (i % ss + 0.5f) / ss - 0.5f;
          pys[l] = ys[l] + (j % ss + 0.5f) / ss - 0.5f;
          dirs[l] = rotation * impl_->RayAt(pxs[l], pys[l]);
        }
        packet.ray.org_x[l] = origin.x();
        packet.ray.org_y[l] = origin.y();
        packet.ray.org_z[l] = origin.z();
        packet.ray.dir_x[l] = dirs[l].x();
        packet.ray.dir_y[l] = dirs[l].y();
        packet.ray.dir_z[l] = dirs[l].z();
        packet.ray.tnear[l] = 1.0f;
        packet.ray.tfar[l] = std::numeric_limits<float>::infinity();
        packet.ray.mask[l] = 0xFFFFFFFF;
        packet.ray.time[l] = 0.0f;
        packet.ray.flags[l] = 0;
        packet.ray.id[l] = 0;
        packet.hit.geomID[l] = RTC_INVALID_GEOMETRY_ID;
        packet.hit.instID[0][l] = RTC_INVALID_GEOMETRY_ID;
      }
      rtcIntersect8(valid, impl_->rtc_scene, &context, &packet);
      // Shadow rays towards the lamp, as a packet too (parallel rays: coherent). Only the natural frame
      // needs them.
      alignas(32) int shadow_valid[kPacket] = {};
      alignas(32) RTCRay8 shadow;
      bool any_shadow_ray = false;
      for (int l = 0; l < kPacket; ++l) {
        shadow.tfar[l] = 0.0f;
        if (!lamp_shadows || valid[l] == 0 || packet.hit.geomID[l] == RTC_INVALID_GEOMETRY_ID) continue;
        Eigen::Vector3f ng(packet.hit.Ng_x[l], packet.hit.Ng_y[l], packet.hit.Ng_z[l]);
        if (ng.dot(dirs[l]) > 0) ng = -ng;
        if (ng.dot(light_f) <= 0) continue;  // facing away from the lamp: unlit anyway
        const Eigen::Vector3f p = origin + packet.ray.tfar[l] * dirs[l];
        shadow.org_x[l] = p.x();
        shadow.org_y[l] = p.y();
        shadow.org_z[l] = p.z();
        shadow.dir_x[l] = light_f.x();
        shadow.dir_y[l] = light_f.y();
        shadow.dir_z[l] = light_f.z();
        shadow.tnear[l] = 1e-2f;
        shadow.tfar[l] = kLampDistanceMm;
        shadow.mask[l] = 0xFFFFFFFF;
        shadow.time[l] = 0.0f;
        shadow.flags[l] = 0;
        shadow.id[l] = 0;
        shadow_valid[l] = -1;
        any_shadow_ray = true;
      }
      if (any_shadow_ray) rtcOccluded8(shadow_valid, impl_->rtc_scene, &context, &shadow);
      for (int l = 0; l < kPacket; ++l) {
        if (valid[l] == 0 || packet.hit.geomID[l] == RTC_INVALID_GEOMETRY_ID) continue;  // black background
        shade(xs[l], ys[l], pxs[l], pys[l], dirs[l], packet.ray.tfar[l],
              Eigen::Vector3f(packet.hit.Ng_x[l], packet.hit.Ng_y[l], packet.hit.Ng_z[l]),
              packet.hit.geomID[l], packet.hit.primID[l], packet.hit.u[l], packet.hit.v[l],
              shadow_valid[l] != 0 && shadow.tfar[l] < 0.0f);
      }
    }
  }

  RenderedStep out;
  const SensorModel& sensor = sc.sensor;
  const float laser_scale = static_cast<float>(sensor.laser_exposure_us * sensor.sensitivity_e_per_us);
  const float natural_scale = static_cast<float>(sensor.natural_exposure_us * sensor.sensitivity_e_per_us);
  // electrons = scale * (base + line * response), then blur and the sensor. ws.electrons is scratch.
  // The ambient light of the laser and off frames, per row (renderer.h): a level of its own per frame and
  // a flicker read out row by row.
  const bool ambient_varies = sc.ambient_change > 0 || sc.ambient_flicker > 0;
  std::vector<float> gains;
  auto ambient_gains = [&](int frame) {
    const uint64_t h = Mix64(seed ^ (0x7f4a7c159e3779b9ULL * (frame + 11)));
    float z[2];
    FillNormal(h, 0, z, 2);
    const double level = std::max(0.0, 1.0 + sc.ambient_change * z[0]);
    const double phase = static_cast<double>(h >> 11) * 0x1p-53 * 2.0 * 3.14159265358979323846;
    const double omega = 2.0 * 3.14159265358979323846 * sc.flicker_hz * 1e-6;  // per µs
    gains.resize(static_cast<size_t>(height));
    for (int y = 0; y < height; ++y) {
      gains[static_cast<size_t>(y)] = static_cast<float>(
          level * (1.0 + sc.ambient_flicker * std::sin(phase + omega * sensor.line_time_us * y)));
    }
  };
  auto finish = [&](const cv::Mat& base, float scale, const cv::Mat* line, const float* response, int frame) {
    cv::Mat& electrons = ws.electrons;
    electrons.create(height, width, CV_32FC3);
    float sensor_scale = 1.0f;  // what the sensor model still has to multiply by
    const bool vary = ambient_varies && frame <= 2;
    if (vary) ambient_gains(frame);
    if (line == nullptr && !vary) {
      // The blur is linear: blurring the base and scaling in the sensor model saves a pass.
      sensor_scale = scale;
      if (sensor.blur_sigma_px > 0) {
        cv::GaussianBlur(base, electrons, cv::Size(0, 0), sensor.blur_sigma_px, sensor.blur_sigma_px,
                         cv::BORDER_REPLICATE);
      } else {
        base.copyTo(electrons);
      }
    } else {
      float r[3] = {0.0f, 0.0f, 0.0f};
      if (line != nullptr) r[0] = scale * response[0], r[1] = scale * response[1], r[2] = scale * response[2];
      for (int y = 0; y < height; ++y) {
        const float* a = base.ptr<float>(y);
        const float* l = line != nullptr ? line->ptr<float>(y) : nullptr;
        const float g = vary ? scale * gains[static_cast<size_t>(y)] : scale;
        float* e = electrons.ptr<float>(y);
        if (l == nullptr) {
          for (int x = 0; x < 3 * width; ++x) e[x] = g * a[x];
          continue;
        }
        for (int x = 0; x < width; ++x) {
          e[3 * x + 0] = g * a[3 * x + 0] + l[x] * r[0];
          e[3 * x + 1] = g * a[3 * x + 1] + l[x] * r[1];
          e[3 * x + 2] = g * a[3 * x + 2] + l[x] * r[2];
        }
      }
      if (sensor.blur_sigma_px > 0) {
        cv::GaussianBlur(electrons, electrons, cv::Size(0, 0), sensor.blur_sigma_px, sensor.blur_sigma_px,
                         cv::BORDER_REPLICATE);
      }
    }
    out.frames[frame] =
        SensorResponse(sensor, electrons, sensor_scale, seed ^ (0x51ed2701ULL * (frame + 1)), ws.raw);
    if (sensor.jpeg_quality > 0 && out.frames[frame].depth() == CV_8U) {  // MJPEG: a JPEG round trip
      std::vector<uint8_t> jpeg;
      cv::imencode(".jpg", out.frames[frame], jpeg, {cv::IMWRITE_JPEG_QUALITY, sensor.jpeg_quality});
      out.frames[frame] = cv::imdecode(jpeg, cv::IMREAD_COLOR);
    }
  };
  for (int k = 0; k < 2; ++k) {
    if (!mask[k]) continue;
    const LaserModel& laser = sc.laser[k];
    cv::Mat& line = laser_img[k];
    if (laser.speckle_contrast > 0 || laser.f_number > 0)
      ApplySpeckle(laser, sensor.pixel_size_um, seed ^ (0xabcdef12345ULL * (k + 1)), line, ws.speckle);
    const float response[3] = {static_cast<float>(laser.response[2]), static_cast<float>(laser.response[1]),
                               static_cast<float>(laser.response[0])};  // BGR
    finish(ambient, laser_scale, &line, response, k);
  }
  if (mask[2]) finish(ambient, laser_scale, nullptr, nullptr, 2);
  if (mask[3]) finish(lamp, natural_scale, nullptr, nullptr, 3);
  return out;
}

std::vector<bundle::LinePoint> Renderer::LineTruth(geometry::LaserId id, double table_angle) const {
  const Scene& sc = scene_;
  const geometry::CameraModel& camera = sc.rig.camera;
  const int k = static_cast<int>(id);
  const geometry::Plane& plane = sc.rig.laser_plane[k];
  const Eigen::Isometry3d table_from_cam = sc.rig.WorldFromCamAtAngle(table_angle);
  const Eigen::Isometry3d cam_from_table = table_from_cam.inverse();
  const Eigen::Vector3d cam_centre = table_from_cam.translation();
  const Eigen::Vector3d laser_origin = table_from_cam * sc.laser[k].origin_in_cam;
  std::vector<bundle::LinePoint> points;
  for (std::size_t mi = 0; mi < impl_->meshes.size(); ++mi) {
    const Mesh& mesh = impl_->meshes[mi];
    std::vector<Eigen::Vector3d> in_cam(mesh.vertices.size());
    std::vector<double> distance(mesh.vertices.size());
    for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
      in_cam[v] = cam_from_table * mesh.vertices[v].cast<double>();
      distance[v] = plane.SignedDistance(in_cam[v]);
    }
    for (const Eigen::Vector3i& f : mesh.faces) {
      Eigen::Vector3d ends[2];
      int found = 0;
      for (int e = 0; e < 3 && found < 2; ++e) {
        const int a = f[e], b = f[(e + 1) % 3];
        const bool pa = distance[a] >= 0, pb = distance[b] >= 0;
        if (pa == pb) continue;
        const double t = distance[a] / (distance[a] - distance[b]);
        ends[found++] = in_cam[a] + t * (in_cam[b] - in_cam[a]);
      }
      if (found < 2 || ends[0].z() <= 1.0 || ends[1].z() <= 1.0) continue;
      // Normal of the triangle (table frame) for the same-side test of camera and laser.
      const Eigen::Vector3d v0 = mesh.vertices[f[0]].cast<double>(), v1 = mesh.vertices[f[1]].cast<double>(),
                            v2 = mesh.vertices[f[2]].cast<double>();
      const Eigen::Vector3d normal = (v1 - v0).cross(v2 - v0);
      const double row_a = camera.Project(ends[0]).y(), row_b = camera.Project(ends[1]).y();
      if (!std::isfinite(row_a) || !std::isfinite(row_b)) continue;
      // Clamped before the conversion to int (far outside the image a lens model can diverge).
      const int first =
          static_cast<int>(std::ceil(std::clamp(std::min(row_a, row_b), 0.0, camera.height - 1.0)));
      const int last =
          static_cast<int>(std::floor(std::clamp(std::max(row_a, row_b), 0.0, camera.height - 1.0)));
      for (int row = first; row <= last; ++row) {
        // Bisection on the segment for projected row == row (the projection of a segment is monotone).
        double lo = 0, hi = 1;
        const bool increasing = row_b > row_a;
        for (int it = 0; it < 60; ++it) {
          const double mid = 0.5 * (lo + hi);
          const double r = camera.Project(ends[0] + mid * (ends[1] - ends[0])).y();
          if ((r < row) == increasing) {
            lo = mid;
          } else {
            hi = mid;
          }
        }
        const Eigen::Vector3d point_in_cam = ends[0] + 0.5 * (lo + hi) * (ends[1] - ends[0]);
        const Eigen::Vector2d pixel = camera.Project(point_in_cam);
        if (pixel.x() < -0.5 || pixel.x() > camera.width - 0.5) continue;
        if (std::abs(pixel.y() - row) > 1e-6) continue;  // the projection was not monotone here
        const Eigen::Vector3d p = table_from_cam * point_in_cam;
        if (normal.dot(cam_centre - p) * normal.dot(laser_origin - p) <= 0) continue;  // lit side unseen
        if (impl_->Occluded(cam_centre, p, 1e-2)) continue;    // hidden from the camera
        if (impl_->Occluded(p, laser_origin, 1e-2)) continue;  // in the laser's shadow
        bundle::LinePoint lp;
        lp.row = row;
        lp.column = pixel.x();
        lp.point_in_cam = point_in_cam;
        lp.point_in_world = p;
        lp.object = static_cast<int>(mi);
        points.push_back(lp);
      }
    }
  }
  std::sort(points.begin(), points.end(), [](const bundle::LinePoint& a, const bundle::LinePoint& b) {
    return a.row != b.row ? a.row < b.row : a.column < b.column;
  });
  // A point on an edge shared by two triangles is found twice: keep one.
  points.erase(std::unique(points.begin(), points.end(),
                           [](const bundle::LinePoint& a, const bundle::LinePoint& b) {
                             return a.row == b.row && std::abs(a.column - b.column) < 1e-6;
                           }),
               points.end());
  return points;
}

}  // namespace rotoscan::sim
