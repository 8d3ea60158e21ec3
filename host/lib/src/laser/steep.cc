// RecentreSteepLines (extract_steps.h): a steep line's centre measured across the line.
//
// Where the line runs along the rows (the table top's line, a surface seen at a grazing angle), a row cuts
// it obliquely: the row's profile is the line's own, stretched by L = sqrt(1 + s^2) (s: columns per row),
// and its centre of mass along the row errs by L times its error across the line, from the few pixels of
// one row. Here such a point's centre is measured across the line instead: the line's direction and
// curvature from the neighbouring rows' points (least squares over kSteepFitRows rows either side), then the
// centre of mass of the difference, over the columns within kSteepAlongPx of the point along the line and
// within the line's width across it, of their distance across the line (pixels of several rows, as a column
// profile would be for a horizontal line). The point is put where that centre's line (same slope) crosses
// the row: the row's column moves by L times the offset across. A vertical line (|s| under kSteepSlope)
// costs only its slope's test.
//
// The pixels are summed once per run of consecutive steep points, not once per point (the windows of
// neighbouring points overlap almost wholly; before, two windows a point, ~0.9 us a point, laser_bench).
// The run is one curve (its points' fitted columns joined by straight pieces, the end points' own lines
// beyond); each column near it gets its run of rows across that curve (within the nearest point's half
// width across the line, pixels whose difference passes that point's level), and each pixel is binned by
// its coordinate along the curve (kSteepBinsPerPx bins a px) into moments: sums of d and 1 times 1, c, r,
// r^2. A point's window is the bins within kSteepAlongPx of it along the line; its centre of mass across
// its own parabola, with its own level (w = d - level), comes from prefix sums of those moments (the
// parabola is quadratic in r: exact for it). One pass: the columns' runs are centred on the fitted curve
// already (a second pass around the first centres measured no better on the webcam test).
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

#include "extract_steps.h"
#include "kernels.h"

