#include "rotoscan/laser/triangulate.h"

#include <algorithm>
#include <cmath>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

#include "rotoscan/core/check.h"

namespace rotoscan::laser {
namespace {

constexpr double kSixth = 1.0 / 6.0;

// The ray-plane intersection of the ray (x, y, 1): the point t (x, y, 1) with n . (t (x, y, 1)) + offset = 0.
// Written out (not Eigen's dot, whose summation order is its own) so that TriangulateTableAvx2 adds in the
// same order and gives the same bits.
struct Hit {
  double t, denominator;
};
inline Hit Intersect(const geometry::Plane& plane, double x, double y) {
  const double denominator = plane.normal.x() * x + plane.normal.y() * y + plane.normal.z();
  return {-plane.offset / denominator, denominator};
}
inline bool Valid(const Hit& hit) { return std::abs(hit.denominator) >= 1e-12 && hit.t > 0; }

#if defined(__x86_64__) || defined(__i386__)
// For TriangulateTableAvx2: of points p[0..3], the rows, whether they lie in the image, u and its node g
// as in RayUnchecked (std::clamp, then x / 8 computed as x * 0.125, the same number), and the table
// offsets (row * nodes_per_row + g - 1) * 2 (rows outside the image read row 0; their points are dropped).
struct Block {
  __m128i row, inside, g, at;
  __m256d u;
};
__attribute__((target("avx2"))) inline Block BlockOf(const LinePoint* p, int height, int nodes_per_row,
                                                     double column_max, double column_step) {
  Block b;
  b.row = _mm_setr_epi32(p[0].row, p[1].row, p[2].row, p[3].row);
  b.inside = _mm_andnot_si128(_mm_cmpgt_epi32(_mm_setzero_si128(), b.row),
                              _mm_cmpgt_epi32(_mm_set1_epi32(height), b.row));
  const __m256d column = _mm256_cvtps_pd(_mm_setr_ps(p[0].column, p[1].column, p[2].column, p[3].column));
  const __m256d clamped = _mm256_min_pd(_mm256_max_pd(column, _mm256_set1_pd(-0.5)), _mm256_set1_pd(column_max));
  b.u = _mm256_mul_pd(_mm256_add_pd(clamped, _mm256_set1_pd(2 * column_step)), _mm256_set1_pd(1.0 / column_step));
  b.g = _mm256_cvttpd_epi32(b.u);
  b.at = _mm_slli_epi32(_mm_add_epi32(_mm_mullo_epi32(_mm_and_si128(b.row, b.inside), _mm_set1_epi32(nodes_per_row)),
                                      _mm_sub_epi32(b.g, _mm_set1_epi32(1))),
                        1);
  return b;
}

// Triangulate's loop over the table (distorted camera), 4 points per turn, for the first count - count % 4
// points: the same operations as RayUnchecked and Intersect in the same order, in double and without
// fused multiply-adds, so every point is the same to the bit as on the scalar path (tested). The table's
// values are taken two nodes per 128-bit load and paired so that each 256-bit vector holds (x, y) of two
// points, the layout of the output's Vector3d. Returns the number of invalid points; kept[i] is i or -1.
__attribute__((target("avx2"))) size_t TriangulateTableAvx2(const LinePoint* points, size_t count,
                                                            const float* table, int nodes_per_row, int height,
                                                            double column_max, double column_step,
                                                            const geometry::Plane& plane, double* out, int* kept) {
  const __m256d c1 = _mm256_set1_pd(1.0), c2 = _mm256_set1_pd(2.0), sixth = _mm256_set1_pd(kSixth);
  const __m256d half = _mm256_set1_pd(0.5), sign = _mm256_set1_pd(-0.0);
  const __m256d normal_xy = _mm256_setr_pd(plane.normal.x(), plane.normal.y(), plane.normal.x(), plane.normal.y());
  const __m256d normal_z = _mm256_set1_pd(plane.normal.z()), minus_offset = _mm256_set1_pd(-plane.offset);
  const __m256d abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffff));
  const __m256d tiny = _mm256_set1_pd(1e-12);
  // The table (1.3 MB at 1288x964) is read one row apart per point, and the frames streamed through the
  // cache just before: the entries two turns ahead are fetched while this turn computes. Each block of 4
  // is worked out once, when it is two turns ahead, and carried to its turn.
  Block current{}, next{};
  if (count >= 4) current = BlockOf(points, height, nodes_per_row, column_max, column_step);
  if (count >= 8) next = BlockOf(points + 4, height, nodes_per_row, column_max, column_step);
  size_t invalid = 0;
  for (size_t i = 0; i + 4 <= count; i += 4) {
    Block ahead{};
    if (i + 12 <= count) {
      ahead = BlockOf(points + i + 8, height, nodes_per_row, column_max, column_step);
      alignas(16) int at_ahead[4];
      _mm_store_si128(reinterpret_cast<__m128i*>(at_ahead), ahead.at);
      for (int j = 0; j < 4; ++j) _mm_prefetch(reinterpret_cast<const char*>(table + at_ahead[j]), _MM_HINT_T0);
    }
    const __m256d u = current.u;
    const __m128i g = current.g, inside = current.inside;
    alignas(16) int at[4];
    _mm_store_si128(reinterpret_cast<__m128i*>(at), current.at);
    current = next;
    next = ahead;
    const __m256d t = _mm256_sub_pd(u, _mm256_cvtepi32_pd(g));
    const __m256d tm1 = _mm256_sub_pd(t, c1), tm2 = _mm256_sub_pd(t, c2), tp1 = _mm256_add_pd(t, c1);
    const __m256d w[4] = {
        _mm256_mul_pd(_mm256_mul_pd(_mm256_mul_pd(_mm256_xor_pd(t, sign), tm1), tm2), sixth),
        _mm256_mul_pd(_mm256_mul_pd(_mm256_mul_pd(tp1, tm1), tm2), half),
        _mm256_mul_pd(_mm256_mul_pd(_mm256_mul_pd(_mm256_xor_pd(tp1, sign), t), tm2), half),
        _mm256_mul_pd(_mm256_mul_pd(_mm256_mul_pd(tp1, t), tm1), sixth)};
    __m256d ray[2];  // (x, y) of points 0 and 1, of points 2 and 3
    for (int half_block = 0; half_block < 2; ++half_block) {
      const float* e0 = table + at[2 * half_block];
      const float* e1 = table + at[2 * half_block + 1];
      const __m128d a01 = _mm_castps_pd(_mm_loadu_ps(e0)), a23 = _mm_castps_pd(_mm_loadu_ps(e0 + 4));
      const __m128d b01 = _mm_castps_pd(_mm_loadu_ps(e1)), b23 = _mm_castps_pd(_mm_loadu_ps(e1 + 4));
      const __m128d node[4] = {_mm_unpacklo_pd(a01, b01), _mm_unpackhi_pd(a01, b01), _mm_unpacklo_pd(a23, b23),
                               _mm_unpackhi_pd(a23, b23)};
      __m256d sum = _mm256_setzero_pd();
      for (int k = 0; k < 4; ++k) {
        const __m256d wk = half_block == 0 ? _mm256_permute4x64_pd(w[k], 0x50) : _mm256_permute4x64_pd(w[k], 0xFA);
        const __m256d term = _mm256_mul_pd(wk, _mm256_cvtps_pd(_mm_castpd_ps(node[k])));
        sum = k == 0 ? term : _mm256_add_pd(sum, term);
      }
      ray[half_block] = sum;
    }
    // Denominators n.x x + n.y y + n.z in the order of points (hadd gives 0, 2, 1, 3).
    const __m256d dots = _mm256_hadd_pd(_mm256_mul_pd(ray[0], normal_xy), _mm256_mul_pd(ray[1], normal_xy));
    const __m256d denominator = _mm256_permute4x64_pd(_mm256_add_pd(dots, normal_z), 0xD8);
    const __m256d tt = _mm256_div_pd(minus_offset, denominator);
    const __m256d ok = _mm256_and_pd(
        _mm256_and_pd(_mm256_cmp_pd(_mm256_and_pd(denominator, abs_mask), tiny, _CMP_GE_OQ),
                      _mm256_cmp_pd(tt, _mm256_setzero_pd(), _CMP_GT_OQ)),
        _mm256_castsi256_pd(_mm256_cvtepi32_epi64(inside)));
    const int valid = _mm256_movemask_pd(ok);
    const __m256d xy01 = _mm256_mul_pd(ray[0], _mm256_permute4x64_pd(tt, 0x50));
    const __m256d xy23 = _mm256_mul_pd(ray[1], _mm256_permute4x64_pd(tt, 0xFA));
    const __m128d t01 = _mm256_castpd256_pd128(tt), t23 = _mm256_extractf128_pd(tt, 1);
    double* o = out + 3 * i;
    _mm_storeu_pd(o, _mm256_castpd256_pd128(xy01));
    _mm_store_sd(o + 2, t01);
    _mm_storeu_pd(o + 3, _mm256_extractf128_pd(xy01, 1));
    _mm_storeh_pd(o + 5, t01);
    _mm_storeu_pd(o + 6, _mm256_castpd256_pd128(xy23));
    _mm_store_sd(o + 8, t23);
    _mm_storeu_pd(o + 9, _mm256_extractf128_pd(xy23, 1));
    _mm_storeh_pd(o + 11, t23);
    for (int j = 0; j < 4; ++j) kept[i + j] = (valid >> j & 1) ? static_cast<int>(i) + j : -1;
    invalid += 4 - static_cast<size_t>(__builtin_popcount(static_cast<unsigned>(valid)));
  }
  return invalid;
}
#endif

}  // namespace

