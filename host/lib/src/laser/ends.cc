// RecentreLineEnds (extract_steps.h): the last rows of a steep stretch of line, whose row profile the
// line's end cuts, measured across the line as it runs before its end.
//
// Why (issue 15; TableRowsTest.MissedRowsBySignal, opt-in, with ROTOSCAN_TABLE_ROWS_DUMP=end): where a
// steep line (s columns per row) ends (the table's rim, the object's silhouette or its junction with the
// table's line), a row near the end crosses the line obliquely, and the part of its profile on the side
// where the line would go on has no light: the profile is one-sided and its centre of mass is pulled
// towards the lit side. On the webcam sets (8 steps x 2 lasers, f/4, before this step) 123 of the rows over
// 1 px across were within 4 rows of a line's end (the truth's, or where the other part's rows begin), 56 of
// them in its last two rows; in all but 8 the row's own estimate (no steep step, no smoothing) was over
// 1 px off too, and the noise-free render's own centre of mass in the row was 1.5-2.2 px off along the row
// (median; over 1 px across in 42 of them): the light is there, the profile is cut. steep.cc measures a
// steep point across its line, but with the direction from the neighbouring rows' points, which near an
// end are the cut rows themselves (pulled the same way), and moves a point by at most its uncertainty (or
// kSteepMaxMoveWidths of its row width).
//
// The step: at each open end of a stretch (steep.cc's: rows at most 2 apart, at most kSteepMaxStepPx columns
// per row; not at the frame's first or last rows, and not where the line goes on after a gap of at most
// kEndResumeRows rows: a shadow, whose cut's angle is unknown, see below), a straight line (column against
// row, least squares) through kEndFitRows points of the stretch from kEndMaxRows points in from the end
// (at least kSteepMinPoints; the residual test of steep.cc, as loose as gaps.cc's: kEndMaxResidual) gives
// the direction; it must be steep (kSteepSlope). The end rows, those within twice the interior's median
// row width (full width at half maximum) over the slope (at most kEndMaxRows), are put where the centre of
// mass across that line (the difference above kComLevelNum / kComScale of the point's peak, over the
// pixels within kSteepAlongPx along the line from the row's foot on it and the line's half width across,
// kSteepIterations times as steep.cc) crosses the row. A point moves by at most its uncertainty or
// kEndMaxMoveWidths of its row width, whichever is larger.
//
// Where the cut is square to the line, the pixels past it carry no light and the centre across is not
// moved by it (LineEndTest: the last 6 rows of a synthetic line cut so, over 1 px 24 -> 14 of 60, RMS
// 1.11 -> 0.84 px). Where the cut is oblique (a cut along the rows, as GapFillTest's shadow; the table's
// rim), the lit part of the window is lopsided across and its centre is pulled too: GapFillTest's
// shadow's edge rows went from 2 to 7 over 1 px until ends followed by the same line were left out.
#include <algorithm>
#include <cmath>
#include <vector>

#include "extract_steps.h"
#include "kernels.h"

