// FillLineGaps (extract_steps.h): rows missing inside a stretch of line, looked for along the stretch's
// curve with a threshold on the summed difference instead of one row's peak.
//
// Why (issue 15, TableRowsTest.MissedRowsBySignal): on the webcam sets the table top's line peaks at
// ~13 DN over a noise of 1.4-1.8 DN, and its rows that the row pass misses (12 % / 32 % of the table's
// rows, glossy / textured, 8 steps) nearly all lie in gaps between found rows of the same line, and all
// but 2 of 1,012 carry at least 4 sigma in the noise-free render (85 % at least 6 sigma): fully developed
// speckle takes a grain out of the line's peak (the missed rows' noisy peak is 0.75 of the clean one, median)
// and the row falls under the 6 sigma threshold. One row's peak cannot be trusted lower (DetectionFloorTest:
// 4 sigma gives 25 false rows in 5,760 on laser-off pairs), but the line's pixels over several rows can:
// speckle grains average out along the line, and noise falls as the square root of the pixels summed.
//
// The step: for two found points at most kGapMaxRows apart whose columns join (kSteepMaxStepPx per row),
// the points within kGapFitRows rows of the gap on either side (at least kGapMinSide each, each step
// joined) give a parabola, column against row (least squares, as steep.cc), which must fit them as a line
// (steep.cc's residual test, looser: kGapMaxResidual, as these points are the rows' own centres of a weak
// steep line, before steep.cc). For each missing row, around the curve's point there: a matched filter
// across the curve, the signed difference summed over the pixels within kGapAlongPx along the curve and
// within the line's half width across it (a box), against the mean of the same boxes shifted by
// kGapSideShift half widths to either side (a level change or a broad glow sums to zero). The row is filled
// when that contrast is at least min_z (kGapMinZ, 6) times its noise, the frame's sigma (noise_dn) over the
// square root of the boxes' pixel counts times kGapCorrelation, and each half of the window along the
// line (before and after the row's point) and the row's own pixels reach kGapHalfZ on their own: the line
// goes on through the row and does not end at it (a shadow's edge), and the row itself holds its light
// (ExtractTest.RowsWithoutLaserGiveNoPoints: a line on every other row only). Its centre: the centre of mass
// across the curve of the difference above one sigma within the line's width (two iterations, as steep.cc),
// combined with the curve's own (offset 0) by their inverse variances.
//
// The threshold, as the row pass's 6 sigma (DetectionFloorTest): GapFillTest.NoRowsFilledOnLaserOffPairs
// offers the gaps of real stretches (rows 3 and 4 of every 7 punched out) to a pair of laser-off frames of
// the same step (no laser: every filled row is false). On the three webcam scenes, 2 steps, 1,531 rows
// offered: min_z 3 / 4 / 5 / 6 filled 12 / 12 / 9 / 0 before the row's own test (below), 0 / 0 / 0 / 0
// with it; on synthetic white-noise pairs none at any of these. kGapCorrelation 3 stands for the
// correlation of neighbouring pixels of a demosaiced MJPEG frame (a plain 8 x 4 box's sum varies 11 times
// N sigma^2 on those pairs, with their rolling-shutter and ambient level changes, which the side boxes
// take out); 6 keeps the margin the row pass has.
// Chosen on the webcam sets (8 steps, the first frames' seeds of TableRowsTest; table rows found, glossy /
// textured, f/4): the residual test at 0.35 (steep.cc's) 96.5 / 86.4 % found, at 0.8 97.3 / 90.8 %; at
// least 2 points a side instead of 3, 97.9 / 93.2 %; gaps up to 33 rows instead of 17: textured 94.3 %
// found but 79 rows over 1 px across instead of 59. The centre: from the curve alone, textured 97 rows over
// 1 px; from the centre of mass alone 61; combined 63 while the curve's variance was its residual over the
// points' count, and the filled rows' own error: 21 of 725 over 1 px at f/2.4 (both sets), RMS 0.38 px
// across; with the curve's variance one point's (its residual per degree of freedom, as now) 3 of 725,
// RMS 0.31 px.
// A side with fewer than kGapMinSide points within kGapFitRows rows takes its nearest points up to
// kGapFarFitRows (32) away (twelfth session). Why (ObjectRowsTest.TexturedMissedRowsByPlace, textured set,
// all lit rows, 8 steps x 2 lasers): the rows the gap step left inside gaps (86 at f/4, 117 at f/2.4, ~all
// on the dark table top's weak line, 4-6 sigma in the noise-free render: not the object's checker cells,
// whose missed rows all lie past a stretch's end) were 62 / 72 in gaps skipped for want of a second point
// on one side, where the row pass finds the weak line's rows sparsely. Now 47 / 65 rows left in gaps;
// `bench accuracy` (8 steps, all lit rows, across): textured f/4 found 95.94 -> 96.14 % (table 95.27 ->
// 96.05 %), over 1 px unchanged 1.437 %; f/2.4 95.20 -> 95.61 %, 1.724 -> 1.748 % (+2 rows); glossy f/4
// 97.89 -> 97.97 %, 1.796 -> 1.780 %; f/2.4 98.84 -> 98.87 %, 1.254 -> 1.270 % (+1 row). Synthetic
// (GapFillTest.GapsWithASinglePointOnOneSideFilled): 178 -> 556 of 1,017 rows filled, none on laser-off
// pairs. Cost: typical frames (laser_bench BM_ExtractWebcam/1) +0-3 % (more gaps reach the matched filter).
// A stretch that fails the residual test is fitted again over its nearest kGapNearPoints (3) points a side
// (twelfth session): at f/2.4, 45 of the 65 rows left in gaps (8 steps) were in gaps whose stretch failed it
// (the far points above, or a line that bends within 12 rows). Rows left in gaps 47 / 65 -> 46 / 45 (f/4 /
// f/2.4); `bench accuracy` with both changes, main a85a763 -> now: textured f/4 found 95.94 -> 96.38 %
// (table 95.27 -> 96.97 %), over 1 px across 1.437 -> 1.425 %, RMS 0.274 -> 0.273 px; f/2.4 95.20 -> 96.47 %
// (table 92.00 -> 96.88 %), 1.724 -> 1.688 %, 0.249 -> 0.248 px; glossy f/4 97.89 -> 98.14 %, 1.796 ->
// 1.780 %; f/2.4 98.84 -> 98.87 %, 1.254 -> 1.270 % (+1 row). Typical frames 355-359 -> 366-376 us (+3-5 %,
// BM_ExtractWebcam/1, main's library and this one alternating, load 3-4).
//
// A filled point's uncertainty (about two standard errors along the row): the combined centre's standard
// error across, times the line's length factor L = sqrt(1 + s^2), at least kGapMinUncertaintyPx. The
// centre of mass's variance: sigma^2 times the weights' spread over their sum squared, times
// kGapPixelVariance (the measured 11: with kGapCorrelation's 3 the filled rows' error along their row was
// beyond the uncertainty in 23 % of them, with 11 in 5-7 %: 48 of 725 at f/2.4, 43 of 805 at f/4, as two
// standard errors should). Its quality kGapQuality / (1 + u^2): a weaker signal than a found row's. Its
// peak is the matched filter's contrast (DN per pixel), its width the stretch's.
//
// Runs only on frames whose noise was measured on lit pixels (extract.cc), as steep.cc: on the
// machine-vision preset's clean frames the row pass finds what there is.
//
// Then the stretches' ends are looked past (ExtendLineEnds, below: a faint straight continuation summed over
// its run of rows), by the extractor after the smoothing (extract.cc).
#include <algorithm>
#include <cmath>
#include <iterator>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "extract_steps.h"
#include "kernels.h"