Triangulator::Triangulator(const geometry::CameraModel& camera) : camera_(camera) {
  const Status status = camera_.Validate();
  ROTOSCAN_CHECK(status.ok()) << status.ToString();
  distorted_ = camera_.HasDistortion();
  if (!distorted_) return;
  // Nodes at columns (k - 2) * kColumnStep, k = 0 .. nodes_per_row_ - 1: two before column 0 and enough
  // after width - 1 that every column in [-0.5, width - 0.5] has its four cubic taps.
  nodes_per_row_ = static_cast<int>(std::floor((camera_.width - 0.5 + 2 * kColumnStep) / kColumnStep)) + 3;
  normalized_.resize(static_cast<size_t>(nodes_per_row_) * camera_.height * 2);
  for (int r = 0; r < camera_.height; ++r) {
    float* out = normalized_.data() + static_cast<size_t>(r) * nodes_per_row_ * 2;
    // Each node starts from its left neighbour's answer shifted by one node step: one or two
    // Gauss-Newton steps instead of the full iteration.
    Eigen::Vector2d n = camera_.Undistort(Eigen::Vector2d(-2.0 * kColumnStep, r));
    for (int k = 0; k < nodes_per_row_; ++k) {
      if (k > 0) {
        n = camera_.Undistort(Eigen::Vector2d((k - 2.0) * kColumnStep, r),
                              n + Eigen::Vector2d(kColumnStep / camera_.fx, 0.0));
      }
      out[2 * k] = static_cast<float>(n.x());
      out[2 * k + 1] = static_cast<float>(n.y());
    }
  }
}