namespace rotoscan::laser::detail {
namespace {

// A steep point's fit (RecentreSteepLines): its index, row and column, the parabola column = c0 + s dr +
// k dr^2 (dr = row - row0) through its stretch, the fit's column at its row, L = sqrt(1 + s^2), the half
// width across the line, px, and the weights' level (w = d - level where d >= min_d); the half width in rows
// (half L / |s|) and the along coordinate's change per row (sign(s) / L), as MeasureRun's columns use them.
struct SteepFit {
  size_t index;
  int row;
  double c0, s, k, fitted, length, half, level;
  int min_d;
  double half_rows, per_row;
};

// Sums over the pixels of a stretch of the line's along coordinate, rows relative to the run's first
// point and columns to its first column: of x, x c, x r, x r^2 for x = d (the difference) and x = 1, so
// that a point's own level comes out: sum of w (...) = sum d (...) - level sum 1 (...).
struct AlongMoments {
  double d = 0, dc = 0, dr = 0, drr = 0;
  double n = 0, nc = 0, nr = 0, nrr = 0;
};
static_assert(sizeof(AlongMoments) == 8 * sizeof(double), "SteepColumn reads a bin as 8 doubles");

// Bins per px along the line, and the columns beyond the points' windows that a run covers.
constexpr double kSteepBinsPerPx = 2.0;
constexpr int kSteepMarginPx = 8;

// Measures the points of one run of consecutive steep points (fits[0..count): rows increasing, one sign
// of slope) across their line and writes their new columns to `moved`; returns how many moved.
int MeasureRun(const cv::Mat& on, const cv::Mat& off, int channel, int threshold,
               const std::vector<LinePoint>& p, const SteepFit* fits, size_t count,
               std::vector<float>* moved) {
  const int rows = on.rows, cols = on.cols, step = on.channels();
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  // The column sums as vectors (SteepColumnAvx2, the same bits), where its terms are exact (rows and
  // columns under 2^20).
  const bool avx2_sums = HaveAvx2() && rows <= (1 << 20) && cols <= (1 << 20);
#endif
  // The columns any point's window reaches: within kSteepAlongPx along the line of its column, i.e.
  // kSteepAlongPx |s| / L columns, and a margin.
  double reach = 0, c_min = fits[0].c0, c_max = fits[0].c0;
  for (size_t j = 0; j < count; ++j) {
    reach = std::max(reach, kSteepAlongPx * std::abs(fits[j].s) / fits[j].length);
    c_min = std::min({c_min, fits[j].c0, fits[j].fitted});
    c_max = std::max({c_max, fits[j].c0, fits[j].fitted});
  }
  const int c_first = std::max(0, static_cast<int>(std::floor(c_min - reach)) - kSteepMarginPx);
  const int c_last = std::min(cols - 1, static_cast<int>(std::ceil(c_max + reach)) + kSteepMarginPx);
  if (c_first > c_last) return 0;
  const size_t span = static_cast<size_t>(c_last - c_first + 1);
  // Each column's crossing row on the curve through the fitted columns (straight pieces between
  // neighbouring points; beyond the run's ends, the end point's own line), and the nearest point.
  thread_local std::vector<double> crossing;
  thread_local std::vector<uint32_t> nearest;
  crossing.assign(span, std::numeric_limits<double>::quiet_NaN());
  nearest.assign(span, 0);
  const double sign = fits[0].s > 0 ? 1.0 : -1.0;
  const SteepFit& front = fits[0];
  const SteepFit& back = fits[count - 1];
  for (int c = c_first; c <= c_last; ++c) {
    const size_t at = static_cast<size_t>(c - c_first);
    if ((c - front.fitted) * sign <= 0) {
      crossing[at] = front.row + (c - front.fitted) / front.s;
      nearest[at] = 0;
    } else if ((c - back.fitted) * sign >= 0) {
      crossing[at] = back.row + (c - back.fitted) / back.s;
      nearest[at] = static_cast<uint32_t>(count - 1);
    }
  }
  for (size_t j = 0; j + 1 < count; ++j) {
    const SteepFit& a = fits[j];
    const SteepFit& b = fits[j + 1];
    const double df = b.fitted - a.fitted;
    if (df == 0) continue;
    const int from = std::max(c_first, static_cast<int>(std::ceil(std::min(a.fitted, b.fitted))));
    const int to = std::min(c_last, static_cast<int>(std::floor(std::max(a.fitted, b.fitted))));
    for (int c = from; c <= to; ++c) {
      const size_t at = static_cast<size_t>(c - c_first);
      crossing[at] = a.row + (c - a.fitted) / df * (b.row - a.row);
      nearest[at] = static_cast<uint32_t>(std::abs(c - a.fitted) <= std::abs(c - b.fitted) ? j : j + 1);
    }
  }
  // The along coordinate of each column's crossing (px along the curve from c_first, L / |s| a column);
  // a pixel's is its column's plus sign(s) (r - crossing) / L. Shifted by `shift` to be positive.
  thread_local std::vector<double> along;
  along.assign(span + 1, 0);
  double max_half = 0;
  for (size_t at = 0; at < span; ++at) {
    const SteepFit& f = fits[nearest[at]];
    along[at + 1] = along[at] + f.length / std::abs(f.s);
    max_half = std::max(max_half, f.half);
  }
  const double shift = max_half + 2;
  const size_t bins = static_cast<size_t>((along[span] + 2 * shift) * kSteepBinsPerPx) + 2;
  // The moments per bin of the along coordinate, prefix-summed: prefix[b + 1] holds bins 0..b. Each
  // pixel once: a column's run of rows across the curve, within `half` of it (half L / |s| rows), the
  // pixels whose difference reaches the nearest point's level.
  const int base_row = fits[0].row;
  thread_local std::vector<AlongMoments> prefix;
  prefix.assign(bins + 1, AlongMoments{});
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  if (avx2_sums) {  // the loop below in one AVX2 function (SteepColumnsAvx2, the same bits)
    thread_local std::vector<SteepColumnFit> column_fits;
    column_fits.resize(count);
    for (size_t j = 0; j < count; ++j) column_fits[j] = {fits[j].half_rows, fits[j].per_row, fits[j].min_d};
    SteepColumnsAvx2(on.ptr<uint8_t>(0) + channel, on.step[0], off.ptr<uint8_t>(0) + channel, off.step[0], step, rows,
                     c_first, c_last, crossing.data(), along.data(), nearest.data(), column_fits.data(), threshold,
                     shift, kSteepBinsPerPx, static_cast<double>(bins - 1), base_row, &prefix[1].d);
  } else
#endif
  for (int c = c_first; c <= c_last; ++c) {
    const size_t at = static_cast<size_t>(c - c_first);
    if (std::isnan(crossing[at])) continue;
    const SteepFit& f = fits[nearest[at]];
    const double half_rows = f.half_rows;
    const int r_first = std::max(0, static_cast<int>(std::ceil(crossing[at] - half_rows)));
    const int r_last = std::min(rows - 1, static_cast<int>(std::floor(crossing[at] + half_rows)));
    const double per_row = f.per_row, cc = c - c_first;  // sign / f.length: a run's slopes have one sign
    const double u0 = along[at] - crossing[at] * per_row + shift;  // the along coordinate at row 0
    const int min_d = f.min_d;
    AlongMoments* const bin = prefix.data() + 1;
    const double last_bin = static_cast<double>(bins - 1);
    const uint8_t* const pa = on.ptr<uint8_t>(0) + c * step + channel;
    const uint8_t* const pb = off.ptr<uint8_t>(0) + c * step + channel;
    scalar::SteepColumn(pa, pb, on.step[0], off.step[0], r_first, r_last, threshold, min_d, u0, per_row,
                        kSteepBinsPerPx, last_bin, cc, base_row, &bin[0].d);
  }
  for (size_t b = 1; b <= bins; ++b) {
    AlongMoments& m = prefix[b];
    const AlongMoments& before = prefix[b - 1];
    m.d += before.d, m.dc += before.dc, m.dr += before.dr, m.drr += before.drr;
    m.n += before.n, m.nc += before.nc, m.nr += before.nr, m.nrr += before.nrr;
  }
  int moved_count = 0;
  for (size_t j = 0; j < count; ++j) {
    const SteepFit& f = fits[j];
    // The point's along coordinate: its column's crossing's, plus its row's offset from the crossing.
    const double cf = std::floor(f.c0);
    if (cf < c_first || cf >= c_last) continue;
    const size_t at = static_cast<size_t>(cf - c_first);
    if (std::isnan(crossing[at])) continue;
    const double cross = crossing[at] + (f.c0 - cf) / f.s;
    const double u =
        along[at] + (f.c0 - cf) * f.length / std::abs(f.s) + sign * (f.row - cross) / f.length + shift;
    // The window: the bins within kSteepAlongPx of it.
    const long b_first = std::max(0L, static_cast<long>(std::floor((u - kSteepAlongPx) * kSteepBinsPerPx)));
    const long b_last = std::min(static_cast<long>(bins) - 1,
                                 static_cast<long>(std::floor((u + kSteepAlongPx) * kSteepBinsPerPx)));
    if (b_first > b_last) continue;
    const AlongMoments& hi = prefix[static_cast<size_t>(b_last + 1)];
    const AlongMoments& lo = prefix[static_cast<size_t>(b_first)];
    // w = d - level (the point's own level).
    const double w = (hi.d - lo.d) - f.level * (hi.n - lo.n);
    const double wc = (hi.dc - lo.dc) - f.level * (hi.nc - lo.nc);
    const double wr = (hi.dr - lo.dr) - f.level * (hi.nr - lo.nr);
    const double wrr = (hi.drr - lo.drr) - f.level * (hi.nrr - lo.nrr);
    if (w <= 0) continue;
    // Sum of w (c - line(r)) over the window, line(r) = c0 + s (r - row) + k (r - row)^2 (the point's own
    // parabola), in the run's relative columns and rows; the point moves by that over the sum of w (L
    // times the offset across the line).
    const double c0 = f.c0 - c_first, r0 = f.row - base_row;
    const double offset = (wc - c0 * w - f.s * (wr - r0 * w) - f.k * (wrr - 2 * r0 * wr + r0 * r0 * w)) / w;
    // As the smoothing (LimitSmoothing), the point moves by at most its own uncertainty along the row, or
    // kSteepMaxMoveWidths of its row width where that is larger (a weak speckled row's uncertainty can be
    // under its error: ends.cc's limit, tighter).
    const double limit =
        std::max(static_cast<double>(p[f.index].uncertainty_px), kSteepMaxMoveWidths * p[f.index].width);
    (*moved)[f.index] = static_cast<float>(f.c0 + std::clamp(offset, -limit, limit));
    ++moved_count;
  }
  return moved_count;
}

}  // namespace
int RecentreSteepLines(const cv::Mat& on, const cv::Mat& off, int channel, int threshold,
                       std::vector<LinePoint>* line_points) {
  std::vector<LinePoint>& p = *line_points;
  const size_t n = p.size();
  std::vector<float> moved(n);
  for (size_t i = 0; i < n; ++i) moved[i] = p[i].column;
  int count = 0;
  // The stretch around a point: rows at most 2 apart, at most kSteepMaxStepPx columns per row.
  auto joined = [&](size_t a, size_t b) {
    const int gap = p[b].row - p[a].row;
    return gap <= 2 && std::abs(p[b].column - p[a].column) <= kSteepMaxStepPx * gap;
  };
  thread_local std::vector<SteepFit> fits;
  fits.clear();
  for (size_t i = 0; i < n; ++i) {
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
    double rhs[3] = {0, 0, 0};
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
    // Solved by its adjugate, in integers up to the division (exact: |dr| <= kSteepFitRows, at most 2
    // kSteepFitRows + 1 points, every product under 2^53): laser_bench, a third of the step's time had
    // been Eigen's LDLT of this 3x3 matrix.
    const int64_t p0 = powers[0], p1 = powers[1], p2 = powers[2], p3 = powers[3], p4 = powers[4];
    const int64_t adj00 = p2 * p4 - p3 * p3, adj01 = p2 * p3 - p1 * p4, adj02 = p1 * p3 - p2 * p2;
    const int64_t adj11 = p0 * p4 - p2 * p2, adj12 = p1 * p2 - p0 * p3, adj22 = p0 * p2 - p1 * p1;
    const int64_t det = p0 * adj00 + p1 * adj01 + p2 * adj02;
    if (det <= 0) continue;  // fewer than 3 distinct rows
    const double inv_det = 1.0 / static_cast<double>(det);
    const double q00 = static_cast<double>(adj00), q01 = static_cast<double>(adj01);
    const double q02 = static_cast<double>(adj02), q11 = static_cast<double>(adj11);
    const double q12 = static_cast<double>(adj12), q22 = static_cast<double>(adj22);
    const double x[3] = {(q00 * rhs[0] + q01 * rhs[1] + q02 * rhs[2]) * inv_det,
                         (q01 * rhs[0] + q11 * rhs[1] + q12 * rhs[2]) * inv_det,
                         (q02 * rhs[0] + q12 * rhs[1] + q22 * rhs[2]) * inv_det};
    if (!std::isfinite(x[0]) || !std::isfinite(x[1]) || !std::isfinite(x[2])) continue;
    const double s = x[1], curvature = x[2];
    if (std::abs(s) < kSteepSlope) continue;
    const double length = std::sqrt(1.0 + s * s);
    // A line, not rows that merely lie near each other: the points' RMS distance along their rows from
    // the fit (per degree of freedom) is at most kSteepMaxResidual (1 + L) px (a row's error is L times one
    // across the line); or at most kSteepLooseResidual (1 + L) px where the fit's slope is at least
    // kSteepMinSlopeT of its own standard errors (a weak speckled line, whose rows scatter more than 0.35
    // (1 + L): on the webcam sets most of the table's steep mid-line rows over 1 px had been left to their
    // row's own estimate by the tight test alone; independent rows give no significant slope).
    double residual2 = 0;
    for (size_t k = lo; k <= hi; ++k) {
      const double dr = p[k].row - r0;
      const double e = p[k].column - (c0 + x[0] + s * dr + curvature * dr * dr);
      residual2 += e * e;
    }
    const double dof = static_cast<double>(hi - lo + 1 - 3);
    const double scale2 = (1.0 + length) * (1.0 + length) * dof;
    const double slope_variance = residual2 / dof * q11 * inv_det;  // the fit's variance of s
    if (residual2 > kSteepMaxResidual * kSteepMaxResidual * scale2 &&
        (residual2 > kSteepLooseResidual * kSteepLooseResidual * scale2 ||
         s * s < kSteepMinSlopeT * kSteepMinSlopeT * slope_variance))
      continue;
    // Across the line, the row's width divided by L; the window is that width either side.
    const double half = std::max(kSteepMinHalfPx, p[i].width / length);
    const double level = kComLevelNum * static_cast<double>(p[i].peak) / kComScale;
    // The weights' level as an integer test: for a whole difference d, d - level > 0 exactly where
    // d >= floor(level) + 1 (whatever the peak, a whole number of DN or not). No pixel passes over 255.
    const int min_d = static_cast<int>(std::floor(level)) + 1;
    if (min_d > 255) continue;
    fits.push_back({i, r0, c0, s, curvature, c0 + x[0], length, half, level, min_d, half * length / std::abs(s),
                    (s > 0 ? 1.0 : -1.0) / length});
  }
  // Runs of consecutive steep points, each one curve.
  size_t run_first = 0;
  for (size_t j = 0; j < fits.size(); ++j) {
    const bool last = j + 1 == fits.size() || fits[j + 1].index != fits[j].index + 1 ||
                      !joined(fits[j].index, fits[j + 1].index) || (fits[j + 1].s > 0) != (fits[j].s > 0);
    if (!last) continue;
    count += MeasureRun(on, off, channel, threshold, p, fits.data() + run_first, j + 1 - run_first, &moved);
    run_first = j + 1;
  }
  for (size_t i = 0; i < n; ++i) p[i].column = moved[i];
  return count;
}

}  // namespace rotoscan::laser::detail