namespace rotoscan::laser::detail {
namespace {

// A gap of at most kGapMaxRows - 1 missing rows between two found points.
constexpr int kGapMaxRows = 17;
constexpr double kGapMaxResidual = 0.8;
constexpr int kGapFitRows = 12;
constexpr int kGapMinSide = 2;
// A side with fewer than kGapMinSide points within kGapFitRows rows of the gap takes its nearest points up
// to kGapFarFitRows away (twelfth session, below).
constexpr int kGapFarFitRows = 32;
// A stretch that fails the residual test is fitted again over its nearest kGapNearPoints points a side.
constexpr size_t kGapNearPoints = 3;
constexpr double kGapAlongPx = 4.0;
// The slope (columns per row) from which a window's row is visited only where it lies within kGapAlongPx
// along the line.
constexpr double kGapBandMinSlope = 0.05;
// For the centre of mass's variance: a box's sum varies kGapPixelVariance times N sigma^2 on the webcam
// scenes' laser-off pairs (GapFillTest prints it: 11.3).
constexpr double kGapPixelVariance = 11.0;
constexpr double kGapMinUncertaintyPx = 0.5;
constexpr double kGapQuality = 0.5;

// A coordinate as an index in [0, size - 1], whatever its size (a curve extrapolated far, a non-finite
// value: no conversion of an out-of-range double to int).
inline int ClampToIndex(double x, int size) {
  if (!(x > 0)) return 0;
  if (!(x < size - 1)) return size - 1;
  return static_cast<int>(x);
}

// std::floor and std::ceil, but for the sign of a zero (which ClampToIndex and the additions below ignore),
// without the library call (the baseline instruction set has no rounding instruction; FillLineGaps rounds
// ~6 bounds per window row: fourteenth session).
inline double FloorOf(double x) {
  if (!(std::abs(x) < 2e9)) return std::floor(x);
  const double t = static_cast<double>(static_cast<int64_t>(x));  // x truncated, exactly
  return t > x ? t - 1.0 : t;
}
inline double CeilOf(double x) {
  if (!(std::abs(x) < 2e9)) return std::ceil(x);
  const double t = static_cast<double>(static_cast<int64_t>(x));
  return t < x ? t + 1.0 : t;
}

// A pixel of a row's window within kGapAlongPx along the line that counts in the centre of mass: its across
// and its weight there (its difference less one sigma; only those with a positive weight are kept).
using NearPixel = GapPixel;  // kernels.h
// FillLineGaps tests a quotient against an edge without the division (fourteenth session): a numerator
// further than kTestMargin (relative) from the edge times the divisor gives a quotient on the same side of
// the edge once rounded (the roundings of the quotient and of the edge are ~1e-16 relative); nearer, it is
// divided. Below kNormalMin a quotient's sign might be lost to underflow: divided too.
constexpr double kTestMargin = 1e-9;
constexpr double kNormalMin = 1e-290;

struct Curve {
  double c0 = 0, s = 0, k = 0;  // column = c0 + s dr + k dr^2 about row r0
  int r0 = 0;
  double ColumnAt(int row) const {
    const double dr = row - r0;
    return c0 + s * dr + k * dr * dr;
  }
};

// ExtendLineEnds (extract_steps.h; the extractor runs it after the smoothing): a stretch's faint continuation
// past its end, along a straight line from the end.
//
// Why (issue 15, ObjectRowsTest.TexturedFaintRowsSignal and FaintStretchFoundPastItsEnd): the textured
// object's rows that no step found (224 at 8 steps, f/4) are a nearly horizontal stretch (~9 px per row, the
// laser across the object's flat top at a grazing angle), ~4 DN in the noise-free render against a
// threshold of 11.4 DN, summed over the row's segment ~4 noise units. They lie past the end of the object's
// found line (163 of 170 missed rows at 3 steps, both f-numbers: points within 16 rows on one side only),
// not in a gap between two points, so FillLineGaps never looked at them; and a row there holds ~9 px of
// line, so its +-kGapAlongPx window would not have reached 6 sigma either: the signal is there only summed
// over the run of rows. The line turns sharply at the end (a vertical line on the side, a horizontal one on
// the top), so the stretch's own curve does not predict it; the top is flat, so it is straight.
//
// The step, at each end of a stretch (kEndMinPoints joined points within kEndStretchRows rows in from it,
// kEndMinRows free rows past it at least): the anchor is the outermost point with kEndAnchorPeak of the
// stretch's median peak (the weak points past the corner lie on the stretch's glow, not on the turn), with
// its neighbours in the stretch (kEndAnchors). Through each anchor, lines at every slope from kEndMinSlope
// to kEndMaxSlope columns per row either way (the angle stepped so that the line moves kEndAngleStep of the
// half width across at the run's far end): gaps.cc's matched filter (the box of the half width across on
// the line, against the boxes kGapSideShift half widths to either side, kGapCorrelation) summed over the
// rows from the anchor out, pixels within 2 half widths + 1 px along of the anchor left out (the
// stretch's own light), each box a column interval per row from integer prefix sums. The best line over
// anchors, slopes and lengths (kEndMinRows to kEndMaxRows rows past the end) is kept where its z reaches
// min_z (kEndMinZ, 8: more lines are tried than the gap step tries) and each half of its rows past the end
// reaches kGapHalfZ. Its rows past the end get the line's column.
//
// False rows (GapFillTest.NoEndRunsOnLaserOffPairs: the ends of real stretches given with laser-off pairs
// of the three webcam scenes, 8 steps x 2 lasers, 109 ends): filled at z 4 / 5 / 6 / 7 / 8: 16 / 0 / 0 /
// 0 / 0 rows.
// Tried: one anchor instead of three: 91 of the 224 rows left (8 steps) against 62, ~30 against ~50 us a
// typical frame; the line refined afterwards by the highest contrast over offsets and slopes within a step,
// or by a straight-line fit of the centre of mass across: RMS 0.71 -> 1.54 and 0.98 px across (the
// texture under the faint line pulls it).
// A filled row's error (FaintStretchFoundPastItsEnd, f/4 and f/2.4): as placed here, 0.49 px RMS across
// at 3 steps, 1.06 at 8 (each capped at 3 px); the steep step and the smoothing, which run after, move each
// within its uncertainty: 0.72 / 0.86 px, 18 of 98 / 63 of 313 over 1 px, and 9 / 12 rows end more than
// 3 px across. kEndAcrossSd, the standard error across the uncertainty takes (2 L kEndAcrossSd along the
// row), by the rows within their uncertainty after those steps (3 steps): 0.5: 80 of 102; 0.65: 92 of 101;
// 0.8: 95 of 98 (8 steps: 278 of 314); 1.0 (chosen): 98 of 98 (8 steps: 290 of 313).
// Their quality (kGapQuality / (1 + u^2), u ~ 2 L ~ 18 px) is the lowest of any point's: a filter on
// quality drops them first.
// Twelfth session: the line refined, and each row's own evidence. The best line of the search is on a grid
// (its angle step moves the far end by half a half width) and its box filter is flat across the line: as
// placed, 83 of the 317 filled rows within 3 px were over 1 px across (FaintStretchFoundPastItsEnd, 8 steps,
// both f-numbers). Now the angles within one step (kEndRefineSteps a step) and offsets within a half width
// are scored by a Gaussian matched filter across (its sigma from the half width as a half maximum; zero-mean
// over +-3 sigma), on the pixels of the rows to fill binned by their distance across (kEndBinPx), and a row
// is placed only where its own pixels reach kEndRowZ (2) under the same filter (2.5: f/4 fewer rows over
// 1 px but ~20 fewer found; 1.5: the reverse). As placed: 26 of 266 over 1 px, RMS 0.62 px. Wider angle
// ranges (3 or 6 steps) were worse (the steeper lines take the stretch's own glow at the corner). After the
// steep step and the smoothing, which move a point by up to its uncertainty or 0.3 of its row width (here
// ~50 px: 2 half widths along a line at ~9 px per row), 47 of 262 are over 1 px (64 of 313 before): those
// later steps, not the end step's placing, now make most of its rows over 1 px (run after them, in a trial
// of extract.cc's order not kept: textured f/4 over 1 px with the end step 1.58 -> 1.68 % in the test's
// count, against 1.92 %). `bench accuracy --extend-line-ends` (8 steps, all lit rows, across), main a85a763
// -> now: textured f/4 found 97.35 -> 97.29 %, over 1 px 1.808 -> 1.676 %; f/2.4 97.03 -> 97.10 %, 2.167 ->
// 2.047 %; the default's 1.437 / 1.748 % (with the gap step's refit over the nearest points, above:
// 97.53 %, 1.664 % and 97.96 %, 1.988 %; the default's 1.425 / 1.688 %). Cost, laser_bench BM_ExtractWebcam/5
// (the end step on) against /1: ~+55 us on main, ~+75 us now (the refinement ~20 us of a frame, load 4-7:
// noisy). False rows on laser-off pairs (GapFillTest.NoEndRunsOnLaserOffPairs) at z 4 / 5 / 6 / 7 / 8: 2 / 0
// / 0 / 0 / 0 (were 16 / 0 / 0 / 0 / 0).
// Thirteenth session: the extractor runs this step after the smoothing (extract.cc), no longer inside
// FillLineGaps before the steep step: its lines pass through the stretch's smoothed points, and its rows stay
// where it places them (the steep step and the smoothing had moved them within their uncertainty, i.e. by up
// to ~2 px across: the 47 of 262 over 1 px above against 26 as placed). And a run goes on up to kEndMaxRows 24
// rows past the end (was 16): the object's flat top, where most of these rows lie, runs ~20 rows past the
// side's end (rows ~320-340 of the textured set), and at 16 its far rows were left. `bench accuracy
// --extend-line-ends` (8 steps, all lit rows, across), main 812a748 -> after the smoothing -> and 24 rows:
// textured f/4 found 97.53 -> 97.75 -> 98.23 %, over 1 px 1.664 -> 1.533 -> 1.568 % (the default's 96.38 %,
// 1.425 %); f/2.4 97.96 -> 97.95 -> 98.25 %, 1.964 -> 1.820 -> 1.808 % (default 96.47 %, 1.664 %); 20 rows:
// 98.01 %, 1.557 % / 98.04 %, 1.760 %; 32 rows: 98.42 %, 1.652 % / 98.25 %, 1.868 %. Glossy f/4 98.17 %,
// 1.672 % (default 98.14 %, 1.657 %), f/2.4 as the default (98.87 %, 1.270 %). FaintStretchFoundPastItsEnd (3
// steps): 131 filled, RMS 0.53 px across, 10 over 1 px (was 93, 0.77 px, 16). Tried, not kept (same bench):
// the two halves of a run each placed by the Gaussian filter and the line drawn through them, f/4 / f/2.4
// over 1 px 1.700 / 2.143 % (their offsets are noisier than the slope's error); a run rejected where the
// halves disagree by over 1 px (0.6 px), found 97.82 / 97.05 % (97.15 / 96.73 %); the refinement over 2 or 3
// grid steps of angle, 1.700 / 1.856 % and 1.736 / 1.964 %; finer angle steps (4 or 8 a step), no change;
// the stretch's light left out to 3 or 4 half widths along (d0), 97.93 % / 1.545 %, 98.05 % / 1.736 % and
// 97.63 / 97.92 % found; a row's own z 2.5 (1.5), 98.02 / 98.04 % found, 1.509 / 1.772 % (98.38 / 98.50 %,
// 1.604 / 1.844 %); the anchor at 0.3 (0.8) of the median peak, 97.98 / 98.10 %, 1.473 / 1.820 % (98.56 /
// 98.44 %, 1.820 / 2.047 %); a row placed only where its own Gaussian filter peaks within 1 / 1.5 / 2 px
// across of the line, f/4 97.71 / 97.89 / 98.08 % found, 1.509 / 1.509 / 1.545 %, f/2.4 97.75 / 97.98 / 98.16 %,
// 1.748 / 1.784 / 1.796 % (it drops good rows about as often as bad ones). The rows over 1 px that are left
// are runs whose slope is off by 1-3 px per row (most through an anchor of 30-80 DN, against 110-190 for the
// good runs, at the object's top corner).
//
// Tails (rfcap, fourteenth session; since the fifteenth only for the rim step's ends at its steep slope
// bound, ExtractOptions::rim_rows_at_bound: ExtendLineEnds with fill false, tails true and only_ends, after
// RecentreRimRows; extract_steps.h has its figures). The textured object's cylinder top rim: the side line's
// vertical blur carries it 2-4 rows past its true end (peaks 22 / 48 / 93 / 148 DN against ~200 below),
// where the truth is the cap's ~4 DN line at ~9 px per row. An end's tail (its points past the anchor, under
// kEndAnchorPeak of the stretch's median peak) is put on the line that the search above finds going on from
// the anchor (their uncertainty at least the move: the row may hold either line's light). Only where (1) the
// tail is the blur's, not a dim line going on: no point more than kTailRows rows past the anchor at
// kTailNoiseZ noise or above (12 sigma, twice the detection threshold: noise picks and the blur's last light
// are under it; the right laser's dim top on the textured cylinder, 30-40 DN for 6 rows, is not); (2) the
// line leaves the end by at least a half width (end.half) a row, so that the tail rows' own profiles are not
// the continuing line's too (the object's foot, where the table's line goes on at +-2.2 px per row: its tails
// moved there were worse in 3 of 4 rows); (3) its z reaches kTailMinZ (12: the lines under it were the
// glossy object's slow fades, z 9.8 and 11.5, whose 4 moved rows were none better and 2 worse, and the
// textured right laser's dim tops, slopes 7.2-7.5 against a true 9.3). Tails alone search one anchor (the
// end step's three cost ~110-150 us a typical frame against ~40-80 with one, on every end; here only the
// rim step's ends at the bound: 3 in the textured f/2.4 bench's 16 frames) and slopes from the half width up
// (test 2). Strays (kTailStrays): 1-2 noise picks past the end, not joined to it, do not stop it. rfcap
// measured it as a step of its own on every end (main f01a26c, before the rim step; bench accuracy 8 steps,
// across): textured f/4 0.862 -> 0.694 %, f/2.4 1.114 -> 0.682 %, glossy identical; on every end after the
// rim step (its trial merge): textured f/4 0.635 -> 0.647 %, f/2.4 0.754 -> 0.587 %, +40-60 us a frame.
constexpr int kEndMaxRows = 24;
constexpr int kEndMinRows = 4;
constexpr int kEndStretchRows = 16;
constexpr int kEndMinPoints = 6;
constexpr double kEndAnchorPeak = 0.5;
constexpr double kEndMinSlope = 2.0;
constexpr double kEndMaxSlope = 12.0;
constexpr double kEndAngleStep = 0.5;
constexpr int kEndAnchors = 3;
constexpr double kEndAcrossSd = 1.0;
constexpr int kEndRefineSteps = 2;
constexpr double kEndBinPx = 0.2;
constexpr double kEndRowZ = 2.0;
// Tails (above): a point more than kTailRows rows past the anchor at kTailNoiseZ noise or more is a line
// going on; the line's z at least kTailMinZ.
constexpr int kTailRows = 3;
// Tails alone: at most kTailStrays points under kTailNoiseZ noise within kTailStrayRows rows past an end are
// strays (noise picks on the faint line past the corner: 1-2 of 12-15 DN): the rows past the end go through
// them and they are placed with the tail.
constexpr int kTailStrays = 2;
constexpr int kTailStrayRows = 6;
constexpr double kTailNoiseZ = 12.0;
constexpr double kTailMinZ = 12.0;
// A Gaussian's full width at half maximum over its sigma: the matched filter's sigma from the line's width.
constexpr double kFwhmPerSigma = 2.3548;

// The signed difference's prefix sums over a block of rows, each row over its own columns (integers).
struct RowPrefix {
  int first_row = 0;
  std::vector<int> first_col, cols;
  std::vector<size_t> offset;
  std::vector<long> sums;  // per row: cols + 1
  // The sum over columns [c0, c1] of row rr (clipped to the row's columns), and the pixel count.
  long Sum(int rr, int c0, int c1, int* count) const {
    const size_t i = static_cast<size_t>(rr - first_row);
    c0 = std::max(c0, first_col[i]);
    c1 = std::min(c1, first_col[i] + cols[i] - 1);
    if (c1 < c0) {
      *count = 0;
      return 0;
    }
    const long* row = sums.data() + offset[i];
    *count = c1 - c0 + 1;
    return row[c1 - first_col[i] + 1] - row[c0 - first_col[i]];
  }
};

// A stretch's end: the point e with no point joined to it on the side dir (-1: the rows above, +1: below),
// at least kEndMinPoints joined points within kEndStretchRows rows in from it, and at least kEndMinRows
// free rows past it (before the next point or the image's edge).
struct End {
  int last = 0;    // the innermost point looked at
  int anchor = 0;  // the outermost point with kEndAnchorPeak of the stretch's median peak
  int end_row = 0, limit_row = 0;
  double half = 0;  // the line's half width across (the matched filter's)
  int strays = 0;   // stray points past the end that the rows past it go through
};

bool Joined(const std::vector<LinePoint>& p, int a, int b) {
  const int gap = p[static_cast<size_t>(b)].row - p[static_cast<size_t>(a)].row;
  return gap >= 1 && gap <= kGapMaxRows &&
         std::abs(p[static_cast<size_t>(b)].column - p[static_cast<size_t>(a)].column) <= kSteepMaxStepPx * gap;
}

bool EndAt(const std::vector<LinePoint>& p, int e, int dir, int rows, std::vector<float>* peaks,
           std::vector<float>* widths, End* out, double stray_peak = 0) {
  const int n = static_cast<int>(p.size());
  if (dir < 0 ? (e > 0 && Joined(p, e - 1, e)) : (e + 1 < n && Joined(p, e, e + 1))) return false;
  peaks->clear();
  widths->clear();
  int last = e;
  for (int k = e;;) {
    peaks->push_back(p[static_cast<size_t>(k)].peak);
    widths->push_back(p[static_cast<size_t>(k)].width);
    last = k;
    const int next = k - dir;
    if (next < 0 || next >= n ||
        std::abs(p[static_cast<size_t>(next)].row - p[static_cast<size_t>(e)].row) > kEndStretchRows)
      break;
    if (dir < 0 ? !Joined(p, k, next) : !Joined(p, next, k)) break;
    k = next;
  }
  if (static_cast<int>(peaks->size()) < kEndMinPoints) return false;
  // The rows past the end that may be filled: up to the next point or kEndMaxRows.
  const int end_row = p[static_cast<size_t>(e)].row;
  int limit_row = end_row + dir * kEndMaxRows;
  // Stray points past the end (tails: at most kTailStrays, under stray_peak, within kTailStrayRows of it) do
  // not stop the rows past it.
  int next = e + dir, strays = 0;
  while (next >= 0 && next < n && strays < kTailStrays && p[static_cast<size_t>(next)].peak < stray_peak &&
         std::abs(p[static_cast<size_t>(next)].row - p[static_cast<size_t>(e)].row) <= kTailStrayRows)
    next += dir, ++strays;
  if (dir < 0 && next >= 0) limit_row = std::max(limit_row, p[static_cast<size_t>(next)].row + 1);
  if (dir > 0 && next < n) limit_row = std::min(limit_row, p[static_cast<size_t>(next)].row - 1);
  out->strays = strays;
  limit_row = std::clamp(limit_row, 0, rows - 1);
  if (dir * (limit_row - end_row) < kEndMinRows) return false;
  std::vector<float>& sorted = *peaks;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<long>(sorted.size() / 2), sorted.end());
  const double median_peak = sorted[sorted.size() / 2];
  int anchor = e;
  while (anchor != last && p[static_cast<size_t>(anchor)].peak < kEndAnchorPeak * median_peak) anchor -= dir;
  // The line's half width across: the stretch's median width along its rows (wider than across on a
  // steep stretch: at least the line's).
  std::nth_element(widths->begin(), widths->begin() + static_cast<long>(widths->size() / 2), widths->end());
  out->last = last;
  out->anchor = anchor;
  out->end_row = end_row;
  out->limit_row = limit_row;
  out->half = std::max(1.5, 0.5 * (*widths)[widths->size() / 2]);
  return true;
}

}  // namespace