const float* Triangulator::TableEntry(double column, int row) const {
  const double u = (std::clamp(column, -0.5, camera_.width - 0.5) + 2 * kColumnStep) / kColumnStep;
  return normalized_.data() + (static_cast<size_t>(row) * nodes_per_row_ + static_cast<size_t>(u) - 1) * 2;
}

inline Eigen::Vector3d Triangulator::RayUnchecked(double column, int row) const {
  if (!distorted_) {
    return Eigen::Vector3d((column - camera_.cx) / camera_.fx, (row - camera_.cy) / camera_.fy, 1.0);
  }
  // Cubic (4-point Lagrange) interpolation between the nodes of the row: exact for a cubic, so its error
  // is of the order of the lens map's fourth derivative times kColumnStep^4 / 24, less than the float
  // storage's ~3e-5 px for the lenses of the tests (triangulate_test.cc measures it).
  const double u = (std::clamp(column, -0.5, camera_.width - 0.5) + 2 * kColumnStep) / kColumnStep;
  const int g = static_cast<int>(u);  // the node at or left of the column
  const double t = u - g;
  // (Evaluated in this order, and as products with kSixth and 0.5, by TriangulateTableAvx2 too.)
  const double w0 = -t * (t - 1) * (t - 2) * kSixth, w1 = (t + 1) * (t - 1) * (t - 2) * 0.5;
  const double w2 = -(t + 1) * t * (t - 2) * 0.5, w3 = (t + 1) * t * (t - 1) * kSixth;
  const float* p = normalized_.data() + (static_cast<size_t>(row) * nodes_per_row_ + g - 1) * 2;
  return Eigen::Vector3d(w0 * p[0] + w1 * p[2] + w2 * p[4] + w3 * p[6],
                         w0 * p[1] + w1 * p[3] + w2 * p[5] + w3 * p[7], 1.0);
}

