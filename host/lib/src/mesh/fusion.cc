// Range-scan fusion (Curless & Levoy, "A Volumetric Method for Building Complex Models from Range Images",
// SIGGRAPH 1996): a weighted, truncated signed distance per voxel, accumulated from every sample of the scan,
// then marching cubes (Lorensen & Cline 1987; the case tables are Open3D's, from its installed header).
//
// Layout: a dense directory of 8^3-voxel blocks over the cloud's box, a block allocated when a sample first
// touches it. Splatting runs on two threads without locks: the blocks are cut into two slabs along x at the
// samples' median, and each thread writes only the voxels of its own slab (samples near the cut are seen by
// both). Marching cubes runs per block on the same threads: first the vertices on each voxel's three
// forward edges, then the triangles of each cube, which only read.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <string>
#include <thread>
#include <vector>

#include <open3d/pipelines/integration/MarchingCubesConst.h>
#include <opencv2/imgproc.hpp>

#include "rotoscan/core/logging.h"
#include "rotoscan/mesh/mesh.h"

namespace rotoscan::mesh {
namespace {

constexpr int kBlock = 8;
constexpr int kBlockVoxels = kBlock * kBlock * kBlock;
constexpr std::size_t kMaxBlocks = std::size_t{1} << 26;

struct Sample {
  Eigen::Vector3f p, n;
  Eigen::Vector3f view = Eigen::Vector3f::Zero();  // unit, toward the camera; zero when unknown
  float weight, radius;
  Eigen::Vector3f rgb;
  bool table = false;  // a sample of the table plane under the object (flat bottom)
};

struct Block {
  std::array<float, kBlockVoxels> sdf{};     // sum of w * d, then d
  std::array<float, kBlockVoxels> weight{};  // sum of w
  std::array<Eigen::Vector3f, kBlockVoxels> rgb{};
};

int LocalIndex(int i, int j, int k) { return (i & 7) + kBlock * ((j & 7) + kBlock * (k & 7)); }

class Volume {
 public:
  Volume(const Eigen::Vector3d& origin, double voxel, const Eigen::Vector3i& blocks)
      : origin_(origin.cast<float>()), voxel_(static_cast<float>(voxel)), dims_(blocks) {
    directory_.assign(static_cast<std::size_t>(blocks.prod()), nullptr);
  }

  const Eigen::Vector3f& origin() const { return origin_; }
  float voxel() const { return voxel_; }
  const Eigen::Vector3i& dims() const { return dims_; }
  Eigen::Vector3i voxel_dims() const { return dims_ * kBlock; }

  std::size_t BlockIndex(int bi, int bj, int bk) const {
    return static_cast<std::size_t>(bi) +
           static_cast<std::size_t>(dims_.x()) * (static_cast<std::size_t>(bj) +
                                                  static_cast<std::size_t>(dims_.y()) * static_cast<std::size_t>(bk));
  }
  Block*& Slot(int bi, int bj, int bk) { return directory_[BlockIndex(bi, bj, bk)]; }
  const Block* Find(int i, int j, int k) const {
    if (i < 0 || j < 0 || k < 0) return nullptr;
    const int bi = i >> 3, bj = j >> 3, bk = k >> 3;
    if (bi >= dims_.x() || bj >= dims_.y() || bk >= dims_.z()) return nullptr;
    return directory_[BlockIndex(bi, bj, bk)];
  }
  Eigen::Vector3f Centre(int i, int j, int k) const {
    return origin_ + voxel_ * Eigen::Vector3f(static_cast<float>(i) + 0.5f, static_cast<float>(j) + 0.5f,
                                              static_cast<float>(k) + 0.5f);
  }

