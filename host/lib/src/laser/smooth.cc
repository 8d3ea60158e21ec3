// The along-line smoothing (design notes in extract.cc, "Along-line smoothing") and its limits.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "extract_steps.h"
#include "kernels.h"
#include "rotoscan/core/check.h"

namespace rotoscan::laser {
namespace {

// In a stretch joined across steep steps, a run of at least this many rows without one is smoothed as
// its own stretch, as it is without the joining (extract.cc, "Along-line smoothing": the glossy object's
// RMS across 0.370 with the joined fit everywhere, 0.365 so, 0.363 without joining).
constexpr int kKeepRows = 6;
// The curvature correction of the straight fit (SmoothAlongLine): q from the first fit's slopes
// kCurvatureReach half-windows before and after a point, averaged over the points within kCurvatureSpan
// half-windows. Webcam sets, 8 steps x 2 lasers, f/4, RMS across of the glossy / textured object (bench
// accuracy; main 0.363 / 0.289 px): reach 1, span 1: 0.335 / 0.296; reach 1, span 2: 0.336 / 0.287
// (chosen); reach 2, span 1: 0.336 / 0.289; reach 2, span 2: 0.336 / 0.291. With q from +-h / 2 and no
// averaging the textured object's went to 0.337 (the slopes' noise).
constexpr int kCurvatureReach = 1;
constexpr int kCurvatureSpan = 2;
// LimitSmoothing: a saturation change counts where each side holds this many rows of its state.
constexpr int kSaturationRunRows = 3;

// Scratch of the along-line smoothing, per thread (SmoothAlongLine is a free function with a
// public signature; a thread-local buffer keeps it allocation-free from the second frame on).
struct SmoothScratch {
  std::vector<double> prefix;                     // prefix sums and first fits of a stretch
  std::vector<uint64_t> bits;                     // the screen's flags, then outlier bits per point
  std::vector<std::array<double, 4>> cumulative;  // running sums of w, w x, w x^2, w x^3 over the window
  std::vector<int> steep_points;                  // a joined stretch's points fitted over it
};
SmoothScratch& smooth_scratch() {
  thread_local SmoothScratch scratch;
  return scratch;
}

}  // namespace

void SmoothAlongLine(std::vector<LinePoint>* points, int half_rows, int order, double max_jump_px,
                     double outlier_px, std::vector<float>* scratch, double steep_step_change_px,
                     bool curvature) {
  using detail::FlaggedOutliers;
  using detail::ScreenWindows;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  using detail::FlaggedOutliersAvx2;
  using detail::HaveAvx2;
  using detail::ScreenWindowsAvx2;
  using detail::SteepFitsAvx2;
  using detail::WholeWindowFitsAvx2;
#endif
  ROTOSCAN_CHECK(points != nullptr && scratch != nullptr && half_rows >= 0 && order >= 0 && order <= 2 &&
                 steep_step_change_px >= 0.0);
  const int n = static_cast<int>(points->size());
  if (half_rows == 0 || n < 2) return;
  LinePoint* p = points->data();
  // Floats: the raw columns, then per stretch (at most n points) the columns relative to the stretch's
  // first and the first fit's a and b. Padding (pad = h + 8 entries) around raw and rel, for the vector
  // outlier tests' reads past a window's ends (read, then masked), and after af and bf, for the screen's
  // last group.
  const size_t pad = static_cast<size_t>(half_rows) + 8;
  const size_t un = static_cast<size_t>(n);
  scratch->resize(4 * pad + 4 * un + 16);  // only raw's padding needs a value (finite: it is masked)
  float* raw = scratch->data() + pad;
  std::fill(raw - pad, raw, 0.0f);
  std::fill(raw + un, raw + un + pad, 0.0f);
  float* rel = raw + un + 2 * pad;
  float* af = rel + un + pad;
  float* bf = af + un + 8;
  for (int i = 0; i < n; ++i) raw[i] = p[i].column;
  // Order 2: the weighted least-squares polynomial c(x) = a + b x + q x^2 through the neighbours j of
  // point i, x = j - i (a stretch has consecutive rows), triangular weight half_rows + 1 - |x|; the
  // smoothed centre is a. Columns relative to raw[i] so that floats keep their precision. Plain scalar
  // sums and Cramer's rule: this runs for every point of every frame (an Eigen 3x3 version cost 0.6 ms
  // per 964-row frame, twice the whole extraction); `keep(j)` says whether j enters.
  struct Fit {
    double a = 0, b = 0, q = 0;
  };
  auto fit = [&](int i, int lo, int hi, auto&& keep) {
    double s0 = 0, s1 = 0, s2 = 0, s3 = 0, s4 = 0, t0 = 0, t1 = 0, t2 = 0;
    const double ri = raw[i];
    for (int j = lo; j <= hi; ++j) {
      if (!keep(j)) continue;
      const double x = j - i;
      const double w = half_rows + 1 - std::abs(x);
      const double y = raw[j] - ri;
      const double wx = w * x, wxx = wx * x;
      s0 += w;
      s1 += wx;
      s2 += wxx;
      t0 += w * y;
      t1 += wx * y;
      if (order >= 2) {
        s3 += wxx * x;
        s4 += wxx * x * x;
        t2 += wxx * y;
      }
    }
    Fit f;
    if (order >= 2) {
      const double det = s0 * (s2 * s4 - s3 * s3) - s1 * (s1 * s4 - s3 * s2) + s2 * (s1 * s3 - s2 * s2);
      if (std::abs(det) > 1e-9 * s0 * s2 * s4) {  // not enough distinct rows: fall back to the line
        f.a = (t0 * (s2 * s4 - s3 * s3) - s1 * (t1 * s4 - s3 * t2) + s2 * (t1 * s3 - s2 * t2)) / det;
        f.b = (s0 * (t1 * s4 - t2 * s3) - t0 * (s1 * s4 - s3 * s2) + s2 * (s1 * t2 - t1 * s2)) / det;
        f.q = (s0 * (s2 * t2 - s3 * t1) - s1 * (s1 * t2 - s2 * t1) + t0 * (s1 * s3 - s2 * s2)) / det;
        f.a += ri;
        return f;
      }
    }
    const double det = s0 * s2 - s1 * s1;
    if (order >= 1 && det > 1e-9 * s0 * s2) {
      f.a = (s2 * t0 - s1 * t1) / det;
      f.b = (s0 * t1 - s1 * t0) / det;
    } else {
      f.a = t0 / s0;
    }
    f.a += ri;
    return f;
  };
  // Two passes: the second without the neighbours the first does not explain (a glint, a wrong peak),
  // only when there are such. The point itself always stays, so its neighbours alone cannot move it.
  auto robust_fit = [&](int i, int lo, int hi) {
    const Fit first = fit(i, lo, hi, [](int) { return true; });
    auto explained = [&](int j) {
      const double x = j - i;
      return j == i || std::abs(raw[j] - (first.a + x * (first.b + x * first.q))) <= outlier_px;
    };
    bool all = true;
    for (int j = lo; j <= hi && all; ++j) all = explained(j);
    return all ? first.a : fit(i, lo, hi, explained).a;
  };
  // A stretch that holds a steep step (joined by steep_step_change_px): the same two fits one point at a
  // time, the outlier test across the line (a column residual r of a line of slope b is r / sqrt(1 + b^2)
  // across it).
  // A straight fit (q = 0: order 1, the default) has one slope, so its limit is computed once: slope is then
  // b + (+-0), whose square is b's (the same bits). Its square root per neighbour was 1.5 % of a typical
  // frame (perf, laser_bench BM_ExtractWebcam/1).
  auto steep_fit = [&](int i, int lo, int hi) {
    const Fit first = fit(i, lo, hi, [](int) { return true; });
    const bool straight = first.q == 0.0;
    const double straight_limit = outlier_px * std::sqrt(1.0 + first.b * first.b);
    auto explained = [&](int j) {
      const double x = j - i;
      const double slope = first.b + 2.0 * x * first.q;
      return j == i || std::abs(raw[j] - (first.a + x * (first.b + x * first.q))) <=
                           (straight ? straight_limit : outlier_px * std::sqrt(1.0 + slope * slope));
    };
    bool all = true;
    for (int j = lo; j <= hi && all; ++j) all = explained(j);
    return all ? first.a : fit(i, lo, hi, explained).a;
  };
  // Order 0 and 1 (the default): every fit from prefix sums in O(1). With j the index in the stretch and
  // y the column relative to the stretch's first, the sums of the fit of point k over x in [xa, xb]
  // (j = k + x) split at x = 0 into a left part with w = h + 1 + x and a right part with w = h + 1 - x,
  // and each part's sum w y and w x y comes from the range sums of y, j y and j^2 y (x = j - k). The
  // weights' sums s0, s1, s2 are integers, from running sums over x. A second fit whose kept neighbours
  // are again a range around the point (outliers at the window's ends: a curved line) is O(1) the same
  // way; other second fits subtract the outliers' terms from the first's sums.
  const int h = half_rows;
  SmoothScratch& buffers = smooth_scratch();
  std::vector<double>& prefix = buffers.prefix;
  std::vector<uint64_t>& bits = buffers.bits;
  std::vector<std::array<double, 4>>& cumulative = buffers.cumulative;
  std::vector<int>& steep_points = buffers.steep_points;
  steep_points.clear();
  cumulative.resize(static_cast<size_t>(2 * h + 2));
  std::array<double, 4> weight_sums{};  // sums of w, w x, w x^2, w x^3 over x = -h .. x - 1, at index x + h
  for (int x = -h; x <= h; ++x) {
    cumulative[static_cast<size_t>(x + h)] = weight_sums;
    const double w = h + 1 - std::abs(x);
    weight_sums[0] += w;
    weight_sums[1] += w * x;
    weight_sums[2] += w * x * x;
    weight_sums[3] += w * x * x * x;
  }
  cumulative[static_cast<size_t>(2 * h + 1)] = weight_sums;
  const double inv_s0_whole = 1.0 / weight_sums[0], inv_s2_whole = 1.0 / weight_sums[2];
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  const bool avx2 = HaveAvx2();
#endif
  // The exact outlier test of a flagged point in vectors (OutlierBits) while the window fits in the
  // 64 bits; one neighbour at a time beyond.
  const bool vector_test = 2 * h + 1 <= 64;
  std::array<double, 64 + 4> window_x;
  for (int k = 0; k < 64 + 4; ++k) window_x[static_cast<size_t>(k)] = k - h;
  struct Sums {
    double s0, s1, s2, t0, t1;
  };
  auto smooth_stretch = [&](auto&& self, int start, int end) -> void {
    const int len = end - start + 1;
    if (len < 2) return;
    bool steep = false;
    for (int i = start; i < end && !steep && steep_step_change_px > 0.0; ++i)
      steep = std::abs(raw[i + 1] - raw[i]) > max_jump_px;
    if (steep) {
      // Its runs of kKeepRows or more rows without a steep step are smoothed as stretches of their own
      // (as without the joining); the other points by the fit over the joined stretch.
      for (int first = start; first <= end;) {
        int last = first;
        while (last < end && std::abs(raw[last + 1] - raw[last]) <= max_jump_px) ++last;
        if (last - first + 1 >= kKeepRows) {
          // A run holds no steep step, so this call never reaches this branch: steep_points (shared) stays
          // this call's own.
          self(self, first, last);
        } else {
          for (int i = first; i <= last; ++i) steep_points.push_back(i);
        }
        first = last + 1;
      }
      // The joined fits (each point's window over the joined stretch), 4 points at a time by SteepFitsAvx2 (the
      // same bits; the runs above are short, most a single row, so the 4 come from several). Its 4 chains of
      // sums in one loop rather than one latency-bound chain per point: the fit had been ~4 % of a typical
      // frame (perf, laser_bench BM_ExtractWebcam/1).
      size_t k = 0;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
      if (avx2 && order <= 1) {
        for (; k + 4 <= steep_points.size(); k += 4) {
          double fa[4];
          SteepFitsAvx2(raw, steep_points.data() + k, start, end, h, order >= 1, outlier_px, fa);
          for (int lane = 0; lane < 4; ++lane)
            p[steep_points[k + static_cast<size_t>(lane)]].column = static_cast<float>(fa[lane]);
        }
      }
#endif
      for (; k < steep_points.size(); ++k) {
        const int i = steep_points[k];
        p[i].column = static_cast<float>(steep_fit(i, std::max(start, i - h), std::min(end, i + h)));
      }
      steep_points.clear();
      return;
    }
    if (order == 2) {
      for (int i = start; i <= end; ++i) {
        p[i].column = static_cast<float>(robust_fit(i, std::max(start, i - h), std::min(end, i + h)));
      }
      return;
    }
    const double origin = raw[start];
    const size_t m = static_cast<size_t>(len);
    prefix.resize(7 * (m + 1));
    double* py = prefix.data();  // sums over j < index of y, j y, j^2 y
    double* pjy = py + (m + 1);
    double* pjjy = pjy + (m + 1);
    double* fit_a = pjjy + (m + 1);  // the first fit, a absolute
    double* fit_b = fit_a + (m + 1);
    double* bend = fit_b + (m + 1);  // each point's curvature correction (below)
    double* curve = bend + (m + 1);  // prefix sums of the curvature estimates
    // The sums run in registers (a store and reload per step would put store forwarding on each chain).
    double sy = 0, sjy = 0, sjjy = 0, max_rel = 0;
    py[0] = pjy[0] = pjjy[0] = 0.0;
    for (int k = 0; k < len; ++k) {
      const double y = raw[start + k] - origin;
      rel[k] = static_cast<float>(y);
      max_rel = std::max(max_rel, std::abs(y));
      sy += y;
      sjy += k * y;
      sjjy += static_cast<double>(k) * k * y;
      py[k + 1] = sy;
      pjy[k + 1] = sjy;
      pjjy[k + 1] = sjjy;
    }
    // Outside the stretch the screen reads NaN, which its maxima skip: its windows end where the
    // stretch does.
    const float nan = std::numeric_limits<float>::quiet_NaN();
    std::fill(rel - pad, rel, nan);
    std::fill(rel + len, rel + len + pad, nan);
    auto window = [&](int k, int* xa, int* xb) {
      *xa = std::max(-h, -k);
      *xb = std::min(h, len - 1 - k);
    };
    auto range_sums = [&](int k, int xa, int xb) {
      const std::array<double, 4>& hi = cumulative[static_cast<size_t>(xb + h + 1)];
      const std::array<double, 4>& lo = cumulative[static_cast<size_t>(xa + h)];
      const double kd = k;
      const double ly = py[k] - py[k + xa], ljy = pjy[k] - pjy[k + xa], ljjy = pjjy[k] - pjjy[k + xa];
      const double ry = py[k + xb + 1] - py[k], rjy = pjy[k + xb + 1] - pjy[k], rjjy = pjjy[k + xb + 1] - pjjy[k];
      const double lxy = ljy - kd * ly, lxxy = ljjy - 2 * kd * ljy + kd * kd * ly;
      const double rxy = rjy - kd * ry, rxxy = rjjy - 2 * kd * rjy + kd * kd * ry;
      const double hp = h + 1;
      return Sums{hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], hp * (ly + ry) + lxy - rxy, hp * (lxy + rxy) + lxxy - rxxy};
    };
    // a (relative) and b of the fit with these sums, as the general fit solves it.
    auto solve = [&](const Sums& u, double* fa, double* fb) {
      const double det = u.s0 * u.s2 - u.s1 * u.s1;
      if (order >= 1 && det > 1e-9 * u.s0 * u.s2) {
        const double inverse = 1.0 / det;
        *fa = (u.s2 * u.t0 - u.s1 * u.t1) * inverse;
        *fb = (u.s0 * u.t1 - u.s1 * u.t0) * inverse;
      } else {
        *fa = u.t0 / u.s0;
        *fb = 0.0;
      }
    };
    double max_b = 0;
    int vector_from = len, vector_to = len;  // the whole windows done 4 at a time
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
    if (avx2 && len - 2 * h >= 4) {
      vector_from = h;
      vector_to = h + (len - 2 * h) / 4 * 4;
      max_b = WholeWindowFitsAvx2(py, pjy, pjjy, vector_from, vector_to, h, order >= 1, inv_s0_whole, inv_s2_whole,
                                  origin, fit_a, fit_b, af, bf);
    }
#endif
    for (int k = 0; k < len; ++k) {
      if (k == vector_from) {
        k = vector_to - 1;
        continue;
      }
      int xa, xb;
      window(k, &xa, &xb);
      double fa, fb;
      const Sums u = range_sums(k, xa, xb);
      if (xa == -h && xb == h) {  // a whole window: s1 = 0, no division
        fa = u.t0 * inv_s0_whole;
        fb = order >= 1 ? u.t1 * inv_s2_whole : 0.0;
      } else {
        solve(u, &fa, &fb);
      }
      fit_a[k] = fa + origin;
      fit_b[k] = fb;
      af[k] = static_cast<float>(fa);
      bf[k] = static_cast<float>(fb);
      max_b = std::max(max_b, std::abs(fb));
    }
    // The curvature (issue 15, twelfth session; extract.cc, "Along-line smoothing"): a straight line
    // fitted to a line that curves as y = q x^2 near the point is off by q B, with B = (S2^2 - S1 S3) /
    // (S0 S2 - S1^2) from the window's weight sums (S2 / S0 = 28 rows^2 for a whole window of +-12). q from
    // the change of the first fit's slope between the points d = kCurvatureReach h rows before and after
    // (whole windows both: b(c + d) - b(c - d) = 4 d q on a parabola), averaged over the points c within
    // kCurvatureSpan h of the point where there are such (a slope's noise, doubled by the difference,
    // would otherwise add to the fit's); a stretch too short for it (under 4 h + 1 rows) keeps the
    // straight fit.
    std::fill(bend, bend + m, 0.0);
    if (curvature && order == 1) {
      const int d = kCurvatureReach * h;
      const int from = d + h, to = len - 1 - d - h;
      if (to >= from) {
        double sum = 0.0;
        curve[0] = 0.0;
        for (int c = from; c <= to; ++c) {
          sum += (fit_b[c + d] - fit_b[c - d]) / (4.0 * d);
          curve[c - from + 1] = sum;
        }
      }
      for (int k = 0; to >= from && k < len; ++k) {
        const int lo_c = std::clamp(k - kCurvatureSpan * h, from, to);
        const int hi_c = std::clamp(k + kCurvatureSpan * h, from, to);
        const double q = (curve[hi_c - from + 1] - curve[lo_c - from]) / (hi_c - lo_c + 1);
        int xa, xb;
        window(k, &xa, &xb);
        const std::array<double, 4>& hi = cumulative[static_cast<size_t>(xb + h + 1)];
        const std::array<double, 4>& lo = cumulative[static_cast<size_t>(xa + h)];
        const double s0 = hi[0] - lo[0], s1 = hi[1] - lo[1], s2 = hi[2] - lo[2], s3 = hi[3] - lo[3];
        const double det = s0 * s2 - s1 * s1;
        if (det > 1e-9 * s0 * s2) bend[k] = q * (s2 * s2 - s1 * s3) / det;
      }
    }
    // The screen: which points' windows may hold a neighbour the first fit does not explain. Its float
    // residuals are off from the double ones by a few ulp of the largest value involved; the margin
    // covers 16, so every point the exact test finds an outlier for is flagged.
    const double magnitude = max_rel + h * max_b + outlier_px + 1.0;
    const double margin = 1e-3 + 16.0 * std::numeric_limits<float>::epsilon() * magnitude;
    const float limit = static_cast<float>(outlier_px - margin);
    const size_t words = m / 64 + 1;
    bits.assign(words + m, 0);  // the screen's bits, then the flagged points' outlier bits
    uint64_t* flagged = bits.data();
    uint64_t* outliers = flagged + words;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
    if (avx2) {
      ScreenWindowsAvx2(rel, af, bf, 0, len, h, limit, flagged);
    } else
#endif
    {
      ScreenWindows(rel, af, bf, 0, len, h, limit, flagged);
    }
    if (vector_test) {  // the exact test of the flagged points, before the window's ends are masked
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
      if (avx2) {
        FlaggedOutliersAvx2(raw + start, fit_a, fit_b, 0, len, h, outlier_px, flagged, window_x.data(), outliers);
      } else
#endif
      {
        FlaggedOutliers(raw + start, fit_a, fit_b, 0, len, h, outlier_px, flagged, window_x.data(), outliers);
      }
    }
    for (int k = 0; k < len; ++k) {
      const int i = start + k;
      if (!((flagged[static_cast<size_t>(k) >> 6] >> (k & 63)) & 1u)) {
        p[i].column = static_cast<float>(fit_a[k] - bend[k]);
        continue;
      }
      int xa, xb;
      window(k, &xa, &xb);
      uint64_t dropped = 0;  // bits x + h, while vector_test
      if (vector_test) {
        const uint64_t in_window = (~uint64_t{0} >> (63 - (xb - xa))) << (xa + h);  // bits xa + h .. xb + h
        dropped = outliers[k] & in_window;
        if (dropped == 0) {
          p[i].column = static_cast<float>(fit_a[k] - bend[k]);
          continue;
        }
        const uint64_t kept = in_window & ~dropped;  // holds bit h: the point itself always stays
        const uint64_t run = kept >> __builtin_ctzll(kept);
        if ((run & (run + 1)) == 0) {  // the kept neighbours are a range: O(1)
          double fa, fb;
          solve(range_sums(k, __builtin_ctzll(kept) - h, 63 - __builtin_clzll(kept) - h), &fa, &fb);
          p[i].column = static_cast<float>(fa + origin - bend[k]);
          continue;
        }
      }
      // The first fit's sums less the outliers' terms.
      Sums u = range_sums(k, xa, xb);
      bool any = false;
      auto drop = [&](int x) {
        any = true;
        const double w = h + 1 - std::abs(x);
        const double y = raw[i + x] - origin;
        u.s0 -= w;
        u.s1 -= w * x;
        u.s2 -= w * x * x;
        u.t0 -= w * y;
        u.t1 -= w * x * y;
      };
      if (vector_test) {
        for (uint64_t o = dropped; o != 0; o &= o - 1) drop(__builtin_ctzll(o) - h);
      } else {
        for (int x = xa; x <= xb; ++x) {
          if (x != 0 && std::abs(raw[i + x] - (fit_a[k] + x * fit_b[k])) > outlier_px) drop(x);
        }
      }
      double fa = fit_a[k] - origin, fb;
      if (any) solve(u, &fa, &fb);
      p[i].column = static_cast<float>(fa + origin - bend[k]);
    }
  };
  // Stretches: runs of consecutive rows whose column steps are at most max_jump_px. A line steeper than
  // that (a surface seen at a grazing angle: wide, unreliable rows) is not smoothed, nor are its rows
  // joined to their neighbours: measured on Spot (rotoscan evaluate --lines, 100 frames), joining rows
  // whose step merely continues the local slope raised the line centre error from 0.217 to 0.263 px.
  // With steep_step_change_px > 0 (webcam frames only: extract.cc) such rows are joined.
  auto continues = [&](int k) {
    if (p[k + 1].row != p[k].row + 1) return false;
    const double step = raw[k + 1] - raw[k];
    if (std::abs(step) <= max_jump_px) return true;
    return steep_step_change_px > 0.0 && k > 0 && p[k].row == p[k - 1].row + 1 &&
           std::abs(step - (raw[k] - raw[k - 1])) <= steep_step_change_px;
  };
  int start = 0;  // first point of the current stretch
  while (start < n) {
    int end = start;  // last point of the stretch, inclusive
    while (end + 1 < n && continues(end)) ++end;
    smooth_stretch(smooth_stretch, start, end);
    start = end + 1;
  }
}