Eigen::Vector3d Triangulator::Ray(double column, int row) const {
  ROTOSCAN_CHECK(row >= 0 && row < camera_.height) << "row " << row;
  return RayUnchecked(column, row);
}

std::optional<Eigen::Vector3d> Triangulator::PointInCam(const geometry::Plane& plane_in_cam, double column,
                                                        int row) const {
  const Eigen::Vector3d ray = Ray(column, row);  // (Triangulate repeats this without the row check)
  const Hit hit = Intersect(plane_in_cam, ray.x(), ray.y());
  if (!Valid(hit)) return std::nullopt;
  return Eigen::Vector3d(hit.t * ray);
}

void Triangulator::Triangulate(const Line& line, const geometry::Plane& plane_in_cam,
                               std::vector<Eigen::Vector3d>* points_in_cam, std::vector<int>* kept) const {
  ROTOSCAN_CHECK(points_in_cam != nullptr && kept != nullptr);
  const size_t count = line.points.size();
  // Every point is written at its own index and counted when invalid (a row outside the image, a ray
  // parallel to the plane or meeting it behind the camera: rare); the invalid ones are squeezed out
  // afterwards. Writing at a running "next free" index instead chains every point's store to the previous
  // point's division and compare (laser_bench BM_TriangulateOnly, scalar: 13.1 µs that way, 10.1 this
  // way; the AVX2 loop 4.2-4.7 µs).
  points_in_cam->resize(count);
  kept->resize(count);
  Eigen::Vector3d* out_points = points_in_cam->data();
  int* out_kept = kept->data();
  size_t invalid = 0;
  size_t i = 0;
#if defined(__x86_64__) || defined(__i386__)
  if (distorted_ && internal::UseAvx2()) {
    invalid = TriangulateTableAvx2(line.points.data(), count, normalized_.data(), nodes_per_row_, camera_.height,
                                   camera_.width - 0.5, kColumnStep, plane_in_cam,
                                   reinterpret_cast<double*>(out_points), out_kept);
    i = count - count % 4;
  }
#endif
  constexpr size_t kPrefetchAhead = 8;  // as in TriangulateTableAvx2
  for (; i < count; ++i) {
    if (distorted_ && i + kPrefetchAhead < count) {
      const LinePoint& ahead = line.points[i + kPrefetchAhead];
      if (ahead.row >= 0 && ahead.row < camera_.height) __builtin_prefetch(TableEntry(ahead.column, ahead.row));
    }
    const LinePoint& p = line.points[i];
    const bool inside = p.row >= 0 && p.row < camera_.height;
    // PointInCam, inlined (a row outside the image reads row 0 of the table and is dropped).
    const Eigen::Vector3d ray = RayUnchecked(p.column, inside ? p.row : 0);
    const Hit hit = Intersect(plane_in_cam, ray.x(), ray.y());
    out_points[i] = hit.t * ray;
    const bool valid = inside && Valid(hit);
    out_kept[i] = valid ? static_cast<int>(i) : -1;
    invalid += !valid;
  }
  size_t out = count;
  if (invalid > 0) {
    out = 0;
    for (size_t k = 0; k < count; ++k) {
      if (out_kept[k] < 0) continue;
      out_points[out] = out_points[k];
      out_kept[out] = out_kept[k];
      ++out;
    }
  }
  points_in_cam->resize(out);
  kept->resize(out);
}

}  // namespace rotoscan::laser