 private:
  Eigen::Vector3f origin_;
  float voxel_;
  Eigen::Vector3i dims_;
  std::vector<Block*> directory_;
};

// One thread's share of the splatting: the voxels with x index in [x0, x1).
// Below `floor` only the table's own samples count (the object stands on it: nothing of it lies below).
void Splat(const std::vector<Sample>& samples, float truncation, float floor, int x0, int x1, Volume* volume,
           std::vector<std::unique_ptr<Block>>* pool) {
  const float h = volume->voxel();
  const Eigen::Vector3i vd = volume->voxel_dims();
  const Eigen::Vector3f& origin = volume->origin();
  for (const Sample& s : samples) {
    const float reach = std::max(truncation, s.radius);
    const Eigen::Vector3f lo = (s.p - origin).array() / h - reach / h - 0.5f;
    const Eigen::Vector3f hi = (s.p - origin).array() / h + reach / h - 0.5f;
    const int i0 = std::max({x0, static_cast<int>(std::ceil(lo.x())), 0});
    const int i1 = std::min({x1 - 1, static_cast<int>(std::floor(hi.x())), vd.x() - 1});
    if (i0 > i1) continue;
    const int j0 = std::max(0, static_cast<int>(std::ceil(lo.y())));
    const int j1 = std::min(vd.y() - 1, static_cast<int>(std::floor(hi.y())));
    const int lowest = s.table ? 0 : static_cast<int>(std::ceil((floor - origin.z()) / h - 0.5f));
    const int k0 = std::max({0, lowest, static_cast<int>(std::ceil(lo.z()))});
    const int k1 = std::min(vd.z() - 1, static_cast<int>(std::floor(hi.z())));
    const float r2 = s.radius * s.radius;
    const float inv_r2 = 1.0f / r2;
    for (int k = k0; k <= k1; ++k) {
      for (int j = j0; j <= j1; ++j) {
        for (int i = i0; i <= i1; ++i) {
          const Eigen::Vector3f dv = volume->Centre(i, j, k) - s.p;
          const float d = s.n.dot(dv);
          if (std::abs(d) > truncation) continue;
          const float lateral2 = dv.squaredNorm() - d * d;
          if (lateral2 > r2) continue;
          // VRIP's ramp: full weight in front of the sample and just behind it, fading deeper inside.
          const float behind = d < -h ? std::max(0.2f, 1.0f + (d + h) / truncation) : 1.0f;
          const float w = s.weight * (1.0f - 0.9f * lateral2 * inv_r2) * behind;
          Block*& block = volume->Slot(i >> 3, j >> 3, k >> 3);
          if (block == nullptr) {
            pool->push_back(std::make_unique<Block>());
            block = pool->back().get();
          }
          const int v = LocalIndex(i, j, k);
          block->sdf[static_cast<std::size_t>(v)] += w * d;
          block->weight[static_cast<std::size_t>(v)] += w;
          block->rgb[static_cast<std::size_t>(v)] += w * s.rgb;
        }
      }
    }
  }
}

// Runs fn(thread, begin, end) over [0, n) cut into `threads` contiguous parts.
template <typename Fn>
void Parallel(int threads, std::size_t n, Fn fn) {
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) {
    pool.emplace_back(fn, t, n * static_cast<std::size_t>(t) / static_cast<std::size_t>(threads),
                      n * static_cast<std::size_t>(t + 1) / static_cast<std::size_t>(threads));
  }
  fn(0, std::size_t{0}, n / static_cast<std::size_t>(threads));
  for (std::thread& t : pool) t.join();
}

// The table plane under the object: the cells of the lowest slice of samples, closed (gaps between table
// steps bridged) and filled, become samples on z = table_z facing down, so the surface closes there.
std::vector<Sample> TableSamples(const FusionOptions& options, const std::vector<Sample>& samples) {
  std::vector<Sample> table;
  const float h = static_cast<float>(options.voxel_mm);
  const float table_z = static_cast<float>(options.table_z);
  const float band = static_cast<float>(2.0 * options.truncation_voxels * options.voxel_mm);
  Eigen::Vector2f lo(std::numeric_limits<float>::max(), std::numeric_limits<float>::max());
  Eigen::Vector2f hi = -lo;
  Eigen::Vector3f rgb = Eigen::Vector3f::Zero();
  float max_radius = 0;
  std::size_t low = 0;
  for (const Sample& s : samples) {
    if (s.p.z() > table_z + band) continue;
    lo = lo.cwiseMin(s.p.head<2>());
    hi = hi.cwiseMax(s.p.head<2>());
    rgb += s.rgb;
    max_radius = std::max(max_radius, s.radius);
    ++low;
  }
  if (low < 10) return table;
  rgb /= static_cast<float>(low);
  const int close = std::max(1, static_cast<int>(std::ceil(2.0f * max_radius / h)));
  const int pad = close + 2;
  const int cols = static_cast<int>((hi.x() - lo.x()) / h) + 1 + 2 * pad;
  const int rows = static_cast<int>((hi.y() - lo.y()) / h) + 1 + 2 * pad;
  if (static_cast<double>(cols) * rows > 1e8) return table;  // absurd footprint: leave the bottom open
  cv::Mat seen = cv::Mat::zeros(rows, cols, CV_8U);
  auto cell = [&](const Eigen::Vector3f& p) {
    return cv::Point(static_cast<int>((p.x() - lo.x()) / h) + pad, static_cast<int>((p.y() - lo.y()) / h) + pad);
  };
  for (const Sample& s : samples) {
    if (s.p.z() <= table_z + band) seen.at<uint8_t>(cell(s.p)) = 255;
  }
  const cv::Mat disc =
      cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * close + 1, 2 * close + 1));
  cv::Mat closed;
  cv::morphologyEx(seen, closed, cv::MORPH_CLOSE, disc);
  cv::Mat outside = closed.clone();
  cv::floodFill(outside, cv::Point(0, 0), cv::Scalar(128));
  // Footprint: the closed ring and what it encloses (not reached from the border).
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      if (outside.at<uint8_t>(y, x) == 128) continue;
      Sample s;
      s.p = Eigen::Vector3f(lo.x() + (static_cast<float>(x - pad) + 0.5f) * h,
                            lo.y() + (static_cast<float>(y - pad) + 0.5f) * h, table_z);
      s.n = -Eigen::Vector3f::UnitZ();
      s.weight = 0.5f;
      s.radius = 1.5f * h;
      s.rgb = rgb;
      s.table = true;
      table.push_back(s);
    }
  }
  return table;
}

struct Extracted {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<Eigen::Vector3d> colors;
  std::vector<Eigen::Vector3i> triangles;
};

// Watertight (FusionOptions::watertight). Curless & Levoy's §5 ("hole filling") sorts every voxel of the
// volume into near the surface, seen empty, or unseen, and extracts a surface between empty and unseen as
// well, so that the result is closed. Here:
// - observed: a voxel with at least the trimming weight keeps its fused signed distance;
// - seen empty: every voxel a sensor ray crossed. The rays are the points' own, from just in front of each
//   point to its camera, and, with the flat bottom, the cameras' rays to the table top around the object
//   (the camera sees the table wherever the object does not hide it). A ray that meets the inside of an
//   observed surface (signed distance below -h/4) came from behind a surface (an outlier, or a table point
//   the object hides) and carves nothing;
// - unseen: takes the sign of the nearest observed voxel (a breadth-first sweep over the grid), so that a
//   hole's rim continues across the hole; then the seen-empty voxels are set outside, everything under
//   the table and on the box's faces too; unseen sheets thinner than 6 voxels are opened (set outside);
// - the unobserved voxels are then smoothed by Jacobi sweeps of volumetric diffusion (Davis, Marschner,
//   Garr & Levoy, "Filling holes in complex surfaces using volumetric diffusion", 3DPVT 2002), the
//   observed ones held fixed as boundary values and the empty ones kept outside.
// Marching cubes then runs over every cube of the box: every cube has all eight values, so every edge of
// the surface is shared by two triangles. Colors come from the nearest observed voxel.
constexpr uint8_t kUnseen = 0, kEmpty = 1, kObserved = 2, kTouched = 3;

struct ClosedStats {
  std::size_t point_rays = 0, table_rays = 0, discarded = 0;
  double observed_fraction = 1.0;
};