namespace rotoscan::laser::detail {
namespace {

// The across-the-line centre of mass around (r0, foot) on the line column = a + s row, its offset t
// across from the line (px); false where no pixel has weight.
bool CentreAcross(const cv::Mat& on, const cv::Mat& off, int channel, int threshold, double a, double s, int r0,
                  double half, double level, double* t_out) {
  const int step = on.channels();
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  const bool avx2 = HaveAvx2();  // 4 pixels at a time (AcrossWindowSumsAvx2, the same sums)
#endif
  const double length = std::sqrt(1.0 + s * s);
  // The unit vectors along (row, column) = (1, s) / L and across (-s, 1) / L; the foot: the line's point in
  // row r0.
  const double foot_c = a + s * r0;
  const double row_reach = (kSteepAlongPx + half * std::abs(s)) / length + 1.0;
  const int r_first = std::max(0, static_cast<int>(std::floor(r0 - row_reach)));
  const int r_last = std::min(on.rows - 1, static_cast<int>(std::ceil(r0 + row_reach)));
  // The sums' columns from c0, an integer near the foot, so that they stay small.
  const int c0 = static_cast<int>(std::clamp(std::floor(foot_c), -1e9, 1e9));
  const double foot_rel = foot_c - c0;
  double t = 0;
  for (int iteration = 0; iteration < kSteepIterations; ++iteration) {
    AcrossSums sums;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
    if (avx2) {  // the loop below, in one AVX2 function
      AcrossWindowSumsAvx2(on.ptr<uint8_t>(0) + channel, on.step[0], off.ptr<uint8_t>(0) + channel, off.step[0], step,
                           on.cols, r_first, r_last, r0, a, s, length, foot_c, t, half, level, threshold,
                           kSteepAlongPx, c0, &sums);
      if (!AcrossCentre(sums, foot_rel, s, length, level, &t)) return false;
      continue;
    }
#endif
    for (int r = r_first; r <= r_last; ++r) {
      const double line = a + s * r;
      // The run of columns within both windows (the per-pixel test below decides; these bounds only skip
      // pixels it would reject, with a pixel to spare): across, |across - t| <= half; along, (dr + s dc) / L
      // within +-kSteepAlongPx.
      const double dr0 = r - r0;
      const double along_a = foot_c + (-dr0 - kSteepAlongPx * length) / s;
      const double along_b = foot_c + (-dr0 + kSteepAlongPx * length) / s;
      const int c_first = std::max({0, static_cast<int>(std::ceil(line + (t - half) * length - 1.0)),
                                    static_cast<int>(std::floor(std::min(along_a, along_b))) - 1});
      const int c_last = std::min({on.cols - 1, static_cast<int>(std::floor(line + (t + half) * length + 1.0)),
                                   static_cast<int>(std::ceil(std::max(along_a, along_b))) + 1});
      const uint8_t* pa = on.ptr<uint8_t>(r) + channel;
      const uint8_t* pb = off.ptr<uint8_t>(r) + channel;
      scalar::AcrossRowSums(pa, pb, step, c_first, c_last, dr0, foot_c, s, length, t, half, level, threshold,
                            kSteepAlongPx, c0, &sums);
    }
    if (!AcrossCentre(sums, foot_rel, s, length, level, &t)) return false;
  }
  *t_out = t;
  return true;
}

// Points x < y of one stretch (steep.cc's): at most 2 rows apart, at most kSteepMaxStepPx columns per row.
bool Joined(const std::vector<LinePoint>& p, int x, int y) {
  const int gap = p[static_cast<size_t>(y)].row - p[static_cast<size_t>(x)].row;
  return gap <= 2 && std::abs(p[static_cast<size_t>(y)].column - p[static_cast<size_t>(x)].column) <= kSteepMaxStepPx * gap;
}

// A steep straight line column = a0 + s (row - base) through the points from..to (either order; base their
// first's row), by least squares, where it is steep (kSteepSlope) and a line: the points' RMS distance
// along their rows from it (per degree of freedom) at most kEndMaxResidual (1 + L) px (steep.cc's test, as
// loose as gaps.cc's: speckle scatters a weak steep line's rows by more than steep.cc's 0.35).
struct SteepLine {
  int base;
  double a0, s, length;
};
bool FitSteepLine(const std::vector<LinePoint>& p, int from, int to, SteepLine* line) {
  const int dir = to >= from ? 1 : -1;
  const int m = std::abs(to - from) + 1;
  const int base = p[static_cast<size_t>(from)].row;
  double sr = 0, sc = 0, srr = 0, src = 0;
  for (int k = from; k != to + dir; k += dir) {
    const LinePoint& q = p[static_cast<size_t>(k)];
    const double r = q.row - base;
    sr += r;
    sc += q.column;
    srr += r * r;
    src += r * q.column;
  }
  const double det = m * srr - sr * sr;
  if (det <= 0) return false;
  const double s = (m * src - sr * sc) / det;
  const double a0 = (sc - s * sr) / m;
  if (std::abs(s) < kSteepSlope) return false;
  const double length = std::sqrt(1.0 + s * s);
  double residual2 = 0;
  for (int k = from; k != to + dir; k += dir) {
    const LinePoint& q = p[static_cast<size_t>(k)];
    const double e = q.column - (a0 + s * (q.row - base));
    residual2 += e * e;
  }
  if (residual2 > kEndMaxResidual * kEndMaxResidual * (1.0 + length) * (1.0 + length) * (m - 2)) return false;
  *line = {base, a0, s, length};
  return true;
}

// The faint line's light in `row` on column x: the difference summed over a box of +-half columns less the same
// box kGapSideShift half widths to the side `side` (+1 right, -1 left: away from the row's point, whose
// light is another's), over the square root of the pair's variance in units of sigma^2 (kGapCorrelation 2
// N): z times the noise sigma (DN); negative where a box leaves the row.
double FaintLightZ(const cv::Mat& on, const cv::Mat& off, int channel, int row, double x, double half, int side) {
  const int step = on.channels();
  const int c0 = static_cast<int>(std::lround(x - half)), c1 = static_cast<int>(std::lround(x + half));
  const int shift = static_cast<int>(std::lround(kGapSideShift * half)) * side;
  if (std::min(c0, c0 + shift) < 0 || std::max(c1, c1 + shift) >= on.cols) return -1;
  const uint8_t* pa = on.ptr<uint8_t>(row) + channel;
  const uint8_t* pb = off.ptr<uint8_t>(row) + channel;
  long box = 0, side_box = 0;
  for (int c = c0; c <= c1; ++c) {
    box += SignedDifference(pa[c * step], pb[c * step]);
    side_box += SignedDifference(pa[(c + shift) * step], pb[(c + shift) * step]);
  }
  const int n = c1 - c0 + 1;
  return static_cast<double>(box - side_box) / std::sqrt(kGapCorrelation * 2.0 * n);
}

}  // namespace

int RecentreLineEnds(const cv::Mat& on, const cv::Mat& off, int channel, int threshold,
                     std::vector<LinePoint>* line_points) {
  std::vector<LinePoint>& p = *line_points;
  const int n = static_cast<int>(p.size());
  std::vector<float> moved(p.size());
  for (int i = 0; i < n; ++i) moved[static_cast<size_t>(i)] = p[static_cast<size_t>(i)].column;
  int count = 0;
  int start = 0;
  std::vector<double> widths;
  while (start < n) {
    int end = start;  // inclusive
    while (end + 1 < n && Joined(p, end, end + 1)) ++end;
    // Where the line goes on after a gap (a shadow, rows the row pass missed: gaps.cc's), the end is no
    // line's end: the cut's angle is unknown there (a cut along the rows leaves each row's profile whole,
    // and the centre across would be pulled instead).
    auto resumes = [&](int x, int y) {
      const int gap = p[static_cast<size_t>(y)].row - p[static_cast<size_t>(x)].row;
      return gap <= kEndResumeRows &&
             std::abs(p[static_cast<size_t>(y)].column - p[static_cast<size_t>(x)].column) <= kSteepMaxStepPx * gap;
    };
    const bool open_top = p[static_cast<size_t>(start)].row > 1 && !(start > 0 && resumes(start - 1, start));
    const bool open_bottom = p[static_cast<size_t>(end)].row < on.rows - 2 && !(end + 1 < n && resumes(end, end + 1));
    // Each end: dir +1 from the top end down the stretch, -1 from the bottom end up.
    for (const int dir : {1, -1}) {
      if (dir == 1 ? !open_top : !open_bottom) continue;
      const int first = dir == 1 ? start : end;  // the end point
      const int len = end - start + 1;
      if (len < kEndMaxRows + kSteepMinPoints) break;  // too short for an interior fit
      // The interior: kEndMaxRows points in from the end, then kEndFitRows points.
      const int fit_from = first + dir * kEndMaxRows;
      int fit_to = fit_from + dir * (kEndFitRows - 1);
      fit_to = dir == 1 ? std::min(fit_to, end) : std::max(fit_to, start);
      const int m = std::abs(fit_to - fit_from) + 1;
      if (m < kSteepMinPoints) continue;
      SteepLine fit;
      if (!FitSteepLine(p, fit_from, fit_to, &fit)) continue;
      const double s = fit.s, length = fit.length;
      widths.clear();
      for (int k = fit_from; k != fit_to + dir; k += dir) widths.push_back(p[static_cast<size_t>(k)].width);
      std::nth_element(widths.begin(), widths.begin() + static_cast<long>(widths.size() / 2), widths.end());
      const double width = widths[widths.size() / 2];
      // The end rows: within twice the row width over |s| rows of the end point (at most kEndMaxRows).
      const int reach = std::min(kEndMaxRows, static_cast<int>(std::ceil(2.0 * width / std::abs(s))));
      const double a = fit.a0 - s * fit.base;  // column = a + s row
      for (int k = first; k != first + dir * kEndMaxRows; k += dir) {
        LinePoint& q = p[static_cast<size_t>(k)];
        if (std::abs(q.row - p[static_cast<size_t>(first)].row) >= reach) break;
        const double half = std::max(kSteepMinHalfPx, width / length);
        const double level = kComLevelNum * static_cast<double>(q.peak) / kComScale;
        // The last kEndOnLineRows rows on the interior's line itself (t = 0): where the cut runs along the rows
        // (the table's rim), their window crosses it and the lit side pulls the centre across (extract_steps.h).
        double t = 0;
        if (std::abs(q.row - p[static_cast<size_t>(first)].row) >= kEndOnLineRows &&
            !CentreAcross(on, off, channel, threshold, a, s, q.row, half, level, &t))
          continue;
        const double target = a + s * q.row + t * length;
        const double limit = std::max(static_cast<double>(q.uncertainty_px), kEndMaxMoveWidths * q.width);
        moved[static_cast<size_t>(k)] =
            static_cast<float>(q.column + std::clamp(target - q.column, -limit, limit));
        ++count;
      }
    }
    start = end + 1;
  }
  for (int i = 0; i < n; ++i) p[static_cast<size_t>(i)].column = moved[static_cast<size_t>(i)];
  return count;
}

// RecentreJunctionRows (extract_steps.h): where a bright line meets the table's faint steep line (the
// object's foot on the table), the faint line's first rows past the corner are put on its own straight
// line from further in.
//
// Why (issue 15, thirteenth session; TableRowsTest.MissedRowsBySignal's rows by distance to the other
// part): the table's rows within 4 rows of the object's line held 10 of glossy's 34 table rows over 1 px
// and 26 of textured's 41 (8 steps x 2 lasers, f/4). There the object's line, 100-200 DN against the table
// line's ~13 DN, ends on the table: its blur reaches 3-5 rows past its last row, and each of those rows'
// profile is the object's light more than the table's (their noise-free centre of mass 2-5 px from the
// truth along the row, the noisy point on the object's line or between). No centre measured in those rows
// can find the table's line; its interior can: the table top is flat, its line straight in the image.
//
// The step: for each point b and each direction along its stretch (steep.cc's joined rows), the interior
// is the stretch's points kJunctionSkipRows to kJunctionSkipRows + kEndFitRows rows from b (at least half
// of kEndFitRows points). Where b's peak is at least kJunctionRatio times the interior's median peak, that
// median is at most kJunctionDimMax times the frame's threshold (a faint line: the object's dimmer parts
// next to a highlight were moved off their curve when it was not asked for), the interior's straight fit is
// steep (kSteepSlope) and passes ends.cc's residual test, and the bright side (b's stretch within
// kJunctionSideRows rows beyond b, at least 3 points) runs at a slope at least kJunctionMinTurn columns per
// row from the interior's (two lines meeting at a corner, not one line's highlight), the rows past the
// lines' crossing within kJunctionReachRows rows are put on the interior's fit, where that moves them at
// most kJunctionMaxMovePx (further, the point is on another line: the object's, whose row it may be). A
// row several bright points reach takes the nearest one's (its side's fit holds the corner's rows). A row
// between b and the interior whose peak is at most kJunctionFaintRatio times the interior's mean is the faint
// line's whichever side of the straight lines' crossing it lies (a sphere's line curves into the corner, so
// the crossing falls past it), and goes on the fit if that moves it at most kJunctionFaintMaxMovePx (fifteenth
// session; extract_steps.h has the figures). A row past the crossing that neither rule moves because its point
// is further off (another light: the bright line's MJPEG ringing, seventeenth session) goes on the fit where the
// faint line's own light in the row reaches kJunctionLightZ (FaintLightZ), after the smoothing (`deferred`,
// ApplyJunctionGhostRows; null: not at all).
int RecentreJunctionRows(const cv::Mat& on, const cv::Mat& off, int channel, int threshold, double noise_dn,
                         std::vector<LinePoint>* line_points, std::vector<std::pair<int, float>>* deferred) {
  std::vector<LinePoint>& p = *line_points;
  const int n = static_cast<int>(p.size());
  if (n == 0) return 0;
  // Stretch bounds and a prefix count of the faint points (peak at most kJunctionDimMax thresholds): an
  // interior whose median is above that is rejected before it is walked (most points: the object's line).
  std::vector<int> first(p.size()), last(p.size()), dim_before(p.size() + 1, 0);
  for (int i = 0; i < n; ++i) first[static_cast<size_t>(i)] = i > 0 && Joined(p, i - 1, i) ? first[static_cast<size_t>(i - 1)] : i;
  for (int i = n - 1; i >= 0; --i) last[static_cast<size_t>(i)] = i + 1 < n && Joined(p, i, i + 1) ? last[static_cast<size_t>(i + 1)] : i;
  const double dim_max = kJunctionDimMax * threshold;
  for (int i = 0; i < n; ++i)
    dim_before[static_cast<size_t>(i + 1)] = dim_before[static_cast<size_t>(i)] + (p[static_cast<size_t>(i)].peak <= dim_max);
  // Each stretch's faintest peak: a point under kJunctionRatio times it has no interior faint enough
  // (skipped before any search: most of the table's own points).
  std::vector<float> stretch_min(p.size());
  for (int i = 0; i < n; ++i) {
    const size_t f = static_cast<size_t>(first[static_cast<size_t>(i)]);
    stretch_min[f] = static_cast<size_t>(i) == f ? p[static_cast<size_t>(i)].peak
                                                  : std::min(stretch_min[f], p[static_cast<size_t>(i)].peak);
  }
  std::vector<int> point_rows(p.size());
  for (int i = 0; i < n; ++i) point_rows[static_cast<size_t>(i)] = p[static_cast<size_t>(i)].row;
  std::vector<float> moved(p.size());
  std::vector<int> from_rows(p.size(), 1 << 30);  // rows from the bright point a row was moved for
  std::vector<double> widths;
  // The deferred moves (extract_steps.h, kJunctionLightZ) and the rows from the bright point each is for;
  // allocated at the first (most frames have none).
  std::vector<float> ghost;
  std::vector<int> ghost_from;
  for (int i = 0; i < n; ++i) moved[static_cast<size_t>(i)] = p[static_cast<size_t>(i)].column;
  // The interior's ends, [lo, hi], move only forwards with b within a stretch (rows increase with the index):
  // found by pointers that walk on from b's predecessor's (fourteenth session: a binary search per point and
  // direction cost ~4 % of a typical webcam frame, laser_bench BM_ExtractWebcam/1), reset at each stretch's
  // start. Each is the binary search's answer: the first index in its range whose row passes its bound.
  int below_lo = 0, below_hi = 0, above_lo = 0, above_hi = 0;  // dir 1: [lo, hi + 1); dir -1: the same
  for (int b = 0; b < n; ++b) {
    const LinePoint& pb = p[static_cast<size_t>(b)];
    const int s_first = first[static_cast<size_t>(b)], s_last = last[static_cast<size_t>(b)];
    if (b == s_first) below_lo = below_hi = b + 1, above_lo = above_hi = s_first;
    if (pb.peak < kJunctionRatio * stretch_min[static_cast<size_t>(s_first)]) continue;
    // dir 1: the first index in (b, s_last] with row >= pb.row + kJunctionSkipRows (+ kEndFitRows), or
    // s_last + 1 (std::lower_bound); dir -1: the first in [s_first, b) with row > pb.row - kJunctionSkipRows
    // (- kEndFitRows), or b (std::upper_bound).
    below_lo = std::max(below_lo, b + 1);
    while (below_lo <= s_last && point_rows[static_cast<size_t>(below_lo)] < pb.row + kJunctionSkipRows) ++below_lo;
    below_hi = std::max(below_hi, below_lo);
    while (below_hi <= s_last && point_rows[static_cast<size_t>(below_hi)] < pb.row + kJunctionSkipRows + kEndFitRows)
      ++below_hi;
    while (above_lo < b && point_rows[static_cast<size_t>(above_lo)] <= pb.row - kJunctionSkipRows - kEndFitRows) ++above_lo;
    above_hi = std::max(above_hi, above_lo);
    while (above_hi < b && point_rows[static_cast<size_t>(above_hi)] <= pb.row - kJunctionSkipRows) ++above_hi;
    for (const int dir : {1, -1}) {
      // The interior: indices [lo, hi] of b's stretch, kJunctionSkipRows to kJunctionSkipRows + kEndFitRows
      // - 1 rows from b (one point per row, rows increasing with the index).
      auto row_dist = [&](int k) { return std::abs(p[static_cast<size_t>(k)].row - pb.row); };
      const int lo = dir == 1 ? below_lo : above_lo;
      const int hi = (dir == 1 ? below_hi : above_hi) - 1;
      if (lo > hi) continue;
      const int m = hi - lo + 1;
      if (m < kEndFitRows / 2) continue;
      // The median peak at most dim_max: at least m / 2 + 1 of the points that faint.
      if (dim_before[static_cast<size_t>(hi + 1)] - dim_before[static_cast<size_t>(lo)] < m / 2 + 1) continue;
      // b at least kJunctionRatio times the median: at least m / 2 + 1 points that faint (no sort: on the
      // table's own points, every one of which passes the test above, a sort per point cost ~4 % of a
      // typical webcam frame).
      int faint = 0;
      for (int k = lo; k <= hi; ++k) faint += kJunctionRatio * p[static_cast<size_t>(k)].peak <= pb.peak;
      if (faint < m / 2 + 1) continue;
      // The interior's straight line, column = a0 + s (row - base), steep, with the line-end step's residual test.
      SteepLine fit;
      if (!FitSteepLine(p, lo, hi, &fit)) continue;
      const double a0 = fit.a0, s = fit.s;
      const int base = fit.base;
      // The bright side: b and its stretch's points beyond it (away from the interior) within
      // kJunctionSideRows rows; its line crosses the interior's at the corner.
      double br = 0, bc = 0, brr = 0, brc = 0;
      int bm = 0;
      for (int k = b; k >= s_first && k <= s_last && row_dist(k) <= kJunctionSideRows; k -= dir) {
        const double r = p[static_cast<size_t>(k)].row - pb.row, c = p[static_cast<size_t>(k)].column;
        br += r;
        bc += c;
        brr += r * r;
        brc += r * c;
        ++bm;
      }
      const double bdet = bm * brr - br * br;
      if (bm < 3 || bdet <= 0) continue;
      const double sb = (bm * brc - br * bc) / bdet;
      if (std::abs(sb - s) < kJunctionMinTurn) continue;
      const double cb = (bc - sb * br) / bm;  // the bright side's column at b's row
      // a0 + s (r - base) = cb + sb (r - b.row)
      const double corner_row = (cb - sb * pb.row - a0 + s * base) / (s - sb);
      // The interior's mean peak: a row between b and the interior no brighter than kJunctionFaintRatio times
      // it is the faint line's, whichever side of the straight lines' crossing it is on (extract_steps.h).
      double interior_peak = 0;
      for (int k = lo; k <= hi; ++k) interior_peak += p[static_cast<size_t>(k)].peak;
      interior_peak /= m;
      double half = -1;  // the interior's half row width, once a row asks for it
      bool reached = false;  // a bright row past the reach: the rows after it move only by their light (below)
      for (int k = b + dir; k != lo; k += dir) {
        LinePoint& q = p[static_cast<size_t>(k)];
        const double past = (q.row - corner_row) * dir;
        const bool faint_row = q.peak <= kJunctionFaintRatio * interior_peak;
        if (past > kJunctionReachRows && !faint_row) reached = true;
        if (past <= 0 && !faint_row) continue;  // the bright line's side of the corner
        const double target = a0 + s * (q.row - base);
        const int d = std::abs(q.row - pb.row);
        if (d >= from_rows[static_cast<size_t>(k)]) continue;
        const double max_move = faint_row ? kJunctionFaintMaxMovePx : kJunctionMaxMovePx;
        const double move = std::abs(target - q.column);
        // A row past the corner that these rules leave (further off than they move a row, or past the reach)
        // and whose point is over kJunctionMaxMovePx off (another light there: the bright line's MJPEG ringing)
        // goes on the fit after the smoothing, where the faint line's own light in the row shows it
        // (extract_steps.h, kJunctionLightZ).
        if (deferred != nullptr && past > 0 && move > kJunctionMaxMovePx && (reached || move > max_move)) {
          if (ghost.empty()) ghost.assign(p.size(), -1.0f), ghost_from.assign(p.size(), 1 << 30);
          if (d >= ghost_from[static_cast<size_t>(k)]) continue;
          if (half < 0) {
            widths.clear();
            for (int w = lo; w <= hi; ++w) widths.push_back(p[static_cast<size_t>(w)].width);
            std::nth_element(widths.begin(), widths.begin() + static_cast<long>(widths.size() / 2), widths.end());
            half = std::max(kSteepMinHalfPx, 0.5 * widths[widths.size() / 2]);
          }
          if (FaintLightZ(on, off, channel, q.row, target, half, q.column > target ? -1 : 1) >=
              kJunctionLightZ * noise_dn) {
            ghost[static_cast<size_t>(k)] = static_cast<float>(target);
            ghost_from[static_cast<size_t>(k)] = d;
          }
          continue;
        }
        if (reached || move > max_move) continue;
        moved[static_cast<size_t>(k)] = static_cast<float>(target);
        from_rows[static_cast<size_t>(k)] = d;
      }
    }
  }
  int count = 0;
  for (int i = 0; i < n; ++i) {
    // A row the other rules moved for a nearer bright point keeps that move.
    if (!ghost.empty() && ghost[static_cast<size_t>(i)] >= 0 && ghost_from[static_cast<size_t>(i)] < from_rows[static_cast<size_t>(i)])
      deferred->emplace_back(p[static_cast<size_t>(i)].row, ghost[static_cast<size_t>(i)]);
    count += from_rows[static_cast<size_t>(i)] < (1 << 30);
    p[static_cast<size_t>(i)].column = moved[static_cast<size_t>(i)];
  }
  return count;
}

void ApplyJunctionGhostRows(const std::vector<std::pair<int, float>>& deferred, std::vector<LinePoint>* line_points) {
  std::vector<LinePoint>& p = *line_points;
  for (const auto& [row, column] : deferred) {
    const auto it = std::lower_bound(p.begin(), p.end(), row, [](const LinePoint& q, int r) { return q.row < r; });
    if (it == p.end() || it->row != row) continue;
    WidenUncertainty(std::max(static_cast<double>(it->uncertainty_px), std::abs(double{column} - it->column)), &*it);
    it->column = column;
  }
}

// A rim (issue 15, fourteenth session, rfglossy4; extract_steps.h, kRimTailRatio, says why and with what
// figures): a stretch's end whose last rows fade, the side line's tail that the vertical blur carries past
// the rim, where the truth is a flat top's faint line running off at 2-12 columns per row from the corner.
// That line is looked for by its light summed along it over the tail's rows and kRimBeyondRows more (the flat
// top's line is as wide in a row as its slope), away from the tail's own light; where it reaches kRimMinZ
// noise sigmas, the tail's rows go on it.
int RecentreRimRows(const cv::Mat& on, const cv::Mat& off, int channel, double noise_dn,
                    std::vector<LinePoint>* line_points, std::vector<std::pair<int, int>>* at_bound,
                    bool by_albedo) {
  std::vector<LinePoint>& p = *line_points;
  const int n = static_cast<int>(p.size());
  const int step = on.channels();
  const double sigma = std::max(kRimMinSigmaDn, noise_dn);
  int count = 0;
  int start = 0;
  std::vector<float> peaks;
  std::vector<int> sums, counts;
  while (start < n) {
    int end = start;  // inclusive
    while (end + 1 < n && Joined(p, end, end + 1)) ++end;
    const int len = end - start + 1;
    // Each end: dir +1 from the top end down the stretch, -1 from the bottom end up.
    for (const int dir : {1, -1}) {
      if (len < kRimMinStretch) break;
      const int first = dir == 1 ? start : end;  // the end point
      // The interior's peak: the median of kRimInteriorPoints points from kRimInteriorFrom in.
      peaks.clear();
      for (int k = 0; k < kRimInteriorPoints; ++k)
        peaks.push_back(p[static_cast<size_t>(first + dir * (kRimInteriorFrom + k))].peak);
      std::nth_element(peaks.begin(), peaks.begin() + kRimInteriorPoints / 2, peaks.end());
      const double interior = peaks[kRimInteriorPoints / 2];
      // The tail: the points from the end whose peak is under kRimTailRatio of the interior's.
      int tail = 0;
      while (tail < kRimMaxTail && p[static_cast<size_t>(first + dir * tail)].peak < kRimTailRatio * interior)
        ++tail;
      if (tail == 0 || tail == kRimMaxTail) continue;
      // Each row judged against its own albedo's level too (extract_steps.h, kRimAlbedoHalfPx): a dark cell's
      // real rows are not the tail.
      if (by_albedo) {
        auto albedo = [&](const LinePoint& q) {
          const int c = static_cast<int>(std::lround(q.column));
          const uint8_t* po = off.ptr<uint8_t>(q.row) + channel;
          int sum = 0, pixels = 0;
          for (int i = std::max(0, c - kRimAlbedoHalfPx); i <= std::min(off.cols - 1, c + kRimAlbedoHalfPx); ++i)
            sum += po[i * step], ++pixels;
          return std::max(kRimAlbedoFloorSigmas * sigma, static_cast<double>(sum) / std::max(1, pixels));
        };
        peaks.clear();
        for (int k = 0; k < kRimInteriorPoints; ++k) {
          const LinePoint& q = p[static_cast<size_t>(first + dir * (kRimInteriorFrom + k))];
          if ((q.flags & kFlagSaturated) == 0) peaks.push_back(static_cast<float>(q.peak / albedo(q)));
        }
        if (peaks.size() >= 3) {
          std::nth_element(peaks.begin(), peaks.begin() + peaks.size() / 2, peaks.end());
          const double gain = peaks[peaks.size() / 2];
          int own = 0;
          while (own < tail) {
            const LinePoint& q = p[static_cast<size_t>(first + dir * own)];
            if (q.peak >= kRimTailRatio * std::min(interior, gain * albedo(q))) break;
            ++own;
          }
          if (own > 0) tail = own;
        }
      }
      // The corner: the first point in at the interior's level, on a stretch that runs along the columns
      // there (at most kRimMaxInteriorSlope columns per row over the kRimInteriorFrom points in from it).
      const LinePoint& corner = p[static_cast<size_t>(first + dir * tail)];
      const LinePoint& inner = p[static_cast<size_t>(first + dir * (tail + kRimInteriorFrom))];
      if (std::abs(inner.column - corner.column) > kRimMaxInteriorSlope * std::abs(inner.row - corner.row))
        continue;
      // The rim between the corner's row and the first tail row; the tail's own light within its half width
      // and kRimTailClearPx of its column left out.
      const double c0 = corner.column, r0 = corner.row - dir * 0.5;
      const double clear = 0.5 * std::max(4.0f, corner.width) + kRimTailClearPx;
      // Per row, running sums of the difference and of the pixels counted, the tail's own columns left out:
      // each line's sum is then two lookups a row.
      int rows_used = 0;
      const int reach = static_cast<int>(std::ceil(kRimMaxSlope * (tail + kRimBeyondRows + 1))) + 2;
      const int span_lo = std::max(0, static_cast<int>(c0) - reach);
      const int span_hi = std::min(on.cols - 1, static_cast<int>(c0) + reach);
      const int width = span_hi - span_lo + 1;
      sums.assign(static_cast<size_t>((tail + kRimBeyondRows) * (width + 1)), 0);
      counts.assign(sums.size(), 0);
      for (int j = 1; j <= tail + kRimBeyondRows; ++j) {
        const int r = corner.row - dir * j;
        if (r < 0 || r >= on.rows) break;
        const uint8_t* pa = on.ptr<uint8_t>(r) + channel;
        const uint8_t* pb = off.ptr<uint8_t>(r) + channel;
        int* sum_row = sums.data() + static_cast<size_t>((j - 1) * (width + 1));
        int* count_row = counts.data() + static_cast<size_t>((j - 1) * (width + 1));
        for (int i = span_lo; i <= span_hi; ++i) {
          const bool kept = !(std::abs(i - c0) < clear);
          sum_row[i - span_lo + 1] =
              sum_row[i - span_lo] + (kept ? int{pa[i * step]} - int{pb[i * step]} : 0);
          count_row[i - span_lo + 1] = count_row[i - span_lo] + (kept ? 1 : 0);
        }
        rows_used = j;
      }
      double best_z = 0, best_s = 0;
      for (double a = kRimMinSlope; a <= kRimMaxSlope; a += kRimSlopeStep) {
        for (const int side : {-1, 1}) {
          const double s = side * a;  // columns per row away from the rim
          double sum = 0;
          int pixels = 0;
          for (int j = 1; j <= rows_used; ++j) {
            const int r = corner.row - dir * j;
            const double x = c0 + s * std::abs(r - r0);
            const int lo = std::max(span_lo, static_cast<int>(std::floor(x - 0.5 * a)));
            const int hi = std::min(span_hi, static_cast<int>(std::ceil(x + 0.5 * a)));
            if (hi < lo) continue;
            const int* sum_row = sums.data() + static_cast<size_t>((j - 1) * (width + 1));
            const int* count_row = counts.data() + static_cast<size_t>((j - 1) * (width + 1));
            sum += sum_row[hi - span_lo + 1] - sum_row[lo - span_lo];
            pixels += count_row[hi - span_lo + 1] - count_row[lo - span_lo];
          }
          if (pixels < kRimMinPixels) continue;
          const double z = sum / (sigma * std::sqrt(static_cast<double>(pixels)));
          if (z > best_z) {
            best_z = z;
            best_s = s;
          }
        }
      }
      // The best line inside the range of slopes, not at its bounds (beyond them: another line, the table's).
      if (best_z < kRimMinZ || std::abs(best_s) < kRimMinSlope + 0.5 * kRimSlopeStep ||
          std::abs(best_s) > kRimMaxSlope - 0.5 * kRimSlopeStep) {
        // At the steep bound: the box sums' slope is pulled up by the cap line's blurred far light (rfrim5);
        // the end is handed to the matched filter (gaps.cc's tails), as the end point and the direction past
        // it (extract_steps.h).
        if (at_bound != nullptr && best_z >= kRimMinZ &&
            std::abs(best_s) > kRimMaxSlope - 0.5 * kRimSlopeStep)
          at_bound->emplace_back(first, -dir);
        continue;
      }
      for (int k = 0; k < tail; ++k) {
        LinePoint& q = p[static_cast<size_t>(first + dir * k)];
        // The row may hold either line's light (a wrong move is off by the move), and the box places the line
        // anywhere within its |s| columns (extract_steps.h): the uncertainty at least both.
        const float c = static_cast<float>(c0 + best_s * std::abs(q.row - r0));
        WidenUncertainty(std::max({static_cast<double>(q.uncertainty_px), std::abs(double{c} - q.column),
                                   std::abs(best_s) / std::sqrt(3.0)}),
                         &q);
        q.column = c;
        ++count;
      }
    }
    start = end + 1;
  }
  return count;
}

}  // namespace rotoscan::laser::detail