int CountLineEnds(const std::vector<LinePoint>& points, int rows) {
  std::vector<float> peaks, widths;
  End end;
  int count = 0;
  for (int e = 0; e < static_cast<int>(points.size()); ++e)
    for (int dir : {-1, 1}) count += EndAt(points, e, dir, rows, &peaks, &widths, &end);
  return count;
}

int ExtendLineEnds(const cv::Mat& on, const cv::Mat& off, int channel, double noise_dn,
                   std::vector<LinePoint>* line_points, double min_z, bool fill, bool tails,
                   const std::vector<std::pair<int, int>>* only_ends) {
  std::vector<LinePoint>& p = *line_points;
  const int n = static_cast<int>(p.size());
  if (n < kEndMinPoints || noise_dn <= 0) return 0;
  std::vector<std::pair<int, float>> tail_moves;
  const int rows = on.rows, cols = on.cols, step = on.channels();
  std::vector<LinePoint> filled;
  RowPrefix prefix;
  std::vector<float> peaks, widths;
  std::vector<double> gauss;
  std::vector<long> bin_sum;
  std::vector<int> bin_count;
  End end;
  for (int e = 0; e < n; ++e) {
    for (int dir : {-1, 1}) {
      // Tails alone: up to kTailStrays stray points past the end (noise picks over the faint line) do not
      // stop it. Only the ends asked for (the rim step's, ends.cc): an end at most kTailStrayRows rows past
      // one (its strays).
      if (only_ends != nullptr &&
          std::none_of(only_ends->begin(), only_ends->end(), [&](const std::pair<int, int>& o) {
            return o.second == dir && (e - o.first) * dir >= 0 &&
                   std::abs(p[static_cast<size_t>(e)].row - p[static_cast<size_t>(o.first)].row) <=
                       kTailStrayRows;
          }))
        continue;
      if (!EndAt(p, e, dir, rows, &peaks, &widths, &end, fill ? 0.0 : kTailNoiseZ * noise_dn)) continue;
      const int last = end.last, anchor = end.anchor, end_row = end.end_row, limit_row = end.limit_row;
      // A blur tail: points past an anchor of kTailNoiseZ noise or more (a bright line's blur; on a faint
      // line, the table's, the search is not made), those more than kTailRows rows past it all under
      // kTailNoiseZ noise.
      bool tail_ok = tails && anchor != e && p[static_cast<size_t>(anchor)].peak >= kTailNoiseZ * noise_dn;
      for (int k = anchor + dir; tail_ok && k != e + dir; k += dir)
        tail_ok = !(dir * (p[static_cast<size_t>(k)].row - p[static_cast<size_t>(anchor)].row) > kTailRows &&
                    p[static_cast<size_t>(k)].peak >= kTailNoiseZ * noise_dn);
      if (!fill && !tail_ok) continue;
      const double half = end.half;
      const double d0 = 2.0 * half + 1.0;  // along from the anchor: the stretch's own light left out
      // Anchors: the chosen point and its neighbours in the stretch.
      int anchors[3] = {0, 0, 0};
      int anchor_count = 0;
      for (int a : {anchor, anchor - dir, anchor + dir}) {
        if (anchor_count == (fill ? kEndAnchors : 1)) break;
        if (a < 0 || a >= n) continue;
        const int ra = p[static_cast<size_t>(a)].row;
        if (dir * (ra - end_row) > 0 || std::abs(ra - end_row) > kEndStretchRows) continue;
        if (dir * (ra - p[static_cast<size_t>(last)].row) < 0) continue;
        anchors[anchor_count++] = a;
      }
      // The block of rows from the innermost anchor to limit_row, columns within reach.
      int inner_row = end_row;
      for (int i = 0; i < anchor_count; ++i)
        inner_row = dir < 0 ? std::max(inner_row, p[static_cast<size_t>(anchors[i])].row)
                            : std::min(inner_row, p[static_cast<size_t>(anchors[i])].row);
      const int row_lo = std::min(inner_row, limit_row), row_hi = std::max(inner_row, limit_row);

      // Each row's columns: those any hypothesis's boxes can reach.
      const double box_reach = 4.0 * half * std::sqrt(1.0 + kEndMaxSlope * kEndMaxSlope) + 1.0;
      prefix.first_row = row_lo;
      prefix.first_col.clear();
      prefix.cols.clear();
      prefix.offset.clear();
      size_t total = 0;
      for (int rr = row_lo; rr <= row_hi; ++rr) {
        double lo = cols, hi = -1;
        for (int i = 0; i < anchor_count; ++i) {
          const LinePoint& q = p[static_cast<size_t>(anchors[i])];
          const double reach = kEndMaxSlope * std::abs(rr - q.row) + box_reach;
          lo = std::min(lo, q.column - reach);
          hi = std::max(hi, q.column + reach);
        }
        const int c0 = ClampToIndex(std::floor(lo), cols), c1 = ClampToIndex(std::ceil(hi), cols);
        prefix.first_col.push_back(c0);
        prefix.cols.push_back(c1 - c0 + 1);
        prefix.offset.push_back(total);
        total += static_cast<size_t>(c1 - c0 + 2);
      }
      prefix.sums.resize(total);
      for (int rr = row_lo; rr <= row_hi; ++rr) {
        const size_t i = static_cast<size_t>(rr - row_lo);
        const uint8_t* a = on.ptr<uint8_t>(rr) + channel;
        const uint8_t* b = off.ptr<uint8_t>(rr) + channel;
        long* out = prefix.sums.data() + prefix.offset[i];
        long acc = 0;
        out[0] = 0;
        for (int c = 0; c < prefix.cols[i]; ++c) {
          const int col = prefix.first_col[i] + c;
          acc += SignedDifference(a[col * step], b[col * step]);
          out[c + 1] = acc;
        }
      }
      // The hypotheses: lines through an anchor at slopes kEndMinSlope..kEndMaxSlope either way, the angle
      // stepped so that the line moves at most a quarter of the half width across over the rows summed.
      const int span = row_hi - row_lo + 1;
      struct Best {
        double z = 0;
        int anchor = -1, rows = 0;
        double slope = 0, contrast = 0;
      } best;
      auto z_of = [&](double s0, double s1, double s2, long n0, long n1, long n2) {
        if (n0 < 2 || n1 < 2 || n2 < 2) return 0.0;
        const double contrast = s0 / n0 - 0.5 * (s1 / n1 + s2 / n2);
        return contrast / (noise_dn * std::sqrt(kGapCorrelation * (1.0 / n0 + 0.25 / n1 + 0.25 / n2)));
      };
      // Sums of the three boxes over the rows j = 1..; visit(j, z) after each row.
      // The line through (row of point a, column ca) at slope s.
      auto run = [&](int a, double ca, double s, int max_rows, auto&& visit) {
        const int ra = p[static_cast<size_t>(a)].row;
        const double length = std::sqrt(1.0 + s * s);
        const double hl = half * length;
        double sum[3] = {0, 0, 0};
        long count[3] = {0, 0, 0};
        for (int j = 1; j <= max_rows; ++j) {
          const int rr = ra + dir * j;
          const double cl = ca + s * (rr - ra);
          // Columns whose along from the anchor (outwards) is at least d0: dir ((c - ca) s + (rr - ra)) >= d0 L.
          const double bound = ca + (d0 * length * dir - (rr - ra)) / s;  // along = d0 there
          const bool above = dir * s > 0;  // along grows with the column
          const double edges[3][2] = {{cl - hl, cl + hl}, {cl - 4 * hl, cl - 2 * hl}, {cl + 2 * hl, cl + 4 * hl}};
          for (int box = 0; box < 3; ++box) {
            double lo = edges[box][0], hi = edges[box][1];
            if (above) lo = std::max(lo, bound); else hi = std::min(hi, bound);
            if (!(hi >= lo)) continue;
            int c_count = 0;
            const long v = prefix.Sum(rr, static_cast<int>(std::ceil(lo)), static_cast<int>(std::floor(hi)), &c_count);
            sum[box] += static_cast<double>(v);
            count[box] += c_count;
          }
          visit(j, sum, count);
        }
      };
      // Tails alone: only lines that leave the end by at least a half width a row (the tails' test below).
      const double theta_lo = std::atan(fill ? kEndMinSlope : std::max(kEndMinSlope, half)),
                   theta_hi = std::atan(kEndMaxSlope);
      for (int i = 0; i < anchor_count; ++i) {
        const int a = anchors[i];
        const int ra = p[static_cast<size_t>(a)].row;
        const int max_rows = std::abs(limit_row - ra);
        const int min_rows = std::abs(end_row - ra) + kEndMinRows;
        if (max_rows < min_rows) continue;
        for (double theta = theta_lo; theta <= theta_hi;) {
          const double tan_t = std::tan(theta), length = std::sqrt(1.0 + tan_t * tan_t);
          for (int sign : {-1, 1}) {
            const double s = sign * tan_t;
            run(a, p[static_cast<size_t>(a)].column, s, max_rows, [&](int j, const double* sum, const long* count) {
              if (j < min_rows) return;
              const double z = z_of(sum[0], sum[1], sum[2], count[0], count[1], count[2]);
              if (z > best.z) {
                best.z = z;
                best.anchor = a;
                best.rows = j;
                best.slope = s;
                best.contrast = sum[0] / count[0] - 0.5 * (sum[1] / count[1] + sum[2] / count[2]);
              }
            });
          }
          theta += kEndAngleStep * half / (span * length);
        }
      }
      if (best.anchor < 0 || best.z < min_z) continue;
      const double best_ca = p[static_cast<size_t>(best.anchor)].column;
      // Each half of the run on its own (the line goes on through it, it does not stop in its first rows).
      const int ra = p[static_cast<size_t>(best.anchor)].row;
      const int first_fill = std::abs(end_row - ra) + 1;
      const int middle = (first_fill + best.rows) / 2;
      double first_half[3] = {0, 0, 0}, all[3] = {0, 0, 0};
      long first_count[3] = {0, 0, 0}, all_count[3] = {0, 0, 0};
      run(best.anchor, best_ca, best.slope, best.rows, [&](int j, const double* sum, const long* count) {
        if (j == middle) std::copy(sum, sum + 3, first_half), std::copy(count, count + 3, first_count);
        if (j == best.rows) std::copy(sum, sum + 3, all), std::copy(count, count + 3, all_count);
      });
      if (z_of(first_half[0], first_half[1], first_half[2], first_count[0], first_count[1], first_count[2]) < kGapHalfZ ||
          z_of(all[0] - first_half[0], all[1] - first_half[1], all[2] - first_half[2], all_count[0] - first_count[0],
               all_count[1] - first_count[1], all_count[2] - first_count[2]) < kGapHalfZ)
        continue;
      // The line refined (twelfth session): the angles within one step of the best (kEndRefineSteps a
      // step) and offsets across within a half width, each scored by a Gaussian matched filter across the
      // line (zero-mean over +-3 sigma) on the pixels of the rows to fill, binned by their distance across
      // (kEndBinPx; the Gaussian tabulated per bin).
      const double sigma_w = std::max(1.0, 2.0 * half / kFwhmPerSigma);
      const int half_bins = static_cast<int>(std::floor(half / kEndBinPx)),
                g_bins = static_cast<int>(std::ceil(3.0 * sigma_w / kEndBinPx));
      const int centre_bin = half_bins + g_bins + 1, bins = 2 * centre_bin + 1;
      gauss.resize(static_cast<size_t>(2 * g_bins + 1));
      for (int m = -g_bins; m <= g_bins; ++m) {
        const double x = m * kEndBinPx;
        gauss[static_cast<size_t>(m + g_bins)] = std::exp(-0.5 * x * x / (sigma_w * sigma_w));
      }
      bin_sum.resize(static_cast<size_t>(bins));
      bin_count.resize(static_cast<size_t>(bins));
      const double t_best = std::atan(std::abs(best.slope)), sign = best.slope < 0 ? -1.0 : 1.0;
      const double angle_step = kEndAngleStep * half / (span * std::sqrt(1.0 + best.slope * best.slope));
      double best_score = -1e300, best_s = best.slope, best_offset = 0;
      for (int q = -kEndRefineSteps; q <= kEndRefineSteps; ++q) {
        const double s = sign * std::tan(t_best + q * angle_step / kEndRefineSteps);
        const double length = std::sqrt(1.0 + s * s);
        std::fill(bin_sum.begin(), bin_sum.end(), 0L);
        std::fill(bin_count.begin(), bin_count.end(), 0);
        // Each row's columns: those within half + 3 sigma across of the line (the offsets' Gaussian windows)
        // and at least d0 along from the anchor (the stretch's own light left out: dir ((c - ca) s + (rr -
        // ra)) >= d0 L, a bound on the column as dir s != 0).
        const double reach = (half_bins + g_bins + 1) * kEndBinPx;
        const double per_column = 1.0 / (length * kEndBinPx);  // bins per column
        for (int j = first_fill; j <= best.rows; ++j) {
          const int rr = ra + dir * j;
          if (rr < 0 || rr >= rows) continue;
          const double cl = best_ca + s * (rr - ra);
          double lo = cl - reach * length, hi = cl + reach * length;
          const double bound = best_ca + (d0 * length - dir * (rr - ra)) / (dir * s);
          if (dir * s > 0)
            lo = std::max(lo, bound);
          else
            hi = std::min(hi, bound);
          if (!(hi >= lo)) continue;
          const int c_first = ClampToIndex(std::ceil(lo), cols), c_last = ClampToIndex(std::floor(hi), cols);
          const uint8_t* a = on.ptr<uint8_t>(rr) + channel;
          const uint8_t* b = off.ptr<uint8_t>(rr) + channel;
          double t = centre_bin + 0.5 + (c_first - cl) * per_column;
          for (int c = c_first; c <= c_last; ++c, t += per_column) {
            const int k = static_cast<int>(std::floor(t));
            if (k < 0 || k >= bins) continue;
            bin_sum[static_cast<size_t>(k)] += SignedDifference(a[c * step], b[c * step]);
            ++bin_count[static_cast<size_t>(k)];
          }
        }
        for (int i = -half_bins; i <= half_bins; ++i) {
          double sg = 0, sgd = 0, sd = 0;
          long n_px = 0;
          for (int m = -g_bins; m <= g_bins; ++m) {
            const size_t k = static_cast<size_t>(centre_bin + i + m);
            const double g = gauss[static_cast<size_t>(m + g_bins)];
            sg += g * bin_count[k];
            sgd += g * static_cast<double>(bin_sum[k]);
            sd += static_cast<double>(bin_sum[k]);
            n_px += bin_count[k];
          }
          if (n_px < 1) continue;
          const double score = sgd - sg / static_cast<double>(n_px) * sd;
          if (score > best_score) {
            best_score = score;
            best_s = s;
            best_offset = i * kEndBinPx;
          }
        }
      }
      best.slope = best_s;
      const double ca = best_ca + best_offset * std::sqrt(1.0 + best_s * best_s);
      const double length = std::sqrt(1.0 + best.slope * best.slope);
      const double uncertainty = std::max(kGapMinUncertaintyPx, 2.0 * length * kEndAcrossSd);
      if (tail_ok && best.z >= kTailMinZ && std::abs(best.slope) >= half) {
        for (int k = anchor + dir; k != e + dir * (1 + end.strays); k += dir) {
          const int rr = p[static_cast<size_t>(k)].row;
          if (dir * (rr - ra) <= 0) continue;
          tail_moves.emplace_back(k, static_cast<float>(ca + best.slope * (rr - ra)));
        }
      }
      if (!fill) continue;
      for (int j = first_fill; j <= best.rows; ++j) {
        const int rr = ra + dir * j;
        const double c = ca + best.slope * (rr - ra);
        if (!(c >= 0 && c <= cols - 1)) continue;
        {
          // The row's own evidence: the same Gaussian matched filter on its pixels alone, at least
          // kEndRowZ times its noise (the row holds light of the line where it is placed).
          const double reach = g_bins * kEndBinPx;
          const int c_first = ClampToIndex(std::ceil(c - reach * length), cols);
          const int c_last = ClampToIndex(std::floor(c + reach * length), cols);
          const uint8_t* a = on.ptr<uint8_t>(rr) + channel;
          const uint8_t* b = off.ptr<uint8_t>(rr) + channel;
          double sg = 0, sgg = 0, sgd = 0, sd = 0;
          int n_px = 0;
          for (int cc = c_first; cc <= c_last; ++cc) {
            const int m = static_cast<int>(std::lround((cc - c) / (length * kEndBinPx)));
            if (m < -g_bins || m > g_bins) continue;
            const double g = gauss[static_cast<size_t>(m + g_bins)];
            const int d = SignedDifference(a[cc * step], b[cc * step]);
            sg += g;
            sgg += g * g;
            sgd += g * d;
            sd += d;
            ++n_px;
          }
          if (n_px < 3) continue;
          const double var_g = sgg - sg * sg / n_px;
          if (var_g <= 0) continue;
          const double z_row = (sgd - sg / n_px * sd) / (noise_dn * std::sqrt(kGapCorrelation * var_g));
          if (z_row < kEndRowZ) continue;
        }
        LinePoint& q = filled.emplace_back();
        q.row = rr;
        q.column = static_cast<float>(c);
        q.peak = static_cast<float>(best.contrast);
        q.width = static_cast<float>(2.0 * half * length);
        q.uncertainty_px = static_cast<float>(uncertainty);
        q.quality = static_cast<float>(kGapQuality / (1.0 + uncertainty * uncertainty));
        q.flags = 0;
      }
    }
  }
  // A tail's row may hold the light of either line: its uncertainty at least the move, its quality to match.
  for (const auto& [k, c] : tail_moves) {
    LinePoint& q = p[static_cast<size_t>(k)];
    WidenUncertainty(std::max(static_cast<double>(q.uncertainty_px), std::abs(double{c} - q.column)), &q);
    q.column = c;
  }
  if (filled.empty()) return 0;
  std::sort(filled.begin(), filled.end(), [](const LinePoint& a, const LinePoint& b) { return a.row < b.row; });
  // Two ends' runs may reach the same rows (an upper end's and a lower end's facing each other): one each.
  filled.erase(std::unique(filled.begin(), filled.end(), [](const LinePoint& a, const LinePoint& b) { return a.row == b.row; }),
               filled.end());
  const int count = static_cast<int>(filled.size());
  std::vector<LinePoint> merged;
  merged.reserve(p.size() + filled.size());
  std::merge(p.begin(), p.end(), filled.begin(), filled.end(), std::back_inserter(merged),
             [](const LinePoint& a, const LinePoint& b) { return a.row < b.row; });
  p.swap(merged);
  return count;
}

