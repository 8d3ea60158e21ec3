// Step 5 of the row loop (design notes in extract.cc, "Uncertainty" and "Estimators"): a row's point from
// its chosen candidate; and the estimators themselves (EstimateCentre).
#include <algorithm>
#include <cmath>

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

bool MeasurePoint(const Candidate& c, const uint8_t* a, const uint8_t* b, const uint8_t* d, int cols, int row,
                  const ExtractOptions& o, uint8_t flags, LinePoint* point, PointTerms* terms, double* column_out) {
  double column;
  if (o.estimator == Estimator::kCenterOfMass) {  // EstimateCentre's, with the vector extent scans
    column = CenterOfMassOver(d, c.com_first, c.com_last, c.peak);
  } else {
    column = EstimateCentre(o.estimator, d, cols, c.first, c.last, c.peak);
  }
  if (column < 0) return false;
  if (a[c.peak_pos] == 255) {
    flags |= kFlagSaturated;
    // A notch: a saturated pixel of the line whose own difference is below half the line's best.
    const NotchScan scan = ScanNotch(a, b, c.first, c.last, cols);
    if (2 * scan.worst_saturated < scan.best_difference) flags |= kFlagNotched;
  }
  if (c.first == 0 || c.last == cols - 1) flags |= kFlagClipped;
  terms->column = column;
  terms->extent_middle = 0.5 * (c.first + c.last);
  terms->width_num = c.width_num;
  terms->width_den = c.width_den;
  terms->peak = c.peak;
  // Texture across the line (ScorePoints): the laser-off row either side of the centre's pixel.
  const int middle = static_cast<int>(column + 0.5);
  const SidesSum sides = SumsAround(b, c.com_first, middle, c.com_last, cols);
  terms->left = sides.left;
  terms->right = sides.right;
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
  float before = 0.0f;  // the previous point's column (the slope's, below)
  for (size_t i = 0; i < n; ++i) {
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
}

}  // namespace detail
}  // namespace rotoscan::laser