namespace detail {

void LimitSmoothing(const std::vector<float>& own_columns, std::vector<LinePoint>* line_points) {
  std::vector<LinePoint>& points = *line_points;
  const size_t n = points.size();
  // The smoothing's limits: a point moves by at most its uncertainty, and keeps its own estimate where
  // the profile changes (saturation begins or ends, or the profile is lopsided: texture, an edge).
  // Saturation that begins or ends at a point whose albedo was divided out (kFlagAlbedoEdge) is the
  // texture's: the laser-on frame saturates over the bright cells only, and the division has taken the
  // albedo out of the profile, so the smoothing applies there, within the uncertainty (issue 15's
  // textured set, 3 steps x 2 lasers, f/4: the object's rows over 1 px across 85 -> 61; f/2.4 69 -> 53;
  // RealFramesTest.SmoothingGoesOnWhereTextureTogglesSaturation).
  // A saturation change between consecutive points k and k + 1 counts where it persists: at least
  // kSaturationRunRows rows of the same state on either side. A row or two that speckle lifts to 255 (or
  // drops from it) inside a line does not change its profile (issue 15, eleventh session; webcam sets, 8
  // steps x 2 lasers, f/4, across: glossy object over 1 px 2.22 -> 2.12 %, RMS 0.365 -> 0.363 px; textured
  // object 1.85 -> 1.83 %, 0.343 -> 0.341; 2 rows: RMS alike, over 1 px unchanged; Spot unchanged).
  auto sat = [&](size_t k) { return (points[k].flags & kFlagSaturated) != 0; };
  auto persists = [&](size_t k) {
    int left = 0, right = 0;
    for (size_t m = k + 1; m-- > 0 && left < kSaturationRunRows;) {
      if (sat(m) != sat(k) || (m < k && points[m].row + 1 != points[m + 1].row)) break;
      ++left;
    }
    for (size_t m = k + 1; m < n && right < kSaturationRunRows; ++m) {
      if (sat(m) != sat(k + 1) || points[m].row != points[m - 1].row + 1) break;
      ++right;
    }
    return left >= kSaturationRunRows && right >= kSaturationRunRows;
  };
  for (size_t i = 0; i < n; ++i) {
    LinePoint& p = points[i];
    const float own = own_columns[i];
    const bool saturated = (p.flags & kFlagSaturated) != 0;
    const bool texture = (p.flags & kFlagAlbedoEdge) != 0;
    const bool change =
        (!texture && i > 0 && points[i - 1].row + 1 == p.row && sat(i - 1) != saturated && persists(i - 1)) ||
        (!texture && i + 1 < n && points[i + 1].row == p.row + 1 && sat(i + 1) != saturated && persists(i)) ||
        (p.flags & kFlagLopsided) != 0;
    if (change) {
      p.column = own;
      continue;
    }
    p.column = own + std::clamp(p.column - own, -p.uncertainty_px, p.uncertainty_px);
  }
}

}  // namespace detail
}  // namespace rotoscan::laser
