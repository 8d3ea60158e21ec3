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

namespace rotoscan::laser::detail {
namespace {

// The difference at (row, col) of channel `channel`, with step 1's rule for a laser-on pixel saturated
// over a laser-off one with headroom (extract.cc): it counts as 255.
inline int Difference(const cv::Mat& on, const cv::Mat& off, int channel, int threshold, int row, int col) {
  const int k = col * on.channels() + channel;
  const int a = on.ptr<uint8_t>(row)[k];
  const int b = off.ptr<uint8_t>(row)[k];
  if (a == 255 && b <= 255 - threshold) return 255;
  return std::max(a - b, 0);
}

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
    Eigen::Matrix3d normal = Eigen::Matrix3d::Zero();  // normal equations for (offset, s, k)
    Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
    for (size_t k = lo; k <= hi; ++k) {
      const double dr = p[k].row - r0;
      const Eigen::Vector3d basis(1.0, dr, dr * dr);
      normal += basis * basis.transpose();
      rhs += basis * (p[k].column - c0);
    }
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
    const double col_reach = (half + kSteepAlongPx) * length;
    double t = 0;  // the centre's offset across the line from the row's point, px
    bool ok = true;
    for (int iteration = 0; iteration < kSteepIterations && ok; ++iteration) {
      double sum_w = 0, sum_wt = 0;
      for (int r = r_first; r <= r_last; ++r) {
        const double dr = r - r0;
        const double centre = c0 + t * length + s * dr + curvature * dr * dr;  // the line's column in row r
        int c_first = std::max(0, static_cast<int>(std::floor(centre - col_reach)));
        int c_last = std::min(cols - 1, static_cast<int>(std::ceil(centre + col_reach)));
        // Only the columns that can pass the window's tests below are visited: |along| <= kSteepAlongPx
        // holds for (c - c0) s within -dr -+ kSteepAlongPx L, and |across - t| <= half for c within
        // centre -+ half L; each bound widened by a pixel, so that rounding never drops a pixel the exact
        // tests (unchanged, in the same order) would keep: the same pixels, summed in the same order as
        // over the whole bounding box (laser_bench: the box was ~5x the window, and this step ~85 % of
        // a frame whose line is steep in half its rows).
        const double along_a = c0 + (-dr - kSteepAlongPx * length) / s, along_b = c0 + (-dr + kSteepAlongPx * length) / s;
        c_first = std::max({c_first, static_cast<int>(std::floor(std::min(along_a, along_b))) - 1,
                            static_cast<int>(std::floor(centre - half * length)) - 1});
        c_last = std::min({c_last, static_cast<int>(std::ceil(std::max(along_a, along_b))) + 1,
                           static_cast<int>(std::ceil(centre + half * length)) + 1});
        for (int c = c_first; c <= c_last; ++c) {
          const double across = ((c - c0) - s * dr - curvature * dr * dr) / length;
          const double along = ((c - c0) * s + dr) / length;
          if (std::abs(across - t) > half || std::abs(along) > kSteepAlongPx) continue;
          const double w = Difference(on, off, channel, threshold, r, c) - level;
          if (w <= 0) continue;
          sum_w += w;
          sum_wt += w * across;
        }
      }
      if (sum_w <= 0) {
        ok = false;
        break;
      }
      t = sum_wt / sum_w;
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