Result<TriangleMesh> ExtractClosed(const Volume& volume, const std::vector<Sample>& samples,
                                   const std::vector<Eigen::Vector3d>& cameras, float min_weight,
                                   float truncation, const FusionOptions& options, int threads,
                                   ClosedStats* stats) {
  const Eigen::Vector3i dims = volume.voxel_dims();
  const std::size_t nx = static_cast<std::size_t>(dims.x()), ny = static_cast<std::size_t>(dims.y()),
                    nz = static_cast<std::size_t>(dims.z());
  const std::size_t n = nx * ny * nz;
  if (n > (std::size_t{1} << 28)) {
    return InvalidArgumentError("watertight meshing needs the whole box, " + std::to_string(n) +
                                " voxels at " + std::to_string(options.voxel_mm) +
                                " mm, more than 2^28: use a larger voxel");
  }
  const float h = volume.voxel();
  const Eigen::Vector3f& origin = volume.origin();
  auto index = [&](std::size_t i, std::size_t j, std::size_t k) { return i + nx * (j + ny * k); };
  std::vector<float> value(n, 0.0f);
  std::vector<uint8_t> state(n, kUnseen);
  std::vector<uint32_t> nearest(n, std::numeric_limits<uint32_t>::max());  // nearest observed voxel
  std::vector<uint32_t> queue;
  for (std::size_t k = 0; k < nz; ++k) {
    for (std::size_t j = 0; j < ny; ++j) {
      for (std::size_t i = 0; i < nx; ++i) {
        const Block* b = volume.Find(static_cast<int>(i), static_cast<int>(j), static_cast<int>(k));
        if (b == nullptr) continue;
        const auto v = static_cast<std::size_t>(LocalIndex(static_cast<int>(i), static_cast<int>(j), static_cast<int>(k)));
        if (!(b->weight[v] > 0)) continue;
        // Below the trimming weight a voxel is not held fixed, but its sign still counts (the far side of a
        // surface seen at a grazing angle is often light).
        const std::size_t at = index(i, j, k);
        state[at] = b->weight[v] >= min_weight ? kObserved : kTouched;
        value[at] = std::clamp(b->sdf[v], -truncation, truncation);
        nearest[at] = static_cast<uint32_t>(at);
        queue.push_back(static_cast<uint32_t>(at));
      }
    }
  }
  if (queue.empty()) return NotConvergedError("fusion produced no surface (too few or too sparse points?)");

  // Carving: each thread marks its own copy, merged after.
  struct Ray {
    Eigen::Vector3f from, direction;
    float length;
  };
  std::vector<Ray> rays;
  const float diagonal = (dims.cast<float>() * h).norm();
  std::size_t with_view = 0;
  for (const Sample& s : samples) with_view += s.view.squaredNorm() > 0.25f ? 1 : 0;
  const std::size_t stride = std::max<std::size_t>(1, with_view / 400000);
  std::size_t seen = 0;
  for (const Sample& s : samples) {
    if (!(s.view.squaredNorm() > 0.25f) || seen++ % stride != 0) continue;
    rays.push_back({s.p + (truncation + h) * s.view, s.view, diagonal});
  }
  const std::size_t point_rays = rays.size();
  if (options.flat_bottom && !cameras.empty()) {
    // Up to 36 of the cameras, evenly through the scan; table points every 2 voxels, half a voxel up.
    const std::size_t count = std::min<std::size_t>(36, cameras.size());
    const float z = static_cast<float>(options.table_z) + 0.5f * h;
    for (std::size_t c = 0; c < count; ++c) {
      const Eigen::Vector3f camera = cameras[c * cameras.size() / count].cast<float>();
      for (std::size_t j = 1; j + 1 < ny; j += 2) {
        for (std::size_t i = 1; i + 1 < nx; i += 2) {
          const Eigen::Vector3f q = origin + h * Eigen::Vector3f(static_cast<float>(i) + 0.5f,
                                                                 static_cast<float>(j) + 0.5f, 0.0f);
          const Eigen::Vector3f from(q.x(), q.y(), z);
          const Eigen::Vector3f to = camera - from;
          if (!(to.norm() > h)) continue;
          rays.push_back({from, to.normalized(), to.norm()});
        }
      }
    }
  }
  std::vector<std::vector<uint8_t>> marks(static_cast<std::size_t>(threads));
  std::vector<std::size_t> discarded(static_cast<std::size_t>(threads), 0);
  Parallel(threads, rays.size(), [&](int t, std::size_t begin, std::size_t end) {
    std::vector<uint8_t>& mark = marks[static_cast<std::size_t>(t)];
    mark.assign(n, 0);
    std::vector<std::size_t> crossed;
    for (std::size_t r = begin; r < end; ++r) {
      const Ray& ray = rays[r];
      crossed.clear();
      bool inside = false;
      for (float s = 0; s <= ray.length && !inside; s += 0.5f * h) {
        const Eigen::Vector3f q = (ray.from + s * ray.direction - origin) / h;
        if ((q.array() < 0).any() || q.x() >= static_cast<float>(nx) || q.y() >= static_cast<float>(ny) ||
            q.z() >= static_cast<float>(nz)) {
          break;
        }
        const std::size_t at = index(static_cast<std::size_t>(q.x()), static_cast<std::size_t>(q.y()),
                                     static_cast<std::size_t>(q.z()));
        if (state[at] == kObserved || state[at] == kTouched) {
          // Near or behind a surface (seen well or barely): the ray came from behind one (an outlier, a
          // table point the object hides) or grazes it; either way it proves nothing.
          inside = value[at] < h;
          if (state[at] == kObserved) continue;
        }
        crossed.push_back(at);
      }
      if (inside) {
        ++discarded[static_cast<std::size_t>(t)];
        continue;
      }
      for (std::size_t at : crossed) mark[at] = 1;
    }
  });

  // The unseen voxels take the sign of the nearest observed one (6-connected breadth-first sweep).
  for (std::size_t head = 0; head < queue.size(); ++head) {
    const std::size_t at = queue[head];
    const std::size_t i = at % nx, j = (at / nx) % ny, k = at / (nx * ny);
    const std::size_t next[6] = {i > 0 ? at - 1 : at,           i + 1 < nx ? at + 1 : at,
                                 j > 0 ? at - nx : at,          j + 1 < ny ? at + nx : at,
                                 k > 0 ? at - nx * ny : at,     k + 1 < nz ? at + nx * ny : at};
    for (std::size_t m : next) {
      if (nearest[m] != std::numeric_limits<uint32_t>::max()) continue;
      nearest[m] = nearest[at];
      queue.push_back(static_cast<uint32_t>(m));
    }
  }
  queue = {};
  // Beyond the samples' box (by two voxels) nothing was seen: outside. A hole's continuation ends there.
  Eigen::Vector3f seen_lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  Eigen::Vector3f seen_hi = -seen_lo;
  for (const Sample& s : samples) {
    seen_lo = seen_lo.cwiseMin(s.p);
    seen_hi = seen_hi.cwiseMax(s.p);
  }
  const Eigen::Vector3i box_lo = ((seen_lo - origin) / h).array().floor().cast<int>() - 2;
  const Eigen::Vector3i box_hi = ((seen_hi - origin) / h).array().floor().cast<int>() + 2;
  const float table_z = static_cast<float>(options.table_z);
  for (std::size_t k = 0; k < nz; ++k) {
    const bool below = options.flat_bottom && origin.z() + (static_cast<float>(k) + 0.5f) * h < table_z;
    for (std::size_t j = 0; j < ny; ++j) {
      for (std::size_t i = 0; i < nx; ++i) {
        const std::size_t at = index(i, j, k);
        const Eigen::Vector3i c(static_cast<int>(i), static_cast<int>(j), static_cast<int>(k));
        const bool face = i == 0 || j == 0 || k == 0 || i + 1 == nx || j + 1 == ny || k + 1 == nz ||
                          (c.array() < box_lo.array()).any() || (c.array() > box_hi.array()).any();
        bool carved = face || below;
        for (const auto& mark : marks) carved = carved || mark[at] != 0;
        if (state[at] == kObserved && !face) continue;
        if (carved) {
          state[at] = kEmpty;
          value[at] = truncation;
        } else if (state[at] == kUnseen) {
          value[at] = value[nearest[at]] < 0 ? -truncation : truncation;
        }
      }
    }
  }
  marks.clear();

  // Thin unseen sheets (the nearest-voxel sign continues a thin part, an ear, as a sheet into space nobody
  // saw) are opened: an unobserved inside voxel with outside voxels within 3 on both sides along an axis
  // becomes outside. Observed voxels, where a thin part really is, are left alone.
  {
    std::vector<uint8_t> open(n, 0);
    const std::size_t stride_of[3] = {1, nx, nx * ny};
    const std::size_t size_of[3] = {nx, ny, nz};
    Parallel(threads, nz, [&](int, std::size_t k0, std::size_t k1) {
      for (std::size_t k = k0; k < k1; ++k) {
        for (std::size_t j = 0; j < ny; ++j) {
          for (std::size_t i = 0; i < nx; ++i) {
            const std::size_t at = index(i, j, k);
            if (state[at] == kObserved || value[at] >= 0) continue;
            const std::size_t coord[3] = {i, j, k};
            for (int axis = 0; axis < 3 && open[at] == 0; ++axis) {
              bool below = false, above = false;
              for (std::size_t d = 1; d <= 3; ++d) {
                if (!below && coord[axis] >= d && value[at - d * stride_of[axis]] > 0) below = true;
                if (!above && coord[axis] + d < size_of[axis] && value[at + d * stride_of[axis]] > 0) above = true;
              }
              if (below && above) open[at] = 1;
            }
          }
        }
      }
    });
    for (std::size_t at = 0; at < n; ++at) {
      if (open[at] != 0) value[at] = truncation;
    }
  }

  // Diffusion over the unobserved voxels (Jacobi), the box's faces held outside.
  std::vector<float> next_value = value;
  for (int sweep = 0; sweep < options.diffusion_iterations; ++sweep) {
    Parallel(threads, nz, [&](int, std::size_t k0, std::size_t k1) {
      for (std::size_t k = std::max<std::size_t>(k0, 1); k < std::min(k1, nz - 1); ++k) {
        for (std::size_t j = 1; j + 1 < ny; ++j) {
          for (std::size_t i = 1; i + 1 < nx; ++i) {
            const std::size_t at = index(i, j, k);
            if (state[at] == kObserved) continue;
            float mean = (value[at - 1] + value[at + 1] + value[at - nx] + value[at + nx] + value[at - nx * ny] +
                          value[at + nx * ny]) /
                         6.0f;
            if (state[at] == kEmpty) mean = std::max(mean, 0.05f * h);
            next_value[at] = mean;
          }
        }
      }
    });
    std::swap(value, next_value);
  }
  next_value = {};

  // Marching cubes over every cube of the box. Pass 1: a vertex on each crossing edge (per slab of z).
  auto color_of = [&](std::size_t at) {
    const std::size_t src = nearest[at];
    const int i = static_cast<int>(src % nx), j = static_cast<int>((src / nx) % ny),
              k = static_cast<int>(src / (nx * ny));
    return volume.Find(i, j, k)->rgb[static_cast<std::size_t>(LocalIndex(i, j, k))];
  };
  std::vector<Extracted> slab(static_cast<std::size_t>(threads));
  std::vector<std::vector<uint64_t>> slab_keys(static_cast<std::size_t>(threads));
  std::vector<std::size_t> observed_vertices(static_cast<std::size_t>(threads), 0);
  const std::size_t stride_axis[3] = {1, nx, nx * ny};
  Parallel(threads, nz, [&](int t, std::size_t k0, std::size_t k1) {
    Extracted& out = slab[static_cast<std::size_t>(t)];
    std::vector<uint64_t>& keys = slab_keys[static_cast<std::size_t>(t)];
    for (std::size_t k = k0; k < k1; ++k) {
      for (std::size_t j = 0; j < ny; ++j) {
        for (std::size_t i = 0; i < nx; ++i) {
          const std::size_t at = index(i, j, k);
          const float s0 = value[at];
          const std::size_t coord[3] = {i, j, k}, size[3] = {nx, ny, nz};
          for (int axis = 0; axis < 3; ++axis) {
            if (coord[axis] + 1 >= size[axis]) continue;
            const std::size_t other = at + stride_axis[axis];
            const float s1 = value[other];
            if ((s0 < 0) == (s1 < 0)) continue;
            const float f = s0 / (s0 - s1);
            Eigen::Vector3f p = volume.Centre(static_cast<int>(i), static_cast<int>(j), static_cast<int>(k));
            p[axis] += f * h;
            const Eigen::Vector3f c = (1 - f) * color_of(at) + f * color_of(other);
            keys.push_back(3 * static_cast<uint64_t>(at) + static_cast<uint64_t>(axis));
            out.vertices.push_back(p.cast<double>());
            out.colors.push_back(c.cwiseMax(0.0f).cwiseMin(1.0f).cast<double>());
            if (state[at] == kObserved && state[other] == kObserved) ++observed_vertices[static_cast<std::size_t>(t)];
          }
        }
      }
    }
  });
  TriangleMesh mesh;
  std::vector<uint64_t> keys;
  for (std::size_t t = 0; t < slab.size(); ++t) {
    mesh.vertices.insert(mesh.vertices.end(), slab[t].vertices.begin(), slab[t].vertices.end());
    mesh.vertex_colors.insert(mesh.vertex_colors.end(), slab[t].colors.begin(), slab[t].colors.end());
    keys.insert(keys.end(), slab_keys[t].begin(), slab_keys[t].end());
    slab[t] = Extracted{};
  }
  slab_keys.clear();
  if (mesh.vertices.size() >= static_cast<std::size_t>(std::numeric_limits<int>::max()))
    return InvalidArgumentError("watertight surface too large: use a larger voxel");
  // Pass 2: the triangles of every cube (the keys are sorted: the slabs run in order).
  std::vector<std::vector<Eigen::Vector3i>> triangles(static_cast<std::size_t>(threads));
  Parallel(threads, nz > 0 ? nz - 1 : 0, [&](int t, std::size_t k0, std::size_t k1) {
    auto& out = triangles[static_cast<std::size_t>(t)];
    for (std::size_t k = k0; k < k1; ++k) {
      for (std::size_t j = 0; j + 1 < ny; ++j) {
        for (std::size_t i = 0; i + 1 < nx; ++i) {
          int cube = 0;
          for (int c = 0; c < 8; ++c) {
            const std::size_t at = index(i + static_cast<std::size_t>(shift[c].x()),
                                         j + static_cast<std::size_t>(shift[c].y()),
                                         k + static_cast<std::size_t>(shift[c].z()));
            if (value[at] < 0) cube |= 1 << c;
          }
          if (cube == 0 || cube == 255) continue;
          std::array<int, 12> vertex{};
          for (int e = 0; e < 12; ++e) {
            if ((edge_table[cube] & (1 << e)) == 0) continue;
            const std::size_t at = index(i + static_cast<std::size_t>(edge_shift[e].x()),
                                         j + static_cast<std::size_t>(edge_shift[e].y()),
                                         k + static_cast<std::size_t>(edge_shift[e].z()));
            const uint64_t key = 3 * static_cast<uint64_t>(at) + static_cast<uint64_t>(edge_shift[e][3]);
            const auto found = std::lower_bound(keys.begin(), keys.end(), key);
            vertex[static_cast<std::size_t>(e)] = static_cast<int>(found - keys.begin());
          }
          for (int tri = 0; tri_table[cube][tri] != -1; tri += 3) {
            out.emplace_back(vertex[static_cast<std::size_t>(tri_table[cube][tri])],
                             vertex[static_cast<std::size_t>(tri_table[cube][tri + 2])],
                             vertex[static_cast<std::size_t>(tri_table[cube][tri + 1])]);
          }
        }
      }
    }
  });
  for (auto& part : triangles) mesh.triangles.insert(mesh.triangles.end(), part.begin(), part.end());
  if (stats != nullptr) {
    stats->point_rays = point_rays;
    stats->table_rays = rays.size() - point_rays;
    for (std::size_t d : discarded) stats->discarded += d;
    std::size_t observed = 0;
    for (std::size_t o : observed_vertices) observed += o;
    stats->observed_fraction =
        mesh.vertices.empty() ? 0.0 : static_cast<double>(observed) / static_cast<double>(mesh.vertices.size());
  }
  return mesh;
}

}  // namespace

