// Steps 3-4 of the row loop (design notes in extract.cc): a row's candidates, and the one it keeps.
#include <algorithm>
#include <cmath>

#include "extract_steps.h"
#include "kernels.h"

namespace rotoscan::laser::detail {

int FindCandidates(const uint8_t* a, const uint8_t* b, uint8_t* d, int cols, int threshold, int off_saturation_dn,
                   bool centre_of_mass, const int* starts, const uint64_t* masks, int block_count,
                   Candidate* candidates, int capacity) {
  int count = 0;
  auto add_run = [&](int run_first, int run_last) __attribute__((always_inline)) {
    if (count >= capacity) return;
    Candidate& c = candidates[count];
    // Saturated laser-on pixels over an off pixel with headroom were set to 255 by step 1 (a notch cannot
    // split the line); their difference is clipped, so they all take the run's highest true difference
    // among them, the plateau a saturated line has (DESIGN.md), and the candidate is measured on that.
    // (Only those pixels can hold 255, so this is the same as filling where the run's peak is 255.)
    const PeakInRun found = FillPlateau(a, b, d, run_first, run_last, cols, threshold);
    c.peak_pos = found.position;
    c.peak = found.value;
    // The half-maximum extent: d >= peak / 2, i.e. d >= ceil(peak / 2) for integers.
    const int lo = c.peak_pos - ExtentLeft(d, c.peak_pos - 1, (c.peak + 1) / 2);
    const int hi = c.peak_pos + ExtentRight(d, c.peak_pos + 1, (c.peak + 1) / 2);
    c.first = lo;
    c.last = hi;
    if (centre_of_mass) {
      // The centre of mass's run (d > 0.15 peak, i.e. d >= 3 peak / 20 + 1 in integers) around the peak:
      // it holds the half-maximum extent, and scanning it from the peak rather than from the extent's
      // ends lets it run beside the width's steps instead of after the decision.
      const int level_min = kComLevelNum * c.peak / kComScale + 1;
      c.com_first = c.peak_pos - ExtentLeft(d, c.peak_pos - 1, level_min);
      c.com_last = c.peak_pos + ExtentRight(d, c.peak_pos + 1, level_min);
    }
    // The width at half maximum: between the crossings of peak / 2, each interpolated linearly between
    // the extent's end pixel and the next one out (at the image's border half a pixel out), i.e.
    // (hi + 1 - n_r / d_r) - (lo - 1 + n_l / d_l) with n = peak / 2 - d(next out) and d = d(end) -
    // d(next out), in integers as (hi - lo + 2) - (2 n_l d_r + 2 n_r d_l) / (2 d_l d_r). The extent ends
    // where d drops below ceil(peak / 2) >= peak / 2, so both d are positive.
    int nl2 = 2, dl = 2, nr2 = 2, dr = 2;  // n doubled
    if (lo > 0) {
      nl2 = c.peak - 2 * d[lo - 1];
      dl = d[lo] - d[lo - 1];
    }
    if (hi < cols - 1) {
      nr2 = c.peak - 2 * d[hi + 1];
      dr = d[hi] - d[hi + 1];
    }
    c.width_den = 2 * dl * dr;
    c.width_num = (hi - lo + 2) * c.width_den - (nl2 * dr + nr2 * dl);
    c.off_saturated = b[c.peak_pos] >= off_saturation_dn;
    // A run inside, or within kMergeGapPx of, the half-maximum extent of the previous candidate is the
    // same line (a noise dip, a dark speckle grain): one candidate over both extents; unless the weaker of
    // the two peaks under half the stronger one beside it (not inside it): that is no part of the
    // stronger's half-maximum extent but another light beside the line (laser light scattered into a
    // concavity, concave-webcam.json: once the threshold followed the noise, its glow joined the line and
    // the union was too wide, RenderedLineTest.WebcamConcaveCornerKeepsThePrimaryLine), a candidate of
    // its own.
    const bool beside = count > 0 && !(candidates[count - 1].last >= lo && hi <= candidates[count - 1].last) &&
                        2 * std::min(c.peak, candidates[count - 1].peak) < std::max(c.peak, candidates[count - 1].peak);
    if (count > 0 && !beside && candidates[count - 1].last + kMergeGapPx >= lo) {
      Candidate& prev = candidates[count - 1];
      if (prev.last >= lo && hi <= prev.last) {  // wholly inside: the higher peak's candidate
        if (c.peak > prev.peak) prev = c;
        return;
      }
      const Candidate higher = c.peak > prev.peak ? c : prev;
      const int first = std::min(prev.first, lo), last = std::max(prev.last, hi);
      const int com_first = std::min(prev.com_first, c.com_first), com_last = std::max(prev.com_last, c.com_last);
      prev = higher;
      prev.first = first;
      prev.last = last;
      prev.com_first = com_first;
      prev.com_last = com_last;
      prev.width_num = last - first + 1;
      prev.width_den = 1;
      return;
    }
    ++count;
  };
  int run_start = -1, run_last = -2;
  for (int k = 0; k < block_count; ++k) {
    const int base = starts[k];
    uint64_t mask = masks[k];
    while (mask != 0) {  // one turn per run of set bits, not per bit
      const int from = __builtin_ctzll(mask);
      const uint64_t rest = ~(mask >> from);
      const int length = rest != 0 ? __builtin_ctzll(rest) : 64 - from;
      mask = length + from >= 64 ? 0 : mask & (~uint64_t{0} << (from + length));
      const int j = base + from;
      if (j != run_last + 1) {
        if (run_start >= 0) add_run(run_start, run_last);
        run_start = j;
      }
      run_last = j + length - 1;
    }
  }
  add_run(run_start, run_last);
  return count;
}

int ChooseCandidate(const Candidate* candidates, int count, const ExtractOptions& o, double previous_column,
                    bool continuous, LineStats* stats, uint8_t* flags_out) {
  int best = -1, strongest = 0;
  bool any_off_saturated = false;
  for (int k = 0; k < count; ++k) {
    const Candidate& c = candidates[k];
    if (c.peak > candidates[strongest].peak) strongest = k;
    if (c.off_saturated) {
      any_off_saturated = true;
      continue;
    }
    if (!c.WidthWithin(o.min_width_px, o.max_width_px)) continue;
    if (best < 0 || c.peak > candidates[best].peak) best = k;
  }
  if (best < 0) {
    if (any_off_saturated) {
      ++stats->off_saturated;
    } else {
      ++stats->bad_width;
    }
    return -1;
  }
  uint8_t flags = 0;
  {
    // A much stronger candidate (the best below multiple_peak_ratio of it) was rejected. Only one
    // reason lets the weaker one stand: the stronger is narrower than min_width (a hot pixel, a glint's
    // core), flagged. Wider than max_width or hidden under a saturated laser-off pixel, it may be the
    // laser itself: the row gets no point rather than a stray one (ExtractTest.NeverAWeakCandidate...).
    const Candidate& s = candidates[strongest];
    if (strongest != best && candidates[best].peak < o.multiple_peak_ratio * s.peak) {
      if (!s.off_saturated && s.width_num < o.min_width_px * s.width_den) {
        flags |= kFlagStrongerRejected;
      } else {
        ++stats->stronger_rejected;
        return -1;
      }
    }
  }
  for (int k = 0; k < count; ++k) {
    const Candidate& c = candidates[k];
    if (k == best || c.off_saturated || !c.WidthWithin(o.min_width_px, o.max_width_px)) continue;
    if (c.peak >= o.multiple_peak_ratio * candidates[best].peak) {
      flags |= kFlagMultiplePeaks;
      const Candidate& cb = candidates[best];
      if (continuous && std::abs(0.5 * (c.first + c.last) - previous_column) <
                            std::abs(0.5 * (cb.first + cb.last) - previous_column)) {
        best = k;
      }
    }
  }
  *flags_out = flags;
  return best;
}

}  // namespace rotoscan::laser::detail
