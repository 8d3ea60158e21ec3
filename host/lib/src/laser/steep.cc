// RecentreSteepLines (extract_steps.h): a steep line's centre measured across the line.
//
// Where the line runs along the rows (the table top's line, a surface seen at a grazing angle), a row cuts
// it obliquely: the row's profile is the line's own, stretched by L = sqrt(1 + s^2) (s: columns per row),
// and its centre of mass along the row errs by L times its error across the line, from the few pixels of
// one row. Here such a point's centre is measured across the line instead: the line's direction and
// curvature from the neighbouring rows' points (least squares over kSteepFitRows rows either side), then the
// centre of mass of the difference, over the pixels within kSteepAlongPx of the point along the line and
// within the line's width across it, of their distance across the line (pixels of several rows, as a column
// profile would be for a horizontal line). The point is put where that centre's line (same slope) crosses
// the row: the row's column moves by L times the offset across. A vertical line (|s| under kSteepSlope)
// costs only its slope's test.
#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "extract_steps.h"
#include "kernels.h"

namespace rotoscan::laser::detail {
namespace {

// The next iteration's stretch of a row reuses the last one's sums when neither end moved more than this.
constexpr int kSteepEdgePx = 6;

// A row's window sums (WindowSums, but in absolute columns) over [c_first, c_last] (none: c_first > c_last).
struct RowSums {
  int c_first = 0, c_last = -1;
  int64_t count = 0, sum_d = 0, sum_c = 0, sum_dc = 0;
  // Adds (sign 1) or removes (-1) pixel c, by SteepWindowSums' rule.
  void Add(const uint8_t* a, const uint8_t* b, int step, int c, int threshold, int min_d, int sign) {
    const int av = a[c * step], bv = b[c * step];
    const int d = av == 255 && bv <= 255 - threshold ? 255 : std::max(av - bv, 0);
    if (d < min_d) return;
    count += sign;
    sum_d += sign * d;
    sum_c += sign * c;
    sum_dc += int64_t{sign} * d * c;
  }
};

}  // namespace
int RecentreSteepLines(const cv::Mat& on, const cv::Mat& off, int channel, int threshold,
                       std::vector<LinePoint>* line_points) {
  std::vector<LinePoint>& p = *line_points;
  const size_t n = p.size();
  const int rows = on.rows, cols = on.cols;
  std::vector<float> moved(n);
  for (size_t i = 0; i < n; ++i) moved[i] = p[i].column;
  int count = 0;
  for (size_t i = 0; i < n; ++i) {
    // The stretch around the point: rows at most 2 apart, at most kSteepMaxStepPx columns per row.
    auto joined = [&](size_t a, size_t b) {
      const int gap = p[b].row - p[a].row;
      return gap <= 2 && std::abs(p[b].column - p[a].column) <= kSteepMaxStepPx * gap;
    };
    // A point with an adjacent neighbour less than half kSteepSlope away on either side is on a vertical
    // stretch: nothing more to do (the common case).
    if ((i > 0 && p[i - 1].row + 1 == p[i].row &&
         std::abs(p[i].column - p[i - 1].column) < 0.5 * kSteepSlope) ||
        (i + 1 < n && p[i + 1].row == p[i].row + 1 &&
         std::abs(p[i + 1].column - p[i].column) < 0.5 * kSteepSlope))
      continue;
    size_t lo = i, hi = i;
    while (lo > 0 && p[lo - 1].row >= p[i].row - kSteepFitRows && joined(lo - 1, lo)) --lo;
    while (hi + 1 < n && p[hi + 1].row <= p[i].row + kSteepFitRows && joined(hi, hi + 1)) ++hi;
    if (hi - lo + 1 < kSteepMinPoints) continue;  // too few rows for a direction and a test of it
    // The line's column against the row near the point: column = c0 + s dr + k dr^2 (dr = row - r0), by
    // least squares through the stretch's points (at least kSteepMinPoints) relative to the point. The
    // curvature matters: a straight model of a curved line puts the centre of mass on the concave side by
    // about k L^3 along^2 / 6.
    const int r0 = p[i].row;
    const double c0 = p[i].column;
    // The normal equations for (offset, s, k): their matrix holds sums of dr^0..dr^4 over whole rows,
    // summed in integers (exact, as the doubles were: laser_bench, ~10 % of the step when built as Eigen
    // outer products), the right-hand side in doubles.
    int64_t powers[5] = {0, 0, 0, 0, 0};
    Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
    for (size_t k = lo; k <= hi; ++k) {
      const int64_t dr = p[k].row - r0;
      powers[0] += 1;
      powers[1] += dr;
      powers[2] += dr * dr;
      powers[3] += dr * dr * dr;
      powers[4] += dr * dr * dr * dr;
      const double y = p[k].column - c0, drd = static_cast<double>(dr);
      rhs[0] += y;
      rhs[1] += drd * y;
      rhs[2] += (drd * drd) * y;
    }
    Eigen::Matrix3d normal;
    for (int row = 0; row < 3; ++row)
      for (int col = 0; col < 3; ++col) normal(row, col) = static_cast<double>(powers[row + col]);
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(normal);
    if (ldlt.info() != Eigen::Success) continue;
    const Eigen::Vector3d x = ldlt.solve(rhs);
    if (!x.allFinite()) continue;
    const double s = x[1], curvature = x[2];
    if (std::abs(s) < kSteepSlope) continue;
    const double length = std::sqrt(1.0 + s * s);
    // A line, not rows that merely lie near each other: the points' RMS distance along their rows from
    // the fit (per degree of freedom) is at most kSteepMaxResidual (1 + L) px (a row's error is L times one
    // across the line).
    double residual2 = 0;
    for (size_t k = lo; k <= hi; ++k) {
      const double dr = p[k].row - r0;
      const double e = p[k].column - (c0 + x[0] + s * dr + curvature * dr * dr);
      residual2 += e * e;
    }
    if (residual2 > kSteepMaxResidual * kSteepMaxResidual * (1.0 + length) * (1.0 + length) *
                        static_cast<double>(hi - lo + 1 - 3))
      continue;
    // Across the line, the row's width divided by L; the window is that width either side.
    const double half = std::max(kSteepMinHalfPx, p[i].width / length);
    const double level = kComLevelNum * static_cast<double>(p[i].peak) / kComScale;
    // The bounding box of the window (|across - t| <= half, |along| <= kSteepAlongPx).
    const double row_reach = (kSteepAlongPx + half * std::abs(s)) / length + 1.0;
    const int r_first = std::max(0, static_cast<int>(std::floor(r0 - row_reach)));
    const int r_last = std::min(rows - 1, static_cast<int>(std::ceil(r0 + row_reach)));
    double t = 0;  // the centre's offset across the line from the row's point, px
    bool ok = true;
    // The weights' level as an integer test: for a whole difference d, d - level > 0 exactly where
    // d >= floor(level) + 1 (whatever the peak, a whole number of DN or not). No pixel passes over 255.
    const int min_d = static_cast<int>(std::floor(level)) + 1;
    if (min_d > 255) continue;
    const int step = on.channels();
    // Each row's sums of the last iteration, with their stretch and in absolute columns, so that the next
    // iteration (t moves the stretch by a pixel or two) adds and removes the pixels at its ends instead of
    // summing it again: the same integers.
    thread_local std::vector<RowSums> kept;
    kept.assign(static_cast<size_t>(r_last - r_first + 1), RowSums{});
    for (int iteration = 0; iteration < kSteepIterations && ok; ++iteration) {
      double sum_w = 0, sum_wt = 0;
      for (int r = r_first; r <= r_last; ++r) {
        const double dr = r - r0;
        // The window's pixels in row r are a run of columns: across the line (across - t within
        // +-half) they lie within half L of the centre's line, and along it (|along| <= kSteepAlongPx)
        // (c - c0) s is within -dr +- kSteepAlongPx L. Over that run the sums are the difference's, in
        // integers (exact, any order), and the level's and the line's position are taken out per row:
        // sum of w (c - line) = sum d (c - c_first) - level sum (c - c_first) + (c_first - line) sum w,
        // across = (c - line) / L. (Before, the same sums pixel by pixel in doubles over the window's
        // bounding box: the same pixels but for rounding at the window's edge, 1e-12 px; laser_bench:
        // this step was ~90 % of a frame whose line is steep in half its rows.)
        const double line = c0 + s * dr + curvature * dr * dr;  // the line's column in row r
        const double centre = line + t * length;
        const double along_a = c0 + (-dr - kSteepAlongPx * length) / s;
        const double along_b = c0 + (-dr + kSteepAlongPx * length) / s;
        const int c_first = std::max({0, static_cast<int>(std::ceil(std::min(along_a, along_b))),
                                      static_cast<int>(std::ceil(centre - half * length))});
        const int c_last = std::min({cols - 1, static_cast<int>(std::floor(std::max(along_a, along_b))),
                                     static_cast<int>(std::floor(centre + half * length))});
        if (c_first > c_last) continue;
        const uint8_t* a = on.ptr<uint8_t>(r) + channel;
        const uint8_t* b = off.ptr<uint8_t>(r) + channel;
        RowSums& k = kept[static_cast<size_t>(r - r_first)];
        if (k.c_first <= k.c_last && std::abs(c_first - k.c_first) <= kSteepEdgePx &&
            std::abs(c_last - k.c_last) <= kSteepEdgePx && c_first <= k.c_last && k.c_first <= c_last) {
          // The last stretch's sums, its ends moved to [c_first, c_last].
          for (int c = c_first; c < k.c_first; ++c) k.Add(a, b, step, c, threshold, min_d, 1);
          for (int c = k.c_first; c < c_first; ++c) k.Add(a, b, step, c, threshold, min_d, -1);
          for (int c = k.c_last + 1; c <= c_last; ++c) k.Add(a, b, step, c, threshold, min_d, 1);
          for (int c = c_last + 1; c <= k.c_last; ++c) k.Add(a, b, step, c, threshold, min_d, -1);
        } else {
          const WindowSums sums = SteepWindowSums(a, b, step, c_first, c_last, cols, threshold, min_d);  // kernels.h
          k.count = sums.count;
          k.sum_d = sums.sum_d;
          k.sum_c = sums.sum_offset + int64_t{c_first} * sums.count;
          k.sum_dc = sums.sum_d_offset + int64_t{c_first} * sums.sum_d;
        }
        k.c_first = c_first;
        k.c_last = c_last;
        if (k.count == 0) continue;
        // The sums relative to c_first, as SteepWindowSums gives them.
        const int64_t sum_offset = k.sum_c - int64_t{c_first} * k.count;
        const int64_t sum_d_offset = k.sum_dc - int64_t{c_first} * k.sum_d;
        const double w = k.sum_d - level * k.count;
        sum_w += w;
        sum_wt += sum_d_offset - level * sum_offset + (c_first - line) * w;  // times L: across
      }
      if (sum_w <= 0) {
        ok = false;
        break;
      }
      t = sum_wt / length / sum_w;
    }
    if (!ok) continue;
    // As the smoothing (LimitSmoothing), the point moves by at most its own uncertainty along the row.
    const double limit = p[i].uncertainty_px;
    moved[i] = static_cast<float>(c0 + std::clamp(t * length, -limit, limit));
    ++count;
  }
  for (size_t i = 0; i < n; ++i) p[i].column = moved[i];
  return count;
}

}  // namespace rotoscan::laser::detail