Status FusionOptions::Check() const {
  if (!(voxel_mm >= 0.01 && voxel_mm <= 100)) return InvalidArgumentError("fusion voxel must be 0.01..100 mm");
  if (!(truncation_voxels >= 1 && truncation_voxels <= 10))
    return InvalidArgumentError("fusion truncation must be 1..10 voxels");
  if (!(footprint_voxels >= 0.5 && footprint_voxels <= 10))
    return InvalidArgumentError("fusion footprint must be 0.5..10 voxels");
  if (!(min_weight_fraction >= 0 && min_weight_fraction < 1))
    return InvalidArgumentError("fusion min_weight_fraction must be in [0, 1)");
  if (!(min_component_fraction >= 0 && min_component_fraction < 1))
    return InvalidArgumentError("fusion min_component_fraction must be in [0, 1)");
  if (!std::isfinite(table_z)) return InvalidArgumentError("fusion table_z must be finite");
  if (threads < 0 || threads > 256) return InvalidArgumentError("threads must be 0..256");
  if (diffusion_iterations < 0 || diffusion_iterations > 1000)
    return InvalidArgumentError("fusion diffusion_iterations must be 0..1000");
  if (!(color_radius_voxels >= 0 && color_radius_voxels <= 20))
    return InvalidArgumentError("fusion color_radius_voxels must be 0..20");
  return Status::Ok();
}

