// Step 5 of the row loop (design notes in extract.cc, "Uncertainty" and "Estimators"): a row's point from
// its chosen candidate; and the estimators themselves (EstimateCentre).
#include <algorithm>
#include <cmath>
#include <vector>

#include "extract_steps.h"
#include "kernels.h"
#include "rotoscan/core/check.h"

namespace rotoscan::laser {

double EstimateCentre(Estimator estimator, const uint8_t* d, int size, int first, int last, int peak) {
  ROTOSCAN_CHECK(first >= 0 && last < size && first <= last) << "run [" << first << ", " << last << "]";
  switch (estimator) {
    case Estimator::kCenterOfMass: {
      const int level = detail::kComLevelNum * peak;
      while (first > 0 && detail::kComScale * d[first - 1] > level) --first;
      while (last < size - 1 && detail::kComScale * d[last + 1] > level) ++last;
      return detail::CenterOfMassOver(d, first, last, peak);
    }
    case Estimator::kParabolic:
    case Estimator::kGaussian: {
      int pa = first;
      while (pa <= last && d[pa] != peak) ++pa;
      if (pa > last) return -1.0;
      int pb = pa;
      while (pb + 1 <= last && d[pb + 1] == peak) ++pb;
      const double mid = 0.5 * (pa + pb);
      if (pa == 0 || pb == size - 1) return mid;
      double l = d[pa - 1], c = peak, r = d[pb + 1];
      if (estimator == Estimator::kGaussian) {
        l = std::log(std::max(l, 0.5));
        c = std::log(std::max(c, 0.5));
        r = std::log(std::max(r, 0.5));
      }
      const double denominator = l - 2 * c + r;
      if (denominator >= 0) return mid;
      const double delta = 0.5 * (l - r) / denominator;
      return mid + std::clamp(delta, -0.5, 0.5);
    }
    case Estimator::kZeroCrossing: {
      const int k = std::max(1, static_cast<int>(std::lround(0.5 * (last - first + 1))));
      auto g = [&](int i) {
        const int hi = std::min(i + k, size - 1);
        const int lo = std::max(i - k, 0);
        return int{d[hi]} - int{d[lo]};
      };
      // g is positive on the rising flank and negative on the falling one; find the crossing nearest
      // the middle of the run.
      const double mid = 0.5 * (first + last);
      double best = -1.0;
      for (int i = first - 1; i <= last; ++i) {
        if (i < 0 || i + 1 >= size) continue;
        const int gi = g(i);
        if (gi <= 0) continue;
        int j = i + 1;
        while (j <= last + 1 && j < size && g(j) == 0) ++j;
        if (j >= size || g(j) >= 0) continue;
        const double x = (j == i + 1) ? i + static_cast<double>(gi) / (gi - g(j)) : 0.5 * (i + j);
        if (best < 0 || std::abs(x - mid) < std::abs(best - mid)) best = x;
      }
      return best;
    }
  }
  return -1.0;
}

namespace detail {

namespace {

// The Gaussian kernel of kAlbedoBlurPx, radius 3 sigma (kAlbedoRadius, extract_steps.h).
static_assert(kAlbedoRadius >= 3 * kAlbedoBlurPx, "the kernel's radius is 3 sigma");
struct AlbedoKernel {
  double w[2 * kAlbedoRadius + 1];
  AlbedoKernel() {
    for (int k = -kAlbedoRadius; k <= kAlbedoRadius; ++k)
      w[k + kAlbedoRadius] = std::exp(-0.5 * k * k / (kAlbedoBlurPx * kAlbedoBlurPx));
  }
};

// The reciprocal of the divisor of the difference at a pixel whose blurred laser-off value is `blurred`
// (DN, at least floor_dn): blurred^-kAlbedoExponent (extract_steps.h), up to a constant factor (the
// centre of mass of the ratio does not see one). From a table over 0..256 DN in steps of 1/16 DN,
// interpolated linearly (relative error under 1e-4 at the 3 DN floor): a pow per pixel of every divided
// row cost a textured frame ~15k of them.
struct AlbedoPowerTable {
  static constexpr int kSteps = 16;
  float v[256 * kSteps + 2];
  AlbedoPowerTable() {
    for (int i = 0; i < 256 * kSteps + 2; ++i)
      v[i] = static_cast<float>(std::pow(std::max(1.0, static_cast<double>(i) / kSteps), -kAlbedoExponent));
  }
};
static_assert(AlbedoPowerTable::kSteps == kAlbedoPowerSteps, "the AVX2 path's table step");
double AlbedoInverseDivisor(double blurred, double floor_dn) {
  const float* v = AlbedoPowerTableValues();
  const double x = std::min(std::max(blurred, floor_dn), 256.0) * AlbedoPowerTable::kSteps;
  const int i = static_cast<int>(x);
  const double t = x - i;
  return v[i] + t * (v[i + 1] - v[i]);
}

// The laser-off row's edge over [lo, hi] (kAlbedoSharpEdgeNum): its range and its steepest two-pixel
// change, and whether the laser-on row saturates there. AlbedoNormalisedCentre and ClippedAlbedoCentre
// judge the same window by it.
// An edge is sharp where its steepest two-pixel change holds kAlbedoSharpEdgeNum / Den of its range.
bool SharpEdge(int steepest, int high, int low) {
  return kAlbedoSharpEdgeDen * steepest >= kAlbedoSharpEdgeNum * (high - low);
}
struct OffEdge {
  int high = 0, low = 255, steepest = 0;
  bool saturated = false;
  bool Sharp() const { return SharpEdge(steepest, high, low); }
};
OffEdge ScanOffEdge(const uint8_t* a, const uint8_t* b, int lo, int hi) {
  OffEdge e;
  for (int i = lo; i <= hi; ++i) {
    e.saturated |= a[i] == 255;
    e.high = std::max(e.high, int{b[i]});
    e.low = std::min(e.low, int{b[i]});
    if (i > lo + 1) e.steepest = std::max(e.steepest, std::abs(int{b[i]} - int{b[i - 2]}));
  }
  return e;
}
// The steepest two-pixel change of the row b over [lo, hi] (ScanOffEdge's, alone).
int SteepestChange(const uint8_t* b, int lo, int hi) {
  int steepest = 0;
  for (int i = lo + 2; i <= hi; ++i) steepest = std::max(steepest, std::abs(int{b[i]} - int{b[i - 2]}));
  return steepest;
}

}  // namespace

void WidenUncertainty(double with, LinePoint* p) {
  const double u = p->uncertainty_px;
  p->uncertainty_px = static_cast<float>(with);
  p->quality = static_cast<float>(p->quality * (1.0 + u * u) / (1.0 + with * with));
}

const double* AlbedoBlurWeights() {
  static const AlbedoKernel kernel;
  return kernel.w;
}

const float* AlbedoPowerTableValues() {
  static const AlbedoPowerTable table;
  return table.v;
}

double AlbedoBlurredRatioAt(const uint8_t* d, const uint8_t* b, int cols, int i, double floor_dn) {
  const double* weights = AlbedoBlurWeights();
  double sw = 0, sv = 0;
  for (int k = std::max(0, i - kAlbedoRadius); k <= std::min(cols - 1, i + kAlbedoRadius); ++k) {
    const double w = weights[k - i + kAlbedoRadius];
    sw += w;
    sv += w * b[k];
  }
  return d[i] * AlbedoInverseDivisor(sv / sw, floor_dn);
}

// The blurred division's ratio: its 7 products and the table's interpolation per pixel were 12 % of a
// typical frame's row loop (perf, laser_bench BM_ExtractWebcam/4; the textured set divides ~1 row in 4);
// with AVX2 the pixels whose blur lies inside the row go 4 at a time (AlbedoBlurredRatioAvx2, bit for bit).
void AlbedoBlurredRatio(const uint8_t* d, const uint8_t* b, int cols, int lo, int hi, double floor_dn,
                        double* ratio) {
  int i = lo;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  const int from = std::max(lo, kAlbedoRadius), to = std::min(hi, cols - 1 - kAlbedoRadius);
  const int count = to >= from ? (to - from + 1) / 4 * 4 : 0;
  if (count > 0 && HaveAvx2()) {
    for (; i < from; ++i) ratio[i - lo] = AlbedoBlurredRatioAt(d, b, cols, i, floor_dn);
    AlbedoBlurredRatioAvx2(d, b, from, count, floor_dn, ratio + (from - lo));
    i = from + count;
  }
#endif
  for (; i <= hi; ++i) ratio[i - lo] = AlbedoBlurredRatioAt(d, b, cols, i, floor_dn);
}

bool AlbedoEdgeInside(const uint8_t* b, int first, int last, bool narrow_bright, bool shading_ramps) {
  if (last - first < 3) return false;
  const ByteRange range = MinMaxRange(b, first, last);  // kernels.h
  const int low = range.low, high = range.high;
  if (!(low >= kAlbedoMinLowDn && high >= kAlbedoMinOffDn && 5 * high > 8 * low + 5 * kAlbedoStepDn)) return false;
  // An edge, not shading: the steepest change over kAlbedoEdgeSpanPx pixels holds at least half of the
  // range. Shading (a limb, a surface turning away from the lamp) ramps over many pixels, and the laser,
  // coming from elsewhere, is not shaded like the ambient light: dividing by it would add an error
  // (measured on the glossy set: 114 rows so divided at a sphere's limb had 20 over 1 px against 9).
  int steepest = 0;
  for (int i = first; i + kAlbedoEdgeSpanPx <= last; ++i)
    steepest = std::max(steepest, std::abs(int{b[i + kAlbedoEdgeSpanPx]} - int{b[i]}));
  if (2 * steepest < high - low) return false;
  // A single gradual ramp (kShadingRampNum, extract_steps.h): a limb's shading, where the webcam's frames
  // showed the division pulling the centre to the dark side.
  if (shading_ramps && kShadingRampDen * steepest < kShadingRampNum * (high - low)) {
    int variation = 0;
    for (int i = first + 1; i <= last; ++i) variation += std::abs(int{b[i]} - int{b[i - 1]});
    if (kShadingMonotoneDen * variation < kShadingMonotoneNum * (high - low)) return false;
  }
  // Both levels resolved: at least kAlbedoMinLevelPx pixels above and below the middle of the range. The
  // red channel does not resolve a narrower feature (4:2:0 chroma and demosaicing halve its resolution,
  // the optics blur it), so the division would only add the blurs' mismatch; and a small bright spot of
  // the laser-off frame may be a lamp's highlight, which the laser, coming from elsewhere, does not share
  // (RealFramesTest.DesignStatisticsWithNotches...: a 2 px texel). But with narrow_bright a bright level
  // kAlbedoNarrowBrightPx wide where the row is blurred: a white cell's sliver (extract_steps.h).
  const int middle = high + low;  // doubled
  int above = 0;
  for (int i = first; i <= last; ++i) above += 2 * b[i] > middle;
  if (last - first + 1 - above < kAlbedoMinLevelPx) return false;
  if (above >= kAlbedoMinLevelPx) return true;
  return narrow_bright && above >= kAlbedoNarrowBrightPx && !SharpEdge(SteepestChange(b, first, last), high, low);
}

double AlbedoNormalisedCentre(const uint8_t* a, const uint8_t* d, const uint8_t* b, int cols, int first, int last) {
  // The window: the half-maximum extent widened by its own width each side (the line's part on a dark
  // cell lies below the difference's half maximum, often below its centre-of-mass level).
  const int width = last - first + 1;
  int lo = std::max(0, first - width), hi = std::min(cols - 1, last + width);
  if (hi - lo + 1 > kAlbedoMaxWindow) return -1.0;
  // The edge's sharpness (kAlbedoSharpEdgeNum) and whether the laser-on row saturates there.
  const OffEdge edge = ScanOffEdge(a, b, lo, hi);
  const double floor_dn = std::max(3.0, 0.05 * edge.high);
  const bool sharp = edge.Sharp() && !edge.saturated;
  // The ratio's peak is looked for within the extent widened by half its width each side (by
  // kAlbedoSharpReach - 1/2 widths where the edge is sharp).
  int reach2 = width;  // doubled
  if (sharp) {
    lo = std::max(0, first - kAlbedoSharpReach * width);
    hi = std::min(cols - 1, last + kAlbedoSharpReach * width);
    reach2 = (2 * kAlbedoSharpReach - 1) * width;
    if (hi - lo + 1 > kAlbedoMaxWindow) return -1.0;
  }
  const int n = hi - lo + 1;
  double ratio[kAlbedoMaxWindow];
  if (sharp) {
    // An unblurred frame: the difference is the profile times the albedo pixel by pixel.
    for (int i = lo; i <= hi; ++i) ratio[i - lo] = d[i] / std::max(static_cast<double>(b[i]), floor_dn);
  } else {
    // A blurred one: by the row blurred by kAlbedoBlurPx, to the power kAlbedoExponent (extract_steps.h).
    AlbedoBlurredRatio(d, b, cols, lo, hi, floor_dn, ratio);
  }
  // The centre of mass of the ratio, as kCenterOfMass's (level 0.15 of its peak), from the ratio's
  // highest value within the reach above.
  int peak = std::max(0, first - lo - reach2 / 2);
  const int search_end = std::min(n - 1, last - lo + reach2 / 2);
  for (int i = peak + 1; i <= search_end; ++i)
    if (ratio[i] > ratio[peak]) peak = i;
  const double level = kComLevelNum * ratio[peak] / kComScale;
  int f = peak, l = peak;
  while (f > 0 && ratio[f - 1] > level) --f;
  while (l < n - 1 && ratio[l + 1] > level) ++l;
  double sum = 0, moment = 0;
  for (int i = f; i <= l; ++i) {
    sum += ratio[i] - level;
    moment += (ratio[i] - level) * i;
  }
  if (!(sum > 0)) return -1.0;
  return lo + moment / sum;
}

// A line saturated in the laser-on frame over an albedo edge (issue 15; design notes "Albedo inside the
// line"). In an unblurred frame a pixel's laser-on value is a = min(255, rho (A + L)) and its laser-off value
// b = rho A (rho the albedo, A the ambient light, L the laser's profile, all up to the sensor's gain: the
// paper's differential imaging, section III; it numbers no equation for the centre). Where a < 255 the ratio
// (a - b) / b = L / A is the profile whatever the albedo; where a = 255 it is only known to be at least
// (255 - b) / b, a bound that is higher on a dark cell than on a white one, so the difference (notch-filled
// to its plateau) divided by the albedo is not the profile there, and its centre of mass was off by up to
// 1.5 px (our renderer's checker cylinder at 1280x960: 12.8 % of the rows over 1 px, every one of them
// saturated). The ratio is known everywhere up to the lowest of those bounds over the saturated pixels, T:
// min((a - b) / b, T) = min(L / A, T) at every pixel (a saturated one is T). For a profile symmetric about
// its centre, min(L / A, T) is symmetric about the same centre whatever T is, and its centre of mass over
// the run above 0.15 T (kCenterOfMass's level) is the line's centre. Measured in README "Frames from
// POV-Ray" and SaturatedEdgeTest.
// Only where the laser-off row's edge is sharp (kAlbedoSharpEdgeNum, over the extent widened by its width
// each side, as AlbedoNormalisedCentre tests it): only there is the difference the profile times the albedo
// pixel by pixel. Where the frame is blurred (a webcam: demosaicing, 4:2:0 JPEG, after the sensor clipped)
// the clipped 255 is spread into the dark cell's pixels and this estimate was worse than the blurred
// division: the textured webcam set (8 steps x 2 lasers, f/4, per row without smoothing), its 980 rows
// saturated at a divided albedo edge: 101 over 1 px across, RMS 0.596 px, against 60 and 0.506 px for
// AlbedoNormalisedCentre's blurred rule (the ratio here then by the row blurred 1 px to the power 0.9).
double ClippedAlbedoCentre(const uint8_t* a, const uint8_t* d, const uint8_t* b, int cols, int first,
                           int last) {
  const int width = last - first + 1;
  const int lo = std::max(0, first - width), hi = std::min(cols - 1, last + width);
  const OffEdge edge = ScanOffEdge(a, b, lo, hi);
  if (!edge.Sharp()) return -1.0;
  const double floor_dn = std::max(3.0, 0.05 * edge.high);
  auto albedo = [&](int i) { return std::max(static_cast<double>(b[i]), floor_dn); };
  // The saturated run (the first and last laser-on pixel at 255 in the extent) and the clip level T: the
  // lowest ratio that any of its pixels is known to reach, (255 - b) / b.
  int run_first = -1, run_last = -1;
  double clip = 0;
  for (int i = first; i <= last; ++i) {
    if (a[i] != 255 || 255 - b[i] < kAlbedoStepDn) continue;
    const double bound = (255 - b[i]) / albedo(i);
    clip = run_first < 0 ? bound : std::min(clip, bound);
    if (run_first < 0) run_first = i;
    run_last = i;
  }
  if (run_first < 0) return -1.0;
  // The ratio clipped at T: T wherever the laser-on row is at 255, and wherever the ratio exceeds T.
  auto clipped = [&](int i) { return a[i] == 255 ? clip : std::min(clip, d[i] / albedo(i)); };
  // Its centre of mass over the run above kComLevelNum / kComScale of T, as kCenterOfMass's, the run
  // followed out from the saturated pixels (at most kAlbedoMaxWindow / 2 each way).
  const double level = kComLevelNum * clip / kComScale;
  const int reach = kAlbedoMaxWindow / 2;
  double sum = 0, moment = 0;
  auto add = [&](int i) {
    const double w = clipped(i) - level;
    if (w <= 0) return false;
    sum += w;
    moment += w * i;
    return true;
  };
  for (int i = run_first; i <= run_last; ++i) add(i);
  for (int i = run_first - 1; i >= std::max(0, run_first - reach) && add(i); --i) {
  }
  for (int i = run_last + 1; i <= std::min(cols - 1, run_last + reach) && add(i); ++i) {
  }
  if (!(sum > 0)) return -1.0;
  return moment / sum;
}

namespace {

// The laser's light per albedo in row r over [first, last]: the difference over the laser-off row (floored
// as the division floors it), summed. A dark cell's line and a white cell's weigh alike (a horizontal cell
// edge along the line is no end), the surface above a rim, unlit by the laser, is ~0.
double LightPerAlbedo(const FrameRows& f, int r, int first, int last) {
  const int step = f.on->channels();
  const uint8_t* a = f.on->ptr<uint8_t>(r) + f.channel;
  const uint8_t* b = f.off->ptr<uint8_t>(r) + f.channel;
  int high = 0;
  for (int i = first; i <= last; ++i) high = std::max(high, int{b[i * step]});
  const double floor_dn = std::max(3.0, 0.05 * high);
  double sum = 0;
  for (int i = first; i <= last; ++i)
    sum += std::max(0, int{a[i * step]} - int{b[i * step]}) / std::max(floor_dn, static_cast<double>(b[i * step]));
  return sum;
}

// The highest difference of row r over [first, last].
int PeakInRow(const FrameRows& f, int r, int first, int last) {
  const int step = f.on->channels();
  const uint8_t* a = f.on->ptr<uint8_t>(r) + f.channel;
  const uint8_t* b = f.off->ptr<uint8_t>(r) + f.channel;
  int peak = 0;
  for (int i = first; i <= last; ++i) peak = std::max(peak, int{a[i * step]} - int{b[i * step]});
  return peak;
}

// The centre of mass of row r's difference over [first, last].
double DifferenceCentre(const FrameRows& f, int r, int first, int last) {
  const int step = f.on->channels();
  const uint8_t* a = f.on->ptr<uint8_t>(r) + f.channel;
  const uint8_t* b = f.off->ptr<uint8_t>(r) + f.channel;
  double sum = 0, moment = 0;
  for (int i = first; i <= last; ++i) {
    const int v = std::max(0, int{a[i * step]} - int{b[i * step]});
    sum += v;
    moment += v * static_cast<double>(i);
  }
  return sum > 0 ? moment / sum : -1e9;
}

}  // namespace

int AlbedoDivisorRow(const FrameRows& f, int row, int first, int last, int peak) {
  const int rows = f.on->rows;
  if (peak < kAlbedoEndMinPeakDn || row - kAlbedoEndReachRows < 0 ||
      row + kAlbedoEndSearchRows + kAlbedoEndReachRows >= rows)
    return row;
  auto weak = [&](double light, double of) { return kAlbedoEndWeakDen * light < kAlbedoEndWeakNum * of; };
  const double here = LightPerAlbedo(f, row, first, last);
  if (!weak(LightPerAlbedo(f, row - kAlbedoEndReachRows, first, last), here)) return row;  // not an end
  if (weak(LightPerAlbedo(f, row + kAlbedoEndReachRows, first, last), here)) return row;   // nor a body below
  // The line's columns: its difference's centre of mass over the extent widened by its width each side.
  const int width = last - first + 1;
  const int lo = std::max(0, first - width), hi = std::min(f.on->cols - 1, last + width);
  const double centre = DifferenceCentre(f, row, lo, hi);
  for (int k = 1; k <= kAlbedoEndSearchRows; ++k) {
    const int r = row + k;
    // The line continues there (its light per albedo not weak against the row's), and this row is not its
    // fading tail (peak under half the body row's: the rim step's rows, ends.cc).
    const double own = LightPerAlbedo(f, r, first, last);
    if (weak(own, here)) return row;
    if (2 * peak < PeakInRow(f, r, first, last)) return row;
    // The line runs down the rows there (a rim's side line): the body row's albedo is the one under this
    // row's line only where the line is at the same columns (within kAlbedoEndShiftPx).
    if (std::abs(DifferenceCentre(f, r, lo, hi) - centre) > kAlbedoEndShiftPx) return row;
    if (!weak(LightPerAlbedo(f, r - kAlbedoEndReachRows, first, last), own)) return r;
  }
  return row;
}

bool MeasurePoint(const Candidate& c, const uint8_t* a, const uint8_t* b, const uint8_t* d, int cols, int row,
                  const ExtractOptions& o, uint8_t flags, bool noise_on_lit, LinePoint* point,
                  PointTerms* terms, double* column_out, const FrameRows* frames) {
  double column;
  if (o.estimator == Estimator::kCenterOfMass) {  // EstimateCentre's, with the vector extent scans
    column = CenterOfMassOver(d, c.com_first, c.com_last, c.peak);
  } else {
    column = EstimateCentre(o.estimator, d, cols, c.first, c.last, c.peak);
  }
  if (column < 0) return false;
  bool albedo_edge = false;
  if (o.estimator == Estimator::kCenterOfMass &&
      AlbedoEdgeInside(b, std::max(0, c.com_first - kAlbedoMinLevelPx),
                       std::min(cols - 1, c.com_last + kAlbedoMinLevelPx), c.peak >= kAlbedoNarrowMinPeakDn,
                       noise_on_lit)) {
    // The albedo changes inside the line (texture, a dark-and-white edge): the reflection is the laser's
    // profile times the albedo, which pulls the centre of mass towards the brighter side by up to a
    // quarter of the width. The centre of the profile divided by the albedo as the laser-off frame
    // shows it, taken through the same optics (design notes, "Albedo inside the line").
    // Where the laser-on row saturates at the peak and the edge is sharp, the ratio clipped at its known
    // level (ClippedAlbedoCentre); else the division.
    double normalised = -1.0;
    if (a[c.peak_pos] == 255) normalised = ClippedAlbedoCentre(a, d, b, cols, c.first, c.last);
    if (normalised < 0) {
      // At a line's top end, the laser-off row of the line's body (AlbedoDivisorRow, kAlbedoEndReachRows).
      const uint8_t* divisor = b;
      if (frames != nullptr && o.albedo_end_rows && noise_on_lit) {
        const int r = AlbedoDivisorRow(*frames, row, c.first, c.last, c.peak);
        if (r != row) {
          thread_local std::vector<uint8_t> body;
          body.resize(static_cast<size_t>(cols));
          const uint8_t* p = frames->off->ptr<uint8_t>(r) + frames->channel;
          const int step = frames->off->channels();
          for (int i = 0; i < cols; ++i) body[static_cast<size_t>(i)] = p[i * step];
          divisor = body.data();
        }
      }
      normalised = AlbedoNormalisedCentre(a, d, divisor, cols, c.first, c.last);
    }
    if (normalised >= 0) {
      column = normalised;
      albedo_edge = true;
      flags |= kFlagAlbedoEdge;
    }
  }
  if (a[c.peak_pos] == 255) {
    flags |= kFlagSaturated;
    // A notch: a saturated pixel of the line whose own difference is below half the line's best.
    const NotchScan scan = ScanNotch(a, b, c.first, c.last, cols);
    if (2 * scan.worst_saturated < scan.best_difference) flags |= kFlagNotched;
  }
  if (c.first == 0 || c.last == cols - 1) flags |= kFlagClipped;
  terms->column = column;
  // The asymmetry term compares the centre with the difference's extent, which an albedo edge makes
  // lopsided on purpose: for such points the texture term stands for it.
  terms->extent_middle = albedo_edge ? column : 0.5 * (c.first + c.last);
  terms->width_num = c.width_num;
  terms->width_den = c.width_den;
  terms->peak = c.peak;
  const bool com = o.estimator == Estimator::kCenterOfMass;
  terms->overexposed = (flags & kFlagSaturated) != 0 && com;
  terms->foot = com ? c.com_last - c.com_first + 1 : 0;
  // Texture across the line (ScorePoints): the laser-off row either side of the centre's pixel.
  const int middle = static_cast<int>(column + 0.5);
  const SidesSum sides = SumsAround(b, c.com_first, middle, c.com_last, cols);
  // Where the albedo was divided out, its pull is gone: no texture term (ScorePoints), but the division's
  // own residual (ScoreAlbedoDivision).
  terms->left = albedo_edge ? 0 : sides.left;
  terms->right = albedo_edge ? 0 : sides.right;
  terms->left_n = std::max(1, middle - c.com_first);
  terms->right_n = std::max(1, c.com_last - middle);
  // Field by field: a LinePoint built on the stack and copied whole was read back before its flag byte's
  // store had landed (a store-forwarding stall per row, laser_bench).
  point->row = row;
  point->column = static_cast<float>(column);
  point->peak = static_cast<float>(c.peak);
  point->flags = flags;
  *column_out = column;
  return true;
}

void ScorePoints(const PointTerms* terms, const FrameScale& frame, std::vector<LinePoint>* points) {
  const size_t n = points->size();
  LinePoint* p = points->data();
  size_t i = 0;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  // This loop, 4 points at a time (kernels_avx2.cc): a change here must be made there too
  // (KernelsTest.ScorePointsAvx2MatchesScalar compares them bit for bit).
  if (HaveAvx2()) i = ScorePointsAvx2(terms, frame, p, n);
#endif
  float before = i > 0 ? p[i - 1].column : 0.0f;  // the previous point's column (the slope's, below)
  for (; i < n; ++i) {
    const PointTerms& t = terms[i];
    const double width = t.width_num / t.width_den;
    // Uncertainty (see the design notes): noise, speckle and the profile's asymmetry.
    const double asymmetry = t.column - t.extent_middle;
    const double noise_term = frame.noise_dn / t.peak * std::sqrt(width * (1.0 / 12.0));
    // Texture across the line: the laser's reflection is weighed by the albedo, which the laser-off frame
    // shows; an albedo that differs between the line's two halves pulls the centre towards the brighter
    // one, by up to a quarter of the width for a step across the middle.
    const double ml = t.left / t.left_n, mr = t.right / t.right_n;
    const double texture_term = 0.25 * width * std::abs(ml - mr) / std::max(1.0, ml + mr);
    const double uncertainty = 2.0 * std::sqrt(noise_term * noise_term + kSpeckleTerm2 * width +
                                               asymmetry * asymmetry + texture_term * texture_term);
    const uint8_t flags = p[i].flags;
    double quality = 1.0;
    if (frame.noise_dn > 0) quality *= std::min(1.0, t.peak * frame.quality_per_snr);
    quality *= std::min(1.0, (t.peak - 0.5 * frame.threshold) * frame.quality_per_contrast);
    if (width < frame.narrow_width || width > frame.wide_width) quality *= 0.6;
    if (flags & kFlagMultiplePeaks) quality *= 0.5;
    if (flags & kFlagClipped) quality *= 0.3;
    if (flags & kFlagStrongerRejected) quality *= 0.5;
    quality /= 1.0 + uncertainty * uncertainty;
    // A steep line (a surface seen at a grazing angle: the line runs along the rows) has a poorly defined
    // centre per row: an error of the profile along the row is the slope times one across it. The
    // uncertainty grows by sqrt(1 + slope^2), the slope from the neighbouring rows' centres.
    const bool up = i > 0 && p[i - 1].row + 1 == p[i].row;
    const bool down = i + 1 < n && p[i + 1].row == p[i].row + 1;
    const float here = p[i].column;
    float slope = 0.0f;
    if (up && down) {
      slope = 0.5f * (p[i + 1].column - before);
    } else if (up) {
      slope = here - before;
    } else if (down) {
      slope = p[i + 1].column - here;
    }
    before = here;
    const float grow = 1.0f + slope * slope;
    p[i].width = static_cast<float>(width);
    p[i].quality = static_cast<float>(std::clamp(quality, 0.0, 1.0)) / grow;
    p[i].uncertainty_px = static_cast<float>(uncertainty) * std::sqrt(grow);
    if (std::abs(asymmetry) > 0.25 * width) p[i].flags = flags | kFlagLopsided;
  }
  ScoreAlbedoDivision(points);
}

void ScoreAlbedoDivision(std::vector<LinePoint>* points) {
  // Most frames have no such point: nothing more to do (one pass over the flags).
  if (std::none_of(points->begin(), points->end(), [](const LinePoint& p) { return (p.flags & kFlagAlbedoEdge) != 0; }))
    return;
  // The line's usual width: the median of the frame's points.
  thread_local std::vector<float> widths;
  widths.clear();
  for (const LinePoint& p : *points) widths.push_back(p.width);
  std::nth_element(widths.begin(), widths.begin() + static_cast<std::ptrdiff_t>(widths.size() / 2), widths.end());
  const double usual = widths[widths.size() / 2];
  for (LinePoint& p : *points) {
    if (!(p.flags & kFlagAlbedoEdge)) continue;
    // The uncertainty before (its steep-line growth kept) and after the division's residual is added,
    // larger where the difference is narrower than the line's usual width (a dark cell cuts the line).
    const double residual = kAlbedoResidualPx * std::max(1.0, usual / std::max(1.0, static_cast<double>(p.width)));
    WidenUncertainty(std::hypot(static_cast<double>(p.uncertainty_px), residual), &p);
  }
}

void ScoreLineEnds(double max_jump_px, int rows, std::vector<LinePoint>* line_points) {
  std::vector<LinePoint>& points = *line_points;
  const size_t n = points.size();
  size_t start = 0;
  while (start < n) {
    // The stretch [start, end): rows at most 2 apart (as the row loop's continuity), no jump over
    // max_jump_px per row.
    size_t end = start + 1;
    while (end < n) {
      const int gap = points[end].row - points[end - 1].row;
      if (gap > 2 || std::abs(points[end].column - points[end - 1].column) > max_jump_px * gap) break;
      ++end;
    }
    // An end at the image's first or last rows is the frame's edge, not the line's.
    const bool open_top = points[start].row > 1;
    const bool open_bottom = points[end - 1].row < rows - 2;
    for (size_t i = start; i < end; ++i) {
      size_t from_end = static_cast<size_t>(kLineEndRows);
      if (open_top) from_end = std::min(from_end, i - start);
      if (open_bottom) from_end = std::min(from_end, end - 1 - i);
      if (from_end < static_cast<size_t>(kLineEndRows))
        points[i].quality *= static_cast<float>(from_end + 1) / static_cast<float>(kLineEndRows + 1);
    }
    start = end;
  }
}

void WidenAtLineBreaks(std::vector<LinePoint>* line_points) {
  std::vector<LinePoint>& p = *line_points;
  const size_t n = p.size();
  // The column change per row from point k - 1 to point k, where they are at most 2 rows apart.
  auto step = [&p](size_t k, float* per_row) {
    const int gap = p[k].row - p[k - 1].row;
    if (gap > 2) return false;
    *per_row = (p[k].column - p[k - 1].column) / static_cast<float>(gap);
    return true;
  };
  for (size_t k = 1; k < n; ++k) {
    float here = 0.0f, slope = 0.0f;
    if (!step(k, &here)) continue;
    if (!(k >= 2 && step(k - 1, &slope)) && !(k + 1 < n && step(k + 1, &slope))) slope = 0.0f;
    const float jump = std::abs(here - slope) * static_cast<float>(p[k].row - p[k - 1].row);
    if (!(jump > kBreakJumpPx)) continue;
    const int first = p[k - 1].row - kBreakReachRows, last = p[k].row + kBreakReachRows;
    size_t i = k - 1;
    while (i > 0 && p[i - 1].row >= first) --i;
    for (; i < n && p[i].row <= last; ++i) {
      if (jump > p[i].uncertainty_px) WidenUncertainty(jump, &p[i]);
    }
  }
}

int FlagGlints(const PointTerms* terms, int rows, std::vector<LinePoint>* line_points) {
  std::vector<LinePoint>& points = *line_points;
  const size_t n = points.size();
  if (n == 0) return 0;
  if (std::none_of(terms, terms + n, [](const PointTerms& t) { return t.overexposed; })) return 0;
  // Each saturated point's reference: the median foot of the points kGlintNearRows+1 to kGlintReachRows
  // rows away, from a histogram of the feet that slides with the rows (the points are in row order, one
  // a row): a point enters it at kGlintReachRows rows ahead, leaves it at kGlintNearRows, comes back at
  // kGlintNearRows behind and leaves for good past kGlintReachRows.
  constexpr int kMaxFoot = 255;
  auto foot_of = [&](size_t j) { return std::clamp(terms[j].foot, 0, kMaxFoot); };
  thread_local std::vector<int> histogram;
  thread_local std::vector<float> reference;  // the median foot, or 0 where too few points
  histogram.assign(kMaxFoot + 1, 0);
  reference.assign(n, 0.0f);
  int in_reference = 0;
  size_t far_ahead = 0, near_ahead = 0, near_behind = 0, far_behind = 0;
  for (size_t i = 0; i < n; ++i) {
    const int row = points[i].row;
    for (; far_ahead < n && points[far_ahead].row <= row + kGlintReachRows; ++far_ahead, ++in_reference)
      ++histogram[static_cast<size_t>(foot_of(far_ahead))];
    for (; near_ahead < n && points[near_ahead].row <= row + kGlintNearRows; ++near_ahead, --in_reference)
      --histogram[static_cast<size_t>(foot_of(near_ahead))];
    for (; near_behind < n && points[near_behind].row < row - kGlintNearRows; ++near_behind, ++in_reference)
      ++histogram[static_cast<size_t>(foot_of(near_behind))];
    for (; far_behind < n && points[far_behind].row < row - kGlintReachRows; ++far_behind, --in_reference)
      --histogram[static_cast<size_t>(foot_of(far_behind))];
    if (!terms[i].overexposed || in_reference < kGlintMinReference) continue;
    // The median (the lower one of an even count).
    int below = 0, foot = 0;
    while (below + histogram[static_cast<size_t>(foot)] <= (in_reference - 1) / 2)
      below += histogram[static_cast<size_t>(foot++)];
    reference[i] = static_cast<float>(foot);
  }
  // Prefix counts over the frame's rows of the points and of the cores.
  thread_local std::vector<int> all, over;
  all.assign(static_cast<size_t>(rows) + 1, 0);
  over.assign(static_cast<size_t>(rows) + 1, 0);
  bool any = false;
  for (size_t i = 0; i < n; ++i) {
    const bool core = reference[i] > 0 && terms[i].foot > kGlintFootRatio * reference[i];
    all[static_cast<size_t>(points[i].row) + 1] = 1;
    over[static_cast<size_t>(points[i].row) + 1] = core ? 1 : 0;
    any = any || core;
  }
  if (!any) return 0;
  for (int r = 0; r < rows; ++r) {
    all[static_cast<size_t>(r) + 1] += all[static_cast<size_t>(r)];
    over[static_cast<size_t>(r) + 1] += over[static_cast<size_t>(r)];
  }
  auto count = [&](const std::vector<int>& v, int row, int half) {
    const int lo = std::max(0, row - half), hi = std::min(rows - 1, row + half);
    return v[static_cast<size_t>(hi) + 1] - v[static_cast<size_t>(lo)];
  };
  thread_local std::vector<uint8_t> glint;
  glint.assign(n, 0);
  bool any_core = false;
  for (size_t i = 0; i < n; ++i) {
    const int row = points[i].row;
    if (over[static_cast<size_t>(row) + 1] == over[static_cast<size_t>(row)]) continue;  // not a core point
    if (count(over, row, kGlintHalfRows) < kGlintShare * (2 * kGlintHalfRows + 1)) continue;
    if (count(over, row, kGlintReachRows) > kGlintMaxShare * count(all, row, kGlintReachRows)) continue;
    glint[i] = 1;
    any_core = true;
  }
  if (!any_core) return 0;
  // The glint's skirt: the saturated points of the same stretch of line within kGlintSkirtRows of a core
  // point (above), where the lobe rises or falls and the share test has not yet or no longer holds.
  for (size_t i = 0; i < n; ++i) {
    if (glint[i] != 1) continue;
    for (size_t j = i; j-- > 0 && points[i].row - points[j].row <= kGlintSkirtRows;) {
      if (glint[j] != 0 || !(points[j].flags & kFlagSaturated)) continue;
      if (std::abs(points[j].column - points[i].column) > kGlintSkirtPxPerRow * (points[i].row - points[j].row)) break;
      glint[j] = 2;
    }
    for (size_t j = i + 1; j < n && points[j].row - points[i].row <= kGlintSkirtRows; ++j) {
      if (glint[j] != 0 || !(points[j].flags & kFlagSaturated)) continue;
      if (std::abs(points[j].column - points[i].column) > kGlintSkirtPxPerRow * (points[j].row - points[i].row)) break;
      glint[j] = 2;
    }
  }
  // The glint's extent (kGlintGrowRatio): down the rows from each flagged point, then up.
  auto grows = [&](size_t from, size_t to) {
    const int gap = std::abs(points[to].row - points[from].row);
    return glint[from] != 0 && glint[to] == 0 && gap <= 2 && reference[to] > 0 &&
           terms[to].foot > kGlintGrowRatio * reference[to] &&
           std::abs(points[to].column - points[from].column) <= kGlintSkirtPxPerRow * static_cast<float>(gap);
  };
  for (size_t i = 1; i < n; ++i)
    if (grows(i - 1, i)) glint[i] = 3;
  for (size_t i = n - 1; i-- > 0;)
    if (grows(i + 1, i)) glint[i] = 3;
  int flagged = 0;
  for (size_t i = 0; i < n; ++i) {
    if (glint[i] == 0) continue;
    LinePoint& p = points[i];
    p.flags |= kFlagGlint;
    p.quality *= static_cast<float>(kGlintQuality);
    p.uncertainty_px = static_cast<float>(std::hypot(p.uncertainty_px, kGlintUncertaintyPx));
    ++flagged;
  }
  return flagged;
}

}  // namespace detail
}  // namespace rotoscan::laser