int FillLineGaps(const cv::Mat& on, const cv::Mat& off, int channel, double noise_dn,
                 std::vector<LinePoint>* line_points, double min_z) {
  std::vector<LinePoint>& p = *line_points;
  const size_t n = p.size();
  if (n < 2 * kGapMinSide || noise_dn <= 0) return 0;
  const int rows = on.rows, cols = on.cols;
  auto joined = [&](size_t a, size_t b) {
    const int gap = p[b].row - p[a].row;
    return gap >= 1 && gap <= kGapMaxRows && std::abs(p[b].column - p[a].column) <= kSteepMaxStepPx * gap;
  };
  std::vector<LinePoint> filled;
  std::vector<NearPixel> near;  // [0, near_count): the window's pixels kept for the centre of mass
  size_t near_count = 0;
  std::vector<GapSpan> spans;  // a window's rows
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  const bool avx2 = HaveAvx2();  // the window rows 4 pixels at a time (GapWindowRowAvx2, the same bits)
#endif
  std::vector<float> widths;  // a stretch's widths across (here: not allocated per gap)
  for (size_t i = 0; i + 1 < n; ++i) {
    const int gap = p[i + 1].row - p[i].row;
    if (gap < 2 || !joined(i, i + 1)) continue;
    size_t lo = i, hi = i + 1;
    while (lo > 0 && p[lo - 1].row >= p[i].row - kGapFitRows && joined(lo - 1, lo)) --lo;
    while (hi + 1 < n && p[hi + 1].row <= p[i + 1].row + kGapFitRows && joined(hi, hi + 1)) ++hi;
    // A side with fewer than kGapMinSide points within kGapFitRows: its points up to kGapFarFitRows away.
    if (i - lo + 1 < static_cast<size_t>(kGapMinSide))
      while (lo > 0 && i - lo + 1 < static_cast<size_t>(kGapMinSide) &&
             p[lo - 1].row >= p[i].row - kGapFarFitRows && joined(lo - 1, lo))
        --lo;
    if (hi - i < static_cast<size_t>(kGapMinSide))
      while (hi + 1 < n && hi - i < static_cast<size_t>(kGapMinSide) &&
             p[hi + 1].row <= p[i + 1].row + kGapFarFitRows && joined(hi, hi + 1))
        ++hi;
    if (i - lo + 1 < static_cast<size_t>(kGapMinSide) || hi - i < static_cast<size_t>(kGapMinSide)) continue;
    // The curve through the stretch's points, about the gap's first missing row, and its residual test.
    Curve curve;
    double residual2 = 0, max_length = 1.0;
    auto fit = [&](size_t first, size_t last) {
      curve.r0 = p[i].row + 1;
      Eigen::Matrix3d normal = Eigen::Matrix3d::Zero();
      Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
      for (size_t k = first; k <= last; ++k) {
        const double dr = p[k].row - curve.r0;
        const Eigen::Vector3d basis(1.0, dr, dr * dr);
        normal += basis * basis.transpose();
        rhs += basis * static_cast<double>(p[k].column);
      }
      const Eigen::LDLT<Eigen::Matrix3d> ldlt(normal);
      if (ldlt.info() != Eigen::Success) return false;
      const Eigen::Vector3d x = ldlt.solve(rhs);
      if (!x.allFinite()) return false;
      curve.c0 = x[0];
      curve.s = x[1];
      curve.k = x[2];
      residual2 = 0;
      max_length = 1.0;
      widths.clear();
      for (size_t k = first; k <= last; ++k) {
        const double e = p[k].column - curve.ColumnAt(p[k].row);
        residual2 += e * e;
        const double slope = curve.s + 2.0 * curve.k * (p[k].row - curve.r0);
        max_length = std::max(max_length, std::sqrt(1.0 + slope * slope));
        widths.push_back(p[k].width / static_cast<float>(std::sqrt(1.0 + slope * slope)));
      }
      return residual2 <= kGapMaxResidual * kGapMaxResidual * (1.0 + max_length) * (1.0 + max_length) *
                              static_cast<double>(last - first + 1 - 3);
    };
    if (!fit(lo, hi)) {
      // A stretch that fails the test over its kGapFitRows (or kGapFarFitRows) rows may still be a line
      // near the gap: the nearest kGapNearPoints points a side (twelfth session, below).
      const size_t near_lo = std::max(lo, i + 1 >= kGapNearPoints ? i + 1 - kGapNearPoints : size_t{0}),
                   near_hi = std::min(hi, i + kGapNearPoints);
      if ((near_lo == lo && near_hi == hi) || !fit(near_lo, near_hi)) continue;
      lo = near_lo;
      hi = near_hi;
    }
    const size_t dof = hi - lo + 1 - 3;
    // The curve's error along the row at a missing row: taken as one of its points' (the residual's RMS
    // per degree of freedom): a gap's middle is as far from the points as the curve gets.
    const double fit_sd = std::sqrt(residual2 / static_cast<double>(dof));
    // The line's width across it: the stretch's median width along the rows over L.
    std::nth_element(widths.begin(), widths.begin() + static_cast<long>(widths.size() / 2), widths.end());
    const double width_across = widths[widths.size() / 2];
    const double half = std::max(1.5, 0.5 * width_across);  // the matched filter's half width
    for (int r = p[i].row + 1; r < p[i + 1].row; ++r) {
      const double c0 = curve.ColumnAt(r);
      if (!std::isfinite(c0) || c0 < 0 || c0 > cols - 1) continue;
      const double dr0 = r - curve.r0;
      const double s = curve.s + 2.0 * curve.k * dr0;
      const double length = std::sqrt(1.0 + s * s);
      const double reach_across = (kGapSideShift + 1.0) * half;
      const double row_reach = (kGapAlongPx + reach_across * std::abs(s)) / length + 1.0;
      const int r_first = ClampToIndex(FloorOf(r - row_reach), rows);
      const int r_last = ClampToIndex(CeilOf(r + row_reach), rows);
      // The window's columns: only those within reach_px of the curve across (at least the outer boxes'
      // edge, (kGapSideShift + 1) half widths, and the centre of mass's reach, its window from a centre
      // within a half width; plus a pixel) can count; the others are not visited. The original reach
      // along the line, (reach_across + kGapAlongPx) L + 1, only ever added pixels that no test keeps.
      const double window = std::max(kSteepMinHalfPx, width_across);
      const double col_reach = (reach_across + kGapAlongPx) * length + 1.0;
      const double reach_px = std::min(col_reach, std::max(reach_across, half + window) * length + 1.0);
      // span_of(rr, near_only) gives the window's row rr: its pixels' pointers, the curve's column cc in it,
      // and the columns c_first..c_last to visit. A pixel's along from the row's point is
      // ((c - c0) s + rr - r) / L, its across (c - cc) / L. The row's own pixels are summed first (a cheap
      // rejection: the row must hold light of the line, below), then the window's. The sums are of integers
      // (exact in any order); the pixels within kGapAlongPx along whose weight is positive and that lie
      // within the centre of mass's reach are kept, in the visiting order, for the centre of mass (its
      // floating-point sums as another visit of the window would give them).
      // Bit-identical to visiting the whole window each time (laser_digest --check against a build before
      // issue 15's speed-ups; and against main 8acc4fb after this function's rewrite, fifteenth session).
      // Fourteenth session: the tests of along and across against kGapAlongPx and the boxes' edges on their
      // numerators (kTestMargin), a division only near an edge and for the kept pixels' across (two
      // divisions a pixel, ~17,000 pixels a typical frame); the rows' bounds rounded inline (FloorOf).
      const int step = on.channels();
      const double along_in = kGapAlongPx * length * (1.0 - kTestMargin),
                   along_out = kGapAlongPx * length * (1.0 + kTestMargin);
      // |across| L at the boxes' edges: the centre box's (half), the side boxes' inner (2 half) and outer
      // (4 half) edges; and the centre of mass's reach (t within +-half, then the window).
      const double edge0_in = half * length * (1.0 - kTestMargin), edge0_out = half * length * (1.0 + kTestMargin);
      const double edge1_in = (kGapSideShift - 1.0) * half * length * (1.0 - kTestMargin),
                   edge1_out = (kGapSideShift - 1.0) * half * length * (1.0 + kTestMargin);
      const double edge2_in = (kGapSideShift + 1.0) * half * length * (1.0 - kTestMargin),
                   edge2_out = (kGapSideShift + 1.0) * half * length * (1.0 + kTestMargin);
      const double com_out = (half + window) * length * (1.0 + kTestMargin);
      const double inv_s = 1.0 / s;
      // near_only: only the columns that may lie within kGapAlongPx along; a row with none is empty
      // (c_last < c_first). Along is monotonic in the column, so the row's two ends tell.
      auto span_of = [&](int rr, bool near_only) {
        const double cc = curve.ColumnAt(rr);
        const int c_first = ClampToIndex(FloorOf(cc - reach_px), cols);
        const int c_last = ClampToIndex(CeilOf(cc + reach_px), cols);
        GapSpan span{
            on.ptr<uint8_t>(rr) + channel, off.ptr<uint8_t>(rr) + channel, cc, rr - r, c_first, c_last};
        if (!near_only) return span;
        // Empty only where both ends lie beyond kGapAlongPx on one side for certain (else each pixel's own
        // test decides: visiting more pixels than needed changes nothing).
        const double x0 = (span.c_first - c0) * s + (rr - r), x1 = (span.c_last - c0) * s + (rr - r);
        if ((x0 > along_out && x1 > along_out) || (x0 < -along_out && x1 < -along_out)) {
          span.c_last = span.c_first - 1;
          return span;
        }
        // On a sloped line only a band of the row's columns lies within kGapAlongPx along: those between
        // the columns where along is -kGapAlongPx and kGapAlongPx, a pixel more either side (at a slope
        // of at least kGapBandMinSlope a column moves along by ~0.05 px or more, far above rounding, and
        // above the rounding of 1 / s).
        if (std::abs(s) >= kGapBandMinSlope) {
          const double e0 = c0 + (-kGapAlongPx * length - (rr - r)) * inv_s;
          const double e1 = c0 + (kGapAlongPx * length - (rr - r)) * inv_s;
          if (std::isfinite(e0) && std::isfinite(e1)) {
            span.c_first = std::max(span.c_first, ClampToIndex(FloorOf(std::min(e0, e1)) - 1.0, cols));
            span.c_last = std::min(span.c_last, ClampToIndex(CeilOf(std::max(e0, e1)) + 1.0, cols));
          }
        }
        return span;
      };
      auto box_of = [&](double across) {
        return std::abs(across) <= half                          ? 0
               : std::abs(across + kGapSideShift * half) <= half ? 1
               : std::abs(across - kGapSideShift * half) <= half ? 2
                                                                 : -1;
      };
      // box_of(y / L), dividing only near an edge.
      auto box_at = [&](double y) {
        const double ay = std::abs(y);
        if (ay <= edge0_in) return 0;
        if (ay >= edge0_out && ay <= edge1_in) return -1;
        if (ay >= edge1_out && ay <= edge2_in) return y < 0 ? 1 : 2;
        if (ay >= edge2_out) return -1;
        return box_of(y / length);
      };
      // Contrast of the centre box over the sides' mean, per pixel, and its noise; over the whole window
      // (at least min_z times its noise), over each half (at least kGapHalfZ: the line goes on through
      // the row, it does not end at it, as at a shadow's edge) and over the row's own pixels (kGapHalfZ
      // too: the row holds light of the line, not only its neighbours: rows where the laser is hidden, a
      // laser-off frame saturated, stay empty).
      auto z_of = [&](double s0, double s1, double s2, int n0, int n1, int n2) {
        if (n0 < 2 || n1 < 2 || n2 < 2) return 0.0;
        const double contrast = s0 / n0 - 0.5 * (s1 / n1 + s2 / n2);
        return contrast / (noise_dn * std::sqrt(kGapCorrelation * (1.0 / n0 + 0.25 / n1 + 0.25 / n2)));
      };
      // The row's own pixels of the three boxes, at any distance along (a steep line's sides lie far along).
      double own[3] = {0, 0, 0};
      int own_count[3] = {0, 0, 0};
      const GapSpan own_row = span_of(r, false);
      for (int c = own_row.c_first; c <= own_row.c_last; ++c) {
        const int box = box_at(c - own_row.cc);
        if (box < 0) continue;
        own[box] += SignedDifference(own_row.a[c * step], own_row.b[c * step]);
        ++own_count[box];
      }
      if (z_of(own[0], own[1], own[2], own_count[0], own_count[1], own_count[2]) < kGapHalfZ) continue;
      // The matched filter: the box on the curve, and the boxes kGapSideShift half widths to either side;
      // each split into the halves before and after the row's point along the line.
      double sum[2][3] = {{0, 0, 0}, {0, 0, 0}};  // [half][centre, left, right]
      int count[2][3] = {{0, 0, 0}, {0, 0, 0}};
      // Summed in runs of pixels of one box and half (a row crosses each box once), in integers.
      int run_key = -1, run_sum = 0, run_count = 0;
      auto flush = [&] {
        if (run_key < 0) return;
        sum[run_key / 3][run_key % 3] += run_sum;
        count[run_key / 3][run_key % 3] += run_count;
      };
      near_count = 0;
      // The window's rows that may hold pixels within kGapAlongPx along, and their columns.
      spans.clear();
      size_t span_pixels = 0;
      for (int rr = r_first; rr <= r_last; ++rr) {
        const GapSpan span = span_of(rr, true);
        if (span.c_last < span.c_first) continue;
        spans.push_back(span);
        span_pixels += static_cast<size_t>(span.c_last - span.c_first + 1) + 4;
      }
      if (near.size() < span_pixels) near.resize(span_pixels);
      bool done = false;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
      if (avx2) {  // all the rows' pixels 4 at a time (GapWindowAvx2, the same bits), unless one is undecided
        const GapRow terms{c0, s, length, along_in, along_out, kNormalMin, edge0_in, edge0_out, edge1_in,
                           edge1_out, edge2_in, edge2_out, com_out, noise_dn};
        int64_t sums[6] = {0, 0, 0, 0, 0, 0}, counts[6] = {0, 0, 0, 0, 0, 0};
        done = GapWindowAvx2(spans.data(), spans.size(), step, cols - 1, terms, sums, counts, near.data(), &near_count);
        if (done) {
          for (int k = 0; k < 6; ++k) {
            sum[k / 3][k % 3] += static_cast<double>(sums[k]);
            count[k / 3][k % 3] += static_cast<int>(counts[k]);
          }
        } else {
          near_count = 0;
        }
      }
#endif
      for (size_t j = 0; j < spans.size() && !done; ++j) {
        const GapSpan& span = spans[j];
        const int rr = r + span.dr;
        const double cc = span.cc;
        for (int c = span.c_first; c <= span.c_last; ++c) {
          // Whether |along| <= kGapAlongPx, and along < 0 (the numerator's sign is the quotient's).
          const double x = (c - c0) * s + (rr - r);
          const double ax = std::abs(x);
          bool before;
          if (ax < along_in && (ax >= kNormalMin || ax == 0)) {
            before = x < 0;
          } else {
            if (ax > along_out) continue;
            const double along = x / length;
            if (std::abs(along) > kGapAlongPx) continue;
            before = along < 0;
          }
          const double y = c - cc;
          const int d = SignedDifference(span.a[c * step], span.b[c * step]);
          const double w = d - noise_dn;
          // Beyond com_out, |across - t| > window for any t within +-half: never counted.
          if (w > 0 && !(std::abs(y) > com_out)) near[near_count++] = {y / length, w};
          const int box = box_at(y);
          if (box < 0) continue;
          const int key = (before ? 0 : 3) + box;
          if (key != run_key) {
            flush();
            run_key = key;
            run_sum = 0;
            run_count = 0;
          }
          run_sum += d;
          ++run_count;
        }
      }
      flush();
      const double z = z_of(sum[0][0] + sum[1][0], sum[0][1] + sum[1][1], sum[0][2] + sum[1][2],
                            count[0][0] + count[1][0], count[0][1] + count[1][1], count[0][2] + count[1][2]);
      if (z < min_z) continue;
      if (z_of(sum[0][0], sum[0][1], sum[0][2], count[0][0], count[0][1], count[0][2]) < kGapHalfZ ||
          z_of(sum[1][0], sum[1][1], sum[1][2], count[1][0], count[1][1], count[1][2]) < kGapHalfZ)
        continue;
      // The point's peak: the centre box's mean over the sides' (DN).
      const int n_centre = count[0][0] + count[1][0];
      const double contrast =
          (sum[0][0] + sum[1][0]) / n_centre - 0.5 * ((sum[0][1] + sum[1][1]) / (count[0][1] + count[1][1]) +
                                                      (sum[0][2] + sum[1][2]) / (count[0][2] + count[1][2]));
      // The centre: the centre of mass across of the difference above one sigma, within the line's width.
      double t = 0, spread2 = 0, sum_w = 0;
      bool ok = true;
      for (int iteration = 0; iteration < kSteepIterations && ok; ++iteration) {
        double sw = 0, swt = 0, swtt = 0;
        for (size_t k = 0; k < near_count; ++k) {
          const NearPixel& q = near[k];
          if (std::abs(q.across - t) > window) continue;
          const double w = q.weight;
          sw += w;
          swt += w * q.across;
          swtt += w * q.across * q.across;
        }
        if (sw <= 0) {
          ok = false;
          break;
        }
        t = std::clamp(swt / sw, -half, half);
        sum_w = sw;
        spread2 = std::max(0.0, swtt / sw - (swt / sw) * (swt / sw));
      }
      if (!ok) continue;
      // The centre of mass's noise across: sigma sqrt(sum of (x - t)^2 over the window's pixels) / sum of
      // weights, with the weights' spread standing in for the pixels' (times their count), and the pixels'
      // correlation; the curve's own error across. The two estimates of the centre (the curve's, t = 0, and
      // the centre of mass's) are combined by their inverse variances.
      const double com_var = std::max(1e-6, kGapPixelVariance * noise_dn * noise_dn * spread2 *
                                                (2.0 * window * 2.0 * kGapAlongPx) / (sum_w * sum_w));
      const double fit_var = std::max(1e-6, (fit_sd / length) * (fit_sd / length));
      const double var = 1.0 / (1.0 / com_var + 1.0 / fit_var);
      t *= fit_var / (com_var + fit_var);
      const double uncertainty = std::max(kGapMinUncertaintyPx, 2.0 * length * std::sqrt(var));
      LinePoint& q = filled.emplace_back();
      q.row = r;
      q.column = static_cast<float>(c0 + t * length);
      q.peak = static_cast<float>(contrast);
      q.width = static_cast<float>(width_across * length);
      q.uncertainty_px = static_cast<float>(uncertainty);
      q.quality = static_cast<float>(kGapQuality / (1.0 + uncertainty * uncertainty));
      q.flags = 0;
    }
  }
  const int count = static_cast<int>(filled.size());
  if (!filled.empty()) {
    std::vector<LinePoint> merged;
    merged.reserve(n + filled.size());
    std::merge(p.begin(), p.end(), filled.begin(), filled.end(), std::back_inserter(merged),
               [](const LinePoint& a, const LinePoint& b) { return a.row < b.row; });
    p.swap(merged);
  }
  return count;
}

}  // namespace rotoscan::laser::detail