Result<TriangleMesh> FuseSurface(const ColoredPoints& cloud, const FusionOptions& options,
                                 FusionSummary* summary, Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  const std::size_t n = cloud.points.size();
  if (n < 100) return InvalidArgumentError("fusion meshing needs at least 100 points, got " + std::to_string(n));
  auto sized = [n](std::size_t size) { return size == 0 || size == n; };
  if (!sized(cloud.normals.size()) || !sized(cloud.colors.size()) || !sized(cloud.views.size()) ||
      !sized(cloud.quality.size())) {
    return InvalidArgumentError("point cloud arrays differ in length (points, normals, colors, views, quality)");
  }
  if (!std::isfinite(cloud.step_rad)) return InvalidArgumentError("step angle must be finite");
  ROTOSCAN_RETURN_IF_ERROR(CheckCloudExtent(cloud));
  ProgressScope scope(progress, "mesh", 3);
  const auto start = std::chrono::steady_clock::now();
  const int threads = options.threads > 0
                          ? options.threads
                          : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const float h = static_cast<float>(options.voxel_mm);
  const float truncation = static_cast<float>(options.truncation_voxels * options.voxel_mm);
  const float min_radius = static_cast<float>(options.footprint_voxels * options.voxel_mm);

  // Samples: each point with its normal (oriented to its camera), weight and footprint.
  std::vector<Sample> samples;
  samples.reserve(n);
  std::size_t without_normal = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d& p = cloud.points[i];
    if (!p.allFinite() || p.cwiseAbs().maxCoeff() > 1e7)
      return InvalidArgumentError("point cloud holds a non-finite or absurd point (#" + std::to_string(i) + ")");
    Eigen::Vector3d normal = cloud.normals.empty() ? Eigen::Vector3d::Zero() : cloud.normals[i];
    const bool has_view = !cloud.views.empty() && cloud.views[i].squaredNorm() > 0.25;
    if (!(normal.squaredNorm() > 0.25) || !normal.allFinite()) {
      if (!has_view) {
        ++without_normal;
        continue;
      }
      normal = cloud.views[i];
    }
    normal.normalize();
    Sample s;
    s.p = p.cast<float>();
    s.n = normal.cast<float>();
    float weight = cloud.quality.empty() ? 1.0f : std::clamp(cloud.quality[i], 0.05f, 1.0f);
    if (!std::isfinite(weight)) weight = 0.05f;
    if (has_view) {
      // How squarely the camera saw the surface (VRIP weighs by the same cosine).
      const double cosine = normal.dot(cloud.views[i].normalized());
      weight *= static_cast<float>(std::clamp(cosine, 0.1, 1.0));
    }
    s.weight = weight;
    if (has_view) s.view = cloud.views[i].normalized().cast<float>();
    const double across_steps = 0.75 * std::hypot(p.x(), p.y()) * std::abs(cloud.step_rad);
    s.radius = std::clamp(static_cast<float>(across_steps), min_radius, 4.0f * h);
    s.rgb = cloud.colors.empty() ? Eigen::Vector3f(0.8f, 0.8f, 0.8f) : cloud.colors[i].cast<float>();
    samples.push_back(s);
  }
  if (samples.size() < 100) {
    return InvalidArgumentError("fusion needs oriented normals or each point's camera; " +
                                std::to_string(without_normal) + " of " + std::to_string(n) +
                                " points have neither (try --method poisson)");
  }
  if (options.watertight && cloud.views.empty()) {
    return InvalidArgumentError("watertight fusion needs each point's camera (a cloud.ply written by rotoscan "
                                "process carries the camera path)");
  }
  std::vector<Sample> table;
  if (options.flat_bottom) table = TableSamples(options, samples);

  // The volume's box, padded by the largest reach.
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  Eigen::Vector3f hi = -lo;
  for (const auto* batch : {&samples, &table}) {
    for (const Sample& s : *batch) {
      lo = lo.cwiseMin(s.p);
      hi = hi.cwiseMax(s.p);
    }
  }
  const float pad = std::max(truncation, 4.0f * h) + 2.0f * h;
  lo.array() -= pad;
  hi.array() += pad;
  const Eigen::Vector3d extent_blocks = ((hi - lo) / (h * kBlock)).cast<double>();
  if ((extent_blocks.array() + 1).prod() > static_cast<double>(kMaxBlocks)) {
    return InvalidArgumentError("the cloud spans " + std::to_string(static_cast<int>((hi - lo).maxCoeff())) +
                                " mm: too large for " + std::to_string(options.voxel_mm) +
                                " mm voxels (use a larger voxel or remove the far points)");
  }
  const Eigen::Vector3i dims = (extent_blocks.array().ceil() + 1).cast<int>();
  Volume volume(lo.cast<double>(), options.voxel_mm, dims);

  // Splat on `threads` slabs of block columns, cut at quantiles of the samples' x.
  std::vector<int> cuts(static_cast<std::size_t>(threads) + 1, 0);
  {
    std::vector<float> xs(samples.size());
    for (std::size_t i = 0; i < samples.size(); ++i) xs[i] = samples[i].p.x();
    for (int t = 1; t < threads; ++t) {
      auto at = xs.begin() + static_cast<std::ptrdiff_t>(xs.size() * static_cast<std::size_t>(t) /
                                                         static_cast<std::size_t>(threads));
      std::nth_element(xs.begin(), at, xs.end());
      cuts[static_cast<std::size_t>(t)] =
          std::clamp(static_cast<int>((*at - lo.x()) / (h * kBlock)), cuts[static_cast<std::size_t>(t) - 1],
                     dims.x()) *
          kBlock;
    }
    cuts.back() = dims.x() * kBlock;
  }
  const float floor = options.flat_bottom ? static_cast<float>(options.table_z) : -std::numeric_limits<float>::max();
  std::vector<std::vector<std::unique_ptr<Block>>> pools(static_cast<std::size_t>(threads));
  auto splat = [&](const std::vector<Sample>& batch) {
    std::vector<std::thread> pool;
    for (int t = 1; t < threads; ++t) {
      pool.emplace_back(Splat, std::cref(batch), truncation, floor, cuts[static_cast<std::size_t>(t)],
                        cuts[static_cast<std::size_t>(t) + 1], &volume, &pools[static_cast<std::size_t>(t)]);
    }
    Splat(batch, truncation, floor, cuts[0], cuts[1], &volume, &pools[0]);
    for (std::thread& t : pool) t.join();
  };
  // The allocated blocks with their coordinates.
  struct BlockRef {
    Block* block;
    Eigen::Vector3i at;
  };
  std::vector<BlockRef> blocks;
  auto list_blocks = [&] {
    blocks.clear();
    for (int bk = 0; bk < dims.z(); ++bk) {
      for (int bj = 0; bj < dims.y(); ++bj) {
        for (int bi = 0; bi < dims.x(); ++bi) {
          if (Block* b = volume.Slot(bi, bj, bk)) blocks.push_back({b, {bi, bj, bk}});
        }
      }
    }
  };
  splat(samples);
  list_blocks();
  // The median weight of the voxels next to the surface: trimming keeps cubes above a fraction of it, and
  // the table's samples weigh as much as the scan's.
  float median_weight = 1.0f;
  {
    std::vector<float> near;
    for (const BlockRef& ref : blocks) {
      for (int v = 0; v < kBlockVoxels; v += 3) {
        const auto sv = static_cast<std::size_t>(v);
        const float w = ref.block->weight[sv];
        if (w > 0 && std::abs(ref.block->sdf[sv]) < 0.5f * h * w) near.push_back(w);
      }
    }
    if (!near.empty()) {
      auto mid = near.begin() + static_cast<std::ptrdiff_t>(near.size() / 2);
      std::nth_element(near.begin(), mid, near.end());
      median_weight = *mid;
    }
  }
  const float min_weight = std::max(1e-6f, static_cast<float>(options.min_weight_fraction) * median_weight);
  if (!table.empty()) {
    // A voxel under the footprint is reached by ~7 table samples (spacing h, radius 1.5 h).
    for (Sample& t : table) t.weight = median_weight / 4.0f;
    splat(table);
    list_blocks();
  }
  Parallel(threads, blocks.size(), [&](int, std::size_t begin, std::size_t end) {
    for (std::size_t b = begin; b < end; ++b) {
      Block& block = *blocks[b].block;
      for (int v = 0; v < kBlockVoxels; ++v) {
        const float w = block.weight[static_cast<std::size_t>(v)];
        if (w > 0) {
          block.sdf[static_cast<std::size_t>(v)] /= w;
          block.rgb[static_cast<std::size_t>(v)] /= w;
        }
      }
    }
  });
  const double splat_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  scope.Advance();

  // Components (union-find over the triangles' vertices); the small ones go, with unused vertices.
  auto finish = [&](TriangleMesh mesh) -> Result<TriangleMesh> {
    std::vector<int> parent(mesh.vertices.size());
    std::iota(parent.begin(), parent.end(), 0);
    auto find = [&](int x) {
      while (parent[static_cast<std::size_t>(x)] != x) {
        parent[static_cast<std::size_t>(x)] = parent[static_cast<std::size_t>(parent[static_cast<std::size_t>(x)])];
        x = parent[static_cast<std::size_t>(x)];
      }
      return x;
    };
    for (const Eigen::Vector3i& t : mesh.triangles) {
      for (int c = 1; c < 3; ++c) {
        const int a = find(t[0]), b = find(t[c]);
        if (a != b) parent[static_cast<std::size_t>(std::max(a, b))] = std::min(a, b);
      }
    }
    std::vector<std::size_t> size(mesh.vertices.size(), 0);
    for (const Eigen::Vector3i& t : mesh.triangles) ++size[static_cast<std::size_t>(find(t[0]))];
    const double least = options.min_component_fraction * static_cast<double>(mesh.triangles.size());
    std::size_t removed_components = 0;
    for (std::size_t v = 0; v < size.size(); ++v) {
      if (size[v] > 0 && static_cast<double>(size[v]) < least) ++removed_components;
    }
    std::vector<int> remap(mesh.vertices.size(), -1);
    TriangleMesh kept;
    kept.triangles.reserve(mesh.triangles.size());
    for (const Eigen::Vector3i& t : mesh.triangles) {
      if (static_cast<double>(size[static_cast<std::size_t>(find(t[0]))]) < least) continue;
      Eigen::Vector3i u;
      for (int c = 0; c < 3; ++c) {
        int& r = remap[static_cast<std::size_t>(t[c])];
        if (r < 0) {
          r = static_cast<int>(kept.vertices.size());
          kept.vertices.push_back(mesh.vertices[static_cast<std::size_t>(t[c])]);
          kept.vertex_colors.push_back(mesh.vertex_colors[static_cast<std::size_t>(t[c])]);
        }
        u[c] = r;
      }
      if (u[0] != u[1] && u[1] != u[2] && u[0] != u[2]) kept.triangles.push_back(u);
    }
    scope.Advance();
    if (kept.triangles.empty()) return NotConvergedError("fusion produced no surface (too few or too sparse points?)");
    VertexColorSummary colors;
    if (options.color_radius_voxels > 0 && cloud.colors.size() == n) {
      ROTOSCAN_RETURN_IF_ERROR(
          ColorVerticesFromPoints(cloud, options.color_radius_voxels * options.voxel_mm, &kept, &colors));
    }
    if (summary != nullptr) {
      summary->colored_from_points = colors.from_points;
      summary->colored_from_neighbours = colors.from_neighbours;
      summary->input_points = n;
      summary->blocks = blocks.size();
      summary->removed_components = removed_components;
      summary->removed_triangles = mesh.triangles.size() - kept.triangles.size();
      summary->splat_seconds = splat_seconds;
      summary->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      summary->extract_seconds = summary->seconds - splat_seconds;
    }
    ROTOSCAN_LOG(kDebug) << "fusion " << options.voxel_mm << " mm: " << n << " points, " << blocks.size()
                         << " blocks -> " << kept.vertices.size() << " vertices, " << kept.triangles.size()
                         << " triangles";
    return kept;
  };
  if (options.watertight) {
    ClosedStats closed;
    ROTOSCAN_ASSIGN_OR_RETURN(TriangleMesh mesh, ExtractClosed(volume, samples, cloud.cameras, min_weight,
                                                               truncation, options, threads, &closed));
    scope.Advance();
    if (summary != nullptr) {
      summary->carved_point_rays = closed.point_rays;
      summary->carved_table_rays = closed.table_rays;
      summary->discarded_rays = closed.discarded;
      summary->observed_vertex_fraction = closed.observed_fraction;
    }
    return finish(std::move(mesh));
  }

  // Marching cubes, pass 1: a vertex on each voxel's forward edges (+x, +y, +z) that crosses zero between
  // two voxels of enough weight. A crossing between values further apart than the distance can change over
  // one voxel (two opposite truncated bands meeting) is no surface.
  const float max_jump = 2.0f * h;
  std::vector<std::vector<std::array<int, 3>>> edge_vertex(blocks.size());
  std::vector<Extracted> per_block(blocks.size());
  auto value = [&](int i, int j, int k, float* sdf, float* w) {
    const Block* b = volume.Find(i, j, k);
    if (b == nullptr) return false;
    const auto v = static_cast<std::size_t>(LocalIndex(i, j, k));
    *sdf = b->sdf[v];
    *w = b->weight[v];
    return *w >= min_weight;
  };
  Parallel(threads, blocks.size(), [&](int, std::size_t begin, std::size_t end) {
    for (std::size_t b = begin; b < end; ++b) {
      const Block& block = *blocks[b].block;
      auto& edges = edge_vertex[b];
      edges.assign(kBlockVoxels, {-1, -1, -1});
      Extracted& out = per_block[b];
      const Eigen::Vector3i base = blocks[b].at * kBlock;
      for (int v = 0; v < kBlockVoxels; ++v) {
        const auto sv = static_cast<std::size_t>(v);
        const float w0 = block.weight[sv];
        if (w0 < min_weight) continue;
        const float s0 = block.sdf[sv];
        const Eigen::Vector3i at = base + Eigen::Vector3i(v & 7, (v >> 3) & 7, v >> 6);
        for (int axis = 0; axis < 3; ++axis) {
          Eigen::Vector3i next = at;
          ++next[axis];
          float s1 = 0, w1 = 0;
          if (!value(next.x(), next.y(), next.z(), &s1, &w1)) continue;
          if ((s0 < 0) == (s1 < 0) || std::abs(s0 - s1) > max_jump) continue;
          const float t = s0 / (s0 - s1);
          Eigen::Vector3f p = volume.Centre(at.x(), at.y(), at.z());
          p[axis] += t * h;
          const Block* nb = volume.Find(next.x(), next.y(), next.z());
          const Eigen::Vector3f c =
              (1 - t) * block.rgb[sv] + t * nb->rgb[static_cast<std::size_t>(LocalIndex(next.x(), next.y(), next.z()))];
          edges[sv][static_cast<std::size_t>(axis)] = static_cast<int>(out.vertices.size());
          out.vertices.push_back(p.cast<double>());
          out.colors.push_back(c.cwiseMax(0.0f).cwiseMin(1.0f).cast<double>());
        }
      }
    }
  });
  std::vector<std::size_t> offset(blocks.size() + 1, 0);
  for (std::size_t b = 0; b < blocks.size(); ++b) offset[b + 1] = offset[b] + per_block[b].vertices.size();
  std::vector<int> block_of(static_cast<std::size_t>(dims.prod()), -1);
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    block_of[volume.BlockIndex(blocks[b].at.x(), blocks[b].at.y(), blocks[b].at.z())] = static_cast<int>(b);
  }
  // Pass 2: the triangles of every cube whose corners all hold enough weight.
  auto edge_index = [&](const Eigen::Vector3i& at, int axis) -> long long {
    if ((at.array() < 0).any()) return -1;
    const Eigen::Vector3i bl = at / kBlock;
    if ((bl.array() >= dims.array()).any()) return -1;
    const int b = block_of[volume.BlockIndex(bl.x(), bl.y(), bl.z())];
    if (b < 0) return -1;
    const int local = edge_vertex[static_cast<std::size_t>(b)][static_cast<std::size_t>(
        LocalIndex(at.x(), at.y(), at.z()))][static_cast<std::size_t>(axis)];
    return local < 0 ? -1 : static_cast<long long>(offset[static_cast<std::size_t>(b)]) + local;
  };
  Parallel(threads, blocks.size(), [&](int, std::size_t begin, std::size_t end) {
    for (std::size_t b = begin; b < end; ++b) {
      const Eigen::Vector3i base = blocks[b].at * kBlock;
      const Block& block = *blocks[b].block;
      Extracted& out = per_block[b];
      for (int v = 0; v < kBlockVoxels; ++v) {
        if (block.weight[static_cast<std::size_t>(v)] < min_weight) continue;
        const Eigen::Vector3i at = base + Eigen::Vector3i(v & 7, (v >> 3) & 7, v >> 6);
        int cube = 0;
        bool complete = true;
        for (int c = 0; c < 8 && complete; ++c) {
          const Eigen::Vector3i corner = at + shift[c];
          float s = 0, w = 0;
          complete = value(corner.x(), corner.y(), corner.z(), &s, &w);
          if (s < 0) cube |= 1 << c;
        }
        if (!complete || cube == 0 || cube == 255) continue;
        std::array<long long, 12> vertex;
        vertex.fill(-1);
        bool ok = true;
        for (int e = 0; e < 12 && ok; ++e) {
          if ((edge_table[cube] & (1 << e)) == 0) continue;
          vertex[static_cast<std::size_t>(e)] =
              edge_index(at + edge_shift[e].head<3>(), edge_shift[e][3]);
          ok = vertex[static_cast<std::size_t>(e)] >= 0;
        }
        if (!ok) continue;  // a crossing judged no surface: leave the cube open
        for (int t = 0; tri_table[cube][t] != -1; t += 3) {
          // The table lists triangles clockwise seen from the inside-set corners: reversed, they face out.
          out.triangles.emplace_back(static_cast<int>(vertex[static_cast<std::size_t>(tri_table[cube][t])]),
                                     static_cast<int>(vertex[static_cast<std::size_t>(tri_table[cube][t + 2])]),
                                     static_cast<int>(vertex[static_cast<std::size_t>(tri_table[cube][t + 1])]));
        }
      }
    }
  });
  TriangleMesh mesh;
  mesh.vertices.reserve(offset.back());
  mesh.vertex_colors.reserve(offset.back());
  std::size_t triangle_count = 0;
  for (const Extracted& e : per_block) triangle_count += e.triangles.size();
  mesh.triangles.reserve(triangle_count);
  for (Extracted& e : per_block) {
    mesh.vertices.insert(mesh.vertices.end(), e.vertices.begin(), e.vertices.end());
    mesh.vertex_colors.insert(mesh.vertex_colors.end(), e.colors.begin(), e.colors.end());
    mesh.triangles.insert(mesh.triangles.end(), e.triangles.begin(), e.triangles.end());
    e = Extracted{};
  }
  pools.clear();
  scope.Advance();

  return finish(std::move(mesh));
}

}  // namespace rotoscan::mesh
