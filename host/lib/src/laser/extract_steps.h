// The named steps of the line extraction (the design notes at the top of extract.cc say what each does
// and why): private to the laser module.
//
//   EstimateNoise    noise.cc       the difference's noise from a sparse sample, for the threshold
//   RowPass          row_pass.cc    steps 1-2: the row's difference and its groups of pixels >= threshold
//   FindCandidates   candidates.cc  step 3: the runs of such pixels, measured (peak, extents, width)
//   ChooseCandidate  candidates.cc  step 4: plausibility, and the one candidate the row keeps
//   MeasurePoint     point.cc       step 5 in the row: sub-pixel centre and flags
//   ScorePoints      point.cc       step 5 after the rows: width, uncertainty (a steep line's larger), quality
//   SmoothAlongLine  smooth.cc      (public) the along-line smoothing
//   LimitSmoothing   smooth.cc      the smoothing moves no point further than its uncertainty
//   RecentreSteepLines steep.cc     a steep line's centre measured across the line, before the smoothing
//   RecentreLineEnds ends.cc        a steep stretch's end rows (a cut profile) measured across the line
//   RecentreJunctionRows ends.cc    the table line's rows past its corner with the object's, on its own line
//   RecentreRimRows  ends.cc        a stretch's fading tail past a rim, on the flat top's faint line
//   FillLineGaps     gaps.cc        rows missing inside a stretch, found along its curve by a matched filter
//
// The kernels these use, once per instruction set, are in kernels.h.
#pragma once

#include <array>
#include <cstdint>
#include <utility>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "rotoscan/laser/extract.h"

namespace rotoscan::laser::detail {

// The row pass's difference of a laser-on pixel a over its laser-off pixel b (step 1, row_pass.cc): a
// pixel saturated in the laser-on frame over one with headroom (b <= 255 - threshold) counts as 255,
// whatever the difference says (no notch splits a line); otherwise a - b, at least 0.
inline int LaserDifference(int a, int b, int threshold) {
  return a == 255 && b <= 255 - threshold ? 255 : (a > b ? a - b : 0);
}

// The signed difference of a laser-on pixel a over its laser-off pixel b, with step 1's rule for a saturated
// laser-on pixel: 255 - b (the matched filters' box sums: gaps.cc, ends.cc's junction step).
inline int SignedDifference(int a, int b) {
  if (a == 255 && b < 255) return 255 - b;
  return a - b;
}

// The matched filter's box pair (gaps.cc, which says how they were chosen; ends.cc's junction step uses the
// same): the side boxes kGapSideShift half widths away; a box's sum varies kGapCorrelation times N sigma^2
// (neighbouring pixels of a demosaiced MJPEG frame are correlated); each half along the line and a row's own
// pixels reach kGapHalfZ noise units.
constexpr double kGapSideShift = 3.0;
constexpr double kGapHalfZ = 3.0;
constexpr double kGapCorrelation = 3.0;

// The centre of mass weighs d - 0.15 * peak over the run above that level. Measured on the
// synthetic cases of EstimatorComparison with levels 0.5, 0.35, 0.25, 0.2, 0.15 and 0.1: below 0.25 the
// wide weak line gains (more pixels average the noise, 0.092 -> 0.073 px) and nothing loses; 0.15 keeps a
// margin of 6 sigma over a 60 DN line's noise floor.
// The level 0.15 as the exact fraction kComLevelNum / kComScale.
constexpr int kComScale = 20;
constexpr int kComLevelNum = 3;

// Runs whose half-maximum extents are at most this far apart are one candidate (step 3).
constexpr int kMergeGapPx = 2;
// The speckle's share of a point's variance per pixel of line width, px^2 (Uncertainty, design notes).
constexpr double kSpeckleTerm2 = 0.08 * 0.08;
// Internal flag of a point whose profile is lopsided (its centre of mass more than a quarter of its
// width from the middle of its half-maximum extent): cleared before the points are returned.
constexpr uint8_t kFlagLopsided = 0x80;
// The albedo inside the line (point.cc, design notes "Albedo inside the line"): an edge is seen where the
// laser-off row over the centre-of-mass run holds a value at least kAlbedoMinOffDn and its highest
// exceeds 1.6 x its lowest + kAlbedoStepDn; the difference is then divided by the laser-off row, over a
// window of at most kAlbedoMaxWindow pixels: by the row itself where its edge is sharp (kAlbedoSharpEdgeNum),
// else by the row blurred by a Gaussian of kAlbedoBlurPx, to the power kAlbedoExponent.
constexpr int kAlbedoMinOffDn = 12;
// The dark level may be as low as the division's floor (3 DN, AlbedoNormalisedCentre): the webcam's dark
// cells read 3-6 DN in the red channel (black level, JPEG), and with 4 DN the rows on them were left
// undivided (issue 15, textured set, 3 steps x 2 lasers: object rows over 1 px across 65 -> 54 at f/4,
// 71 -> 54 at f/2.4; glossy and Spot unchanged). Lower (1-2 DN) divides by the floor, not the albedo.
constexpr int kAlbedoMinLowDn = 3;
constexpr int kAlbedoEdgeSpanPx = 4;
// A single gradual ramp is shading, not albedo (issue 15, fourteenth session, rfglossy4; applied only on
// frames whose noise was measured on lit pixels): where the steepest change over kAlbedoEdgeSpanPx holds
// less than kShadingRampNum / kShadingRampDen of the range and the row is monotone over the window (its
// total variation under kShadingMonotoneNum / kShadingMonotoneDen of the range), the row is not divided.
// On the glossy webcam set (a white sphere and cylinder: no albedo edge at all) the rows divided at the
// sphere's lower limb, where the lamp's shading falls from ~73 DN to the black level over ~8 px, passed
// the half-range gate (steepest 0.50-0.60 of the range in 36 of its 67 divided object rows, 8 steps x 2
// lasers, f/4, per row without smoothing or steep step); the division pulled them to the dark side: 12 of
// those 36 over 1 px across against 2 for the plain centre of mass (f/2.4: 40 rows, 18 against 5). All of
// them monotone (total variation < 1.2 x the range: 36 of 36; 35 of 40). The textured set's divided rows
// in that band: 150 (f/4), 142 (f/2.4); the division helps the non-monotone ones (two edges: a dark cell's
// strip; 8 over 1 px against 17, f/2.4 3 against 18) and is even on the monotone ones (32 rows: 7 against
// 7; 26: 2 against 3), so the gate takes only the monotone ones. bench accuracy, 8 steps, all lit rows over
// 1 px across: glossy f/4 1.533 -> 1.378 % (object 1.629 -> 1.370 %), f/2.4 1.177 -> 1.053 % (object 1.189 ->
// 0.982 %); textured unchanged at both (0.862 %, 1.114 %; its RMS across +0.001 px at f/4); on 6, 7 and 12
// steps (not used to choose it) glossy 0.04-0.30 points lower, textured 0-2 rows more (doc/issue15-log.md).
// ObjectRowsTest.GlossyLimbShadingIsNotDividedOut checks it on frames of other seeds.
constexpr int kShadingRampNum = 3, kShadingRampDen = 5;
constexpr int kShadingMonotoneNum = 6, kShadingMonotoneDen = 5;
constexpr int kAlbedoMinLevelPx = 3;
constexpr int kAlbedoStepDn = 4;
// The laser-off row's edge is sharp where its steepest change over two pixels holds at least
// kAlbedoSharpEdgeNum / kAlbedoSharpEdgeDen of the window's range (low to high) and the laser-on row does
// not saturate there: the frame was not blurred (a rendered frame without demosaicing or JPEG, a
// machine-vision camera), the difference is the laser's profile times the albedo pixel by pixel, and
// dividing by the row itself gives the profile back (noise-free rows, a Gaussian line of sigma 4 px over a
// 0.9 / 0.09 step 0-6 px from its centre, pixel-integrated: 0.009 px RMS, worst 0.021; with the blurred
// divisor of the tenth session, 2 px and exponent 1.1, 0.567 / 1.416 px). A step blurred by a Gaussian of
// sigma b changes by erf(1 / (b sqrt 2)) of its range over two pixels at most: b 0 px 1.0, 0.5 px 0.95,
// 0.75 px 0.82, 1 px 0.68, 1.25 px 0.58, 2 px 0.38 (over one pixel the unblurred step's share depends on
// its phase, 0.5 to 1: no threshold separates it from a 0.75 px blur). Seen (issue 15, eleventh session):
// POV-Ray's and our unblurred renderer's checker rows 0.9-1 (7 of ~2,400 under 0.8); the webcam sets'
// divided rows (2 steps, both scenes, 1,416 rows) 0.45-0.6, 8 at 0.8 or more.
constexpr int kAlbedoSharpEdgeNum = 4, kAlbedoSharpEdgeDen = 5;
// A bright feature with only kAlbedoNarrowBrightPx (not kAlbedoMinLevelPx) pixels above the middle of the
// range is divided out too where the row is blurred (its steepest two-pixel change under
// kAlbedoSharpEdgeNum / kAlbedoSharpEdgeDen of the range) and the line's peak is at least
// kAlbedoNarrowMinPeakDn (issue 15, rfalbedo3). On the textured webcam set such a feature is a sliver of a
// white cell in the line's flank (the cylinder's cells foreshortened; 20-27 DN over a 5-7 DN dark cell in
// the red channel, which the blur leaves 2 px above the middle), and the undivided centre was pulled ~1 px
// towards it (the set's "texture not divided" rows over 1 px, 7 of 66 at f/4 and 8 of 55 at f/2.4, 8 steps).
// The rows so newly divided, per row without smoothing, across, over 1 px / RMS (clipped at 2 px), 8 steps
// f/4: 28 -> 12 of 73 / 0.97 -> 0.69 px; f/2.4: 22 -> 3 of 63 / 0.91 -> 0.49 px; on angles not tuned on,
// 6 steps 8 -> 6 of 68 / 0.60 -> 0.50 and 12 -> 1 of 52 / 0.75 -> 0.46; 7 steps 16 -> 9 of 87 / 0.76 ->
// 0.57 and 18 -> 0 of 105 / 0.73 -> 0.37. Not in a sharp row: there a 2 px feature is resolved, a texel
// or a lamp's highlight, which the laser does not share (RealFramesTest.DesignStatisticsWithNotches...:
// 8 of its 400 rows over 1 px if divided). Not under a weak line: on the glossy set's table (peaks 9-14 DN)
// the rows so divided were no better (6 steps f/4: 114 rows, 57 closer and 57 further, RMS 0.397 -> 0.413
// px; f/2.4 25 rows, 19 further); with the 30 DN floor the glossy set has none.
constexpr int kAlbedoNarrowBrightPx = 2;
constexpr int kAlbedoNarrowMinPeakDn = 30;
// Where the edge is sharp the window reaches kAlbedoSharpReach half-maximum widths beyond the extent (the
// blurred rule's 1 cut the line where the extent is only the bright side's part: a step 2 px from the
// centre of a line of sigma 4 px left the centre +1.3 px towards the bright side, 4 px +3.1 px; 2 widths
// +0.11 / +1.19, 3 +0.01 / +0.24, 4 +0.01 / -0.05 (RealFramesTest.AlbedoEdgeAlongTheLineInAnUnblurredFrame's
// rows at peak 220, every divided row so widened).
// Not for the blurred rule: 2 widths there put the glossy set's object rows over 1 px across from 2.20 to
// 2.38 % (8 steps, f/4), textured 1.00 to 1.09 %.
constexpr int kAlbedoSharpReach = 4;
// Nor where the laser-on row saturates within the window: the difference there is clipped, not the
// profile times the albedo, and its division by the row itself pulls the centre to the dark side. Such
// windows are measured by the ratio clipped at the level the saturated pixels are known to reach where the
// edge is sharp (ClippedAlbedoCentre, point.cc: our renderer's checker cylinder at 1280x960 12.8 -> 0 % of
// rows over 1 px), else divided by the blurred row (POV-Ray's bright checker at 1280x960, the white cells
// saturated: rows over 1 px 19.3 % divided by the row itself, 17.1 % so; 640x480 8.5 / 9.6 % but RMS
// 0.285 / 0.227 px; our unblurred renderer's checker cylinder at 1280x960: 7.7 / 15.5 %; all measured with
// a one-pixel sharpness test and the blurred rule's window, before the two settings above).
// Otherwise (a webcam's frame: demosaicing, 4:2:0 chroma, the optics) the difference is the blur of the
// profile times the albedo, which no division by the blurred row undoes; a blur and an exponent of the
// divisor that leave the least error were measured on issue 15's sets (session 11, `rotoscan bench accuracy
// --scene` glossy + textured, the textured object's rows over 1 px across / RMS per row; glossy within
// 0.1 points either way): 8 steps f/4, 8 steps f/2.4, 6 steps f/4 (angles not tuned on):
//   blur 2 px, exponent 1.1 (session 10's):   1.894 % 0.341 px | 1.441 % 0.317 | 1.835 % 0.379
//   blur 1 px, exponent 1:                    1.295 % 0.311    | 1.360 % 0.261 | 1.921 % 0.370
//   blur 1 px, exponent 0.95:                 1.020 % 0.298    | 1.279 % 0.248 | 1.425 % 0.353
//   blur 1 px, exponent 0.9:                  1.101 % 0.288    | 1.214 % 0.248 | 1.209 % 0.345
// and at f/4, 8 steps: blur 0 (the row itself) 2.801 %; 0.7 px 1.700 / 1.263 % (exponent 1 / 0.95);
// 1.25 px 1.198 / 1.085 %; 1.5 px 1.295 % (exponent 1.05), 1.263 % (0.95). 1 px is about the webcam
// frames' own edge blur (their steepest two-pixel change 0.5-0.6 of the range: ~1.2 px). An exponent under
// 1 divides the albedo out only in part: the division amplifies the noise and speckle of the dark side.
// 0.9, not 0.95: it leaves the textured set's divided rows unbiased (per row, no smoothing, 8 steps: mean
// error towards the bright side -0.025 px at f/4 and f/2.4; 0.95: -0.097 / -0.098; ObjectRowsTest), and
// it has the fewest rows over 1 px at f/2.4 and on the 6 steps not tuned on. On the synthetic step blurred
// 2 px (RealFramesTest.AlbedoDivisionIsUnbiasedUnderTheWebcamBlur) it leaves +0.151 px (0.95: -0.005,
// 1.0: -0.165; session 10's 2 px / 1.1: -0.118).
constexpr double kAlbedoBlurPx = 1.0;
constexpr double kAlbedoExponent = 0.9;
constexpr int kAlbedoMaxWindow = 256;
// A line's top end (issue 15, rfdiv; ExtractOptions::albedo_end_rows, AlbedoDivisorRow in point.cc). Below
// a rim the laser-off row is the blur of the side and of the surface above it (the cylinder's cap, lit by
// the ambient light from above), which the laser does not light: the webcam's vertical blur (optics sigma
// 1.2 px, the red channel sampled on every other row, 4:2:0 chroma) carries the cap's 30-40 DN 2-3 rows down
// over the side's dark cell (the textured set, rows 342-343 below the rim at 341: 21 and 15 DN against the
// cell's 6), while the difference, the laser's light, holds the side's albedo alone. Divided by that row,
// the dark side of the line was over-divided and the centre stayed 1.0-1.5 px towards the bright cell
// (noise-free render 1.3-1.4 px; two rows further down 0.5 px). Such a row is divided by the laser-off row of
// the line's body instead, the nearest row at most kAlbedoEndSearchRows below whose own light
// kAlbedoEndReachRows above is not weak. A row is at the top end where the light per albedo (the difference
// over the laser-off row, summed over the half-maximum extent) kAlbedoEndReachRows above is under
// kAlbedoEndWeakNum / kAlbedoEndWeakDen of its own: at the textured set's rims 0.0-0.3 (rows 340-345), in the
// line's body at a cell's horizontal edge down to 0.43 (half redivided 60-odd body rows per 6 steps by
// another cell's row: textured 6 steps f/4, the object's rows over 1 px +1, the table's +2; the difference
// alone, not per albedo, takes a dark cell above for an end: 8 steps f/4, the smoothed unsaturated divided
// rows over 1 px 1 -> 27 of 3,351). Not at
// the bottom end: in this rig a line's bottom meets the table's line, whose light continues (the junction),
// and there the object's row was taken for the table's (textured f/2.4, 8 steps, the table's rows over 1 px
// 25 -> 30). Not on a weak line (peak under kAlbedoEndMinPeakDn: the glossy set's faint rows, 8-13 DN, where
// the light 3 rows away differs by noise alone), nor on the fading tail itself (peak under half the body
// row's: the rows the rim step puts on the flat top's line, ends.cc; on the glossy set such a row, divided
// by the body's row, led that step 13.9 px off). Nor where the line does not run down the rows (the body
// row's difference's centre of mass more than kAlbedoEndShiftPx from the row's: a slanted line sees other
// columns' albedo there; RealFramesTest.AlbedoDivisionIsUnbiasedUnderTheWebcamBlur's rows, each its own
// line 50-70 px, had their bias towards the bright side +0.15 -> +0.41 px without it; the rims' side lines
// move 0.01 px per row). Measured in doc/issue15-log.md (seventeenth session, rfdiv).
constexpr int kAlbedoEndReachRows = 3;
constexpr int kAlbedoEndWeakNum = 3, kAlbedoEndWeakDen = 10;
constexpr int kAlbedoEndSearchRows = 2;
constexpr int kAlbedoEndMinPeakDn = 30;
constexpr double kAlbedoEndShiftPx = 1.5;
// The division's residual (px, about two standard errors), added to a divided point's uncertainty in
// place of the texture term (ScoreAlbedoDivision): on issue 15's textured set (3 steps x 2 lasers, f/4)
// the divided rows' per-row error was 0.67 px RMS against ~0.45 px for plain rows of the same set, i.e.
// ~0.5 px of the division's own, and it did not grow with the albedo's contrast (high / low 1.5 to 12:
// 0.43-0.47 px smoothed) nor with the size of the correction (0-0.75 px: 0.45, 1.5-2.25 px: 0.50), but
// with how narrow the difference is (a dark cell cuts the line): over both webcam sets, 8 steps, divided
// rows 4-8 px wide 0.49-0.60 px, 8-12 px wide 0.26-0.30 px; so it is scaled by the frame's median width
// over the point's (when over 1).
constexpr double kAlbedoResidualPx = 1.0;
// Glints (FlagGlints, design notes "Glints"): the line's foot (the centre of mass's run, above 0.15 of
// the peak) against the same line's own: a saturated point is a glint's core when its foot is over
// kGlintFootRatio times the median foot of the frame's points kGlintNearRows+1 to kGlintReachRows rows
// away (either side; at least kGlintMinReference of them), and a point is a glint when at least
// kGlintShare of the rows within kGlintHalfRows of it are core points, and at most kGlintMaxShare of
// those within kGlintReachRows (a compact stretch, not a line overexposed all along). The foot, not the
// half-maximum width nor their ratio: clipping widens a line's half-maximum width whatever its profile
// (POV-Ray's bright checker: 7.5 px saturated against 5 px on the dark cells at 640x480) and its foot
// hardly at all (8-9 against 7-8 px; a triangle's foot cannot outgrow its base), while a glint's lobe
// widens both (glossy set: foot 17 to 22 px). Measured on the glossy set (truth: the glossy laser frame
// against the matte one) and POV-Ray's bright checker (README "Frames from POV-Ray"): 1.15 to 1.2 flag
// the glint's middle and no POV-Ray row; 1.12 flags 91-167 POV-Ray rows at 1280x960 (and 81-128 of our
// renderer's at 640x480); 1.25 misses the glint.
constexpr double kGlintFootRatio = 1.15;
constexpr int kGlintNearRows = 16;
constexpr int kGlintMinReference = 8;
// The glint's extent: from its flagged points (core and skirt) the stretch grows through neighbouring
// saturated points (at most 2 rows apart, kGlintSkirtPxPerRow px per row) whose foot is over
// kGlintGrowRatio times their median (the lobe's rising and falling ends: glossy set, 111 of 117 rows in
// a glint flagged with it, 98 without).
constexpr double kGlintGrowRatio = 1.05;
constexpr int kGlintHalfRows = 8;
constexpr double kGlintShare = 0.75;
constexpr int kGlintReachRows = 96;
constexpr double kGlintMaxShare = 0.5;
// The glint's skirt: saturated points of the same stretch (at most kGlintSkirtPxPerRow px per row from
// a core point) within kGlintSkirtRows rows of one are flagged too (glossy set, the tuned webcam preset:
// 27 of the 117 rows in a glint were at the lobe's rising and falling ends, where the share test
// fails, all saturated, all within 8 rows of a flagged point).
constexpr int kGlintSkirtRows = 8;
constexpr float kGlintSkirtPxPerRow = 2.0f;
// A glint's added uncertainty (px, about two standard errors: glint rows of the glossy set were 0.6-1.0 px
// off) and quality factor.
constexpr double kGlintUncertaintyPx = 1.6;
constexpr double kGlintQuality = 0.5;
// ScoreLineEnds: how many points at either end of a stretch lose quality.
constexpr int kLineEndRows = 8;
// WidenAtLineBreaks: a jump of the line over kBreakJumpPx (along the row, against the line's slope on
// the row before) widens the uncertainty of the points within kBreakReachRows rows of it to the jump.
constexpr float kBreakJumpPx = 3.0f;
constexpr int kBreakReachRows = 4;
// RecentreSteepLines (steep.cc): a point is steep where its line's least-squares slope over the points
// within kSteepFitRows rows either side (a stretch: rows at most 2 apart, at most kSteepMaxStepPx columns
// per row; a parabola through at least kSteepMinPoints) is at least kSteepSlope columns per row; its centre is the
// centre of mass across that curve of the difference above 0.15 of its peak, within kSteepAlongPx along
// the line and the line's width (at least kSteepMinHalfPx) across it, in one pass around the stretch's
// fitted curve (tenth session, rfsteepfast; before, kSteepIterations windows per point, each around the
// last centre, as gaps.cc's windows still are). Chosen on the webcam test's 3 steps (glossy / textured,
// rows > 1 px across the line; before: 3.49 / 4.41 %): slope 1.5, 4 px along, straight: 2.74 / 4.15 %;
// slope 1.0: 2.08 / 3.96 %; 8 px
// along: 2.03 / 4.02 %. Straight, Spot's machine-vision scan (100 frames per row, 0.208 px before) went to
// 0.241 px: a curved line's centre of mass lies inside its curve; with the parabola over 4 rows 0.212, but
// the table's straight line lost (3.10 / 4.50 %: the curvature of 9 noisy points is noise); over 8 rows
// 2.12 / 4.31 %, Spot 0.211 px (across the line 0.185 -> 0.188). Spot loses a little at any setting
// tried (slope 2: 0.209; peaks under 40 DN only: 0.2095): on a clean, sharp line the row's own centre and
// the smoothing are better, so the step runs only on frames whose noise was measured on lit pixels
// (LineStats::noise_on_lit: the webcam-like frames; extract.cc).
// With the line test and the move limit below (final): test's 3 steps 2.61 / 4.15 %, bench's 8 steps
// 2.65 / 4.57 % (before: 3.78 / 4.84 %).
constexpr double kSteepSlope = 1.0;
constexpr int kSteepFitRows = 8;
constexpr double kSteepMaxStepPx = 24.0;
constexpr double kSteepAlongPx = 8.0;
constexpr double kSteepMinHalfPx = 2.0;
constexpr int kSteepIterations = 2;
// ... and only where the stretch's points lie within kSteepMaxResidual (1 + L) px RMS of the fit along
// their rows: rows whose centres merely lie near each other are no line (RealFramesTest's independent rows
// jump by up to 40 px and gave 181 rows over 1 px without this test).
constexpr double kSteepMaxResidual = 0.35;
// ... or within kSteepLooseResidual (1 + L) px where the fitted slope is at least kSteepMinSlopeT standard
// errors (eleventh session, rftabrows; TableRowsTest at 8 steps, f/4, rows over 1 px across, glossy object /
// table, textured object / table: 83 / 61 / 110 / 58 before; 0.8 alone: 76 / 46 / 113 / 46, but
// RealFramesTest's independent rows 0 -> 11 over 1 px; with the slope's test, 5 sigma: 77 / 46 / 113 / 48,
// RealFramesTest 0; 10 sigma: 78 / 47 / 113 / 49; loose 1.0 fails RealFramesTest). A point moves by at most
// its uncertainty or kSteepMaxMoveWidths of its row width (0.3 with the above: 75 / 46 / 112 / 49; 0.6 the
// same, within a row).
constexpr double kSteepLooseResidual = 0.8;
constexpr double kSteepMinSlopeT = 5.0;
constexpr double kSteepMaxMoveWidths = 0.3;
constexpr int kSteepMinPoints = 7;
// Zero bytes before and after the row's difference buffer (LineExtractor::diff_).
constexpr int kPad = 16;

// The highest value of a run and the first pixel holding it (FindPeak, kernels.h).
struct PeakInRun {
  int value = 0;
  int position = 0;
};

// ScanNotch's result (kernels.h): the highest difference over a run, and the lowest among its saturated
// laser-on pixels (255 when there is none).
struct NotchScan {
  int best_difference = 0;
  int worst_saturated = 255;
};

// SumsAround's result (kernels.h): sums of a row either side of a pixel.
struct SidesSum {
  int left = 0, right = 0;
};

// MinMaxRange's result (kernels.h): the lowest and highest value of a stretch of a row.
struct ByteRange {
  int low = 255, high = 0;
};

struct Candidate {
  int peak_pos = 0;  // first pixel at the peak value
  int peak = 0;
  int first = 0;  // half-maximum extent, inclusive
  int last = 0;
  // The width at half maximum as the fraction width_num / width_den (width_den > 0): the candidates are
  // judged by it without a division (a division per candidate on the way to every row's decision was the
  // row's slowest step); only the winner's width is divided out.
  int width_num = 0, width_den = 1;
  int com_first = 0, com_last = 0;  // the centre of mass's run (kCenterOfMass only)
  bool off_saturated = false;
  bool WidthWithin(double min_width, double max_width) const {
    return width_num >= min_width * width_den && width_num <= max_width * width_den;
  }
  double Width() const { return static_cast<double>(width_num) / width_den; }
};

// The noise estimate (noise.cc) samples only pixels whose laser-off value is at least kNoiseMinOffDn:
// darker pixels are clipped at the sensor's black level and carry less noise than a lit surface (webcam
// preset, two laser-off frames of one step: the difference's SD 0.4-0.7 DN where off < 16, 1.1-1.3 DN at
// 16-96, 0 where off = 0, which is 70-80 % of a webcam frame: the frame-wide MAD was 0.05-0.1 DN), so a
// frame-wide estimate said nothing of the noise where a line can be. With fewer than kNoiseMinSamples
// such pixels (a dark frame) every sampled pixel counts.
constexpr int kNoiseMinOffDn = 16;
constexpr uint32_t kNoiseMinSamples = 256;
// Its histograms: 512 bins of the clamped difference and a last one for the pixels not sampled.
constexpr int kNoiseDumpBin = 512;
using NoiseHistograms = std::array<std::array<uint32_t, kNoiseDumpBin + 1>, 4>;

// Robust noise sigma of (on - off) on channel `channel` of the frames, from a sparse sample of the
// pixels whose laser-off value is at least kNoiseMinOffDn (see above); *on_lit: whether enough were
// (false: the estimate is from all sampled pixels).
double EstimateNoise(const cv::Mat& on, const cv::Mat& off, int channel, bool* on_lit);

// Steps 1-2 on one row: d[i] (i < cols; d padded with kPad zero bytes each side) = the difference of the
// laser-on row a and the laser-off row b, and the (start, bit mask) pairs of the row's pixel groups that
// hold a pixel >= threshold, in starts/masks (room for cols / 16 + 3). Returns the number of groups; 0:
// no laser in this row. `avx2`: the AVX2 kernel may run (kernels.h).
int RowPass(const uint8_t* a, const uint8_t* b, int cols, int threshold, bool avx2, uint8_t* d, int* starts,
            uint64_t* masks);

// Step 3: the candidates of a row from RowPass's groups, at most `capacity` of them; returns how many.
// Fills notches in d (saturated laser-on pixels take the run's plateau). `centre_of_mass`: also measure
// each candidate's centre-of-mass run.
int FindCandidates(const uint8_t* a, const uint8_t* b, uint8_t* d, int cols, int threshold, int off_saturation_dn,
                   bool centre_of_mass, const int* starts, const uint64_t* masks, int block_count,
                   Candidate* candidates, int capacity);

// Step 4: the index of the candidate the row keeps, or -1 (the reason counted in *stats). Sets the row's
// kFlagMultiplePeaks / kFlagStrongerRejected in *flags. `continuous`: the previous row with a point is
// at most 2 rows back, its centre at previous_column.
int ChooseCandidate(const Candidate* candidates, int count, const ExtractOptions& o, double previous_column,
                    bool continuous, LineStats* stats, uint8_t* flags);

// What step 5 needs of the frame.
struct FrameScale {
  double noise_dn = 0;
  int threshold = 0;
  double quality_per_snr = 0, quality_per_contrast = 0;
  double narrow_width = 0, wide_width = 0;  // the quality falls outside these widths
};

// What step 5 measures in the row (MeasurePoint) for the uncertainty and quality, which ScorePoints
// computes after the row loop for all points at once: their divisions and square roots, one chain per
// point, then overlap instead of each waiting within its row (laser_bench: 10-15 % of a frame).
struct PointTerms {
  double column;            // the centre, px
  double extent_middle;     // the middle of the half-maximum extent, px
  double width_num, width_den;  // the width at half maximum, their ratio
  double peak;              // DN
  double left, right;       // sums of the laser-off row over the centre of mass's run either side of
  double left_n, right_n;   // the centre's pixel, and their pixel counts (at least 1)
  bool overexposed;         // saturated, its centre by kCenterOfMass (a glint's candidate: FlagGlints)
  int foot;                 // kCenterOfMass: the centre of mass's run, px (FlagGlints); else 0
};

// The blurred division of AlbedoNormalisedCentre: ratio[i - lo] = d[i] over the laser-off row b blurred by
// kAlbedoBlurPx (radius kAlbedoRadius, clipped at the row's ends) to the power kAlbedoExponent, for i in
// [lo, hi] (the AVX2 path where the CPU has it); AlbedoBlurredRatioAt is one pixel's, portable. The blur's
// weights, and the table of blurred^-kAlbedoExponent in steps of 1 / kAlbedoPowerSteps DN (0..256 DN and
// one more) that it interpolates, are point.cc's.
constexpr int kAlbedoRadius = 3;
constexpr int kAlbedoPowerSteps = 16;
void AlbedoBlurredRatio(const uint8_t* d, const uint8_t* b, int cols, int lo, int hi, double floor_dn,
                        double* ratio);
double AlbedoBlurredRatioAt(const uint8_t* d, const uint8_t* b, int cols, int i, double floor_dn);
const double* AlbedoBlurWeights();
const float* AlbedoPowerTableValues();
// Whether the laser-off row b changes inside [first, last] (an albedo edge inside the line); with
// narrow_bright, a bright level only kAlbedoNarrowBrightPx wide counts where the row is blurred.
// With shading_ramps (frames whose noise was measured on lit pixels), a single gradual ramp is shading and
// does not count (kShadingRampNum).
bool AlbedoEdgeInside(const uint8_t* b, int first, int last, bool narrow_bright = false,
                      bool shading_ramps = false);
// The centre of mass of the difference d divided by the laser-off row b (blurred, or itself where its edge
// is sharp and the laser-on row a does not saturate: kAlbedoSharpEdgeNum), over the half-maximum extent
// [first, last] widened by its width each side (kAlbedoSharpReach widths where sharp); negative when it
// fails.
double AlbedoNormalisedCentre(const uint8_t* a, const uint8_t* d, const uint8_t* b, int cols, int first, int last);

// The same where the laser-on row a saturates (at the candidate's peak) and the laser-off row's edge is
// sharp: the centre of mass of d / b clipped at the lowest ratio that the saturated pixels are known to
// reach, (255 - b) / b (point.cc); negative when it does not apply or fails.
double ClippedAlbedoCentre(const uint8_t* a, const uint8_t* d, const uint8_t* b, int cols, int first,
                           int last);

// Step 5, in the row: the point of row `row` from its chosen candidate (sets row, column, peak and flags
// of *point; the rest by ScorePoints), its terms, and its centre in double in *column (the next row's
// continuity test reads it); false when the estimator fails (counted as bad width by the caller). `flags` are
// step 4's. noise_on_lit: the frame's noise was measured on lit pixels (LineStats::noise_on_lit; the
// shading-ramp rule).
// The frames (and the channel) that step 5 reads in rows other than its own: a line's top end rows are
// divided by another row's laser-off row (AlbedoDivisorRow).
struct FrameRows {
  const cv::Mat* on = nullptr;
  const cv::Mat* off = nullptr;
  int channel = 0;
};
// The row whose laser-off row divides row `row`'s difference over the half-maximum extent [first, last] of a
// line of peak `peak` DN: `row` itself, or at the line's top end the body's row (kAlbedoEndReachRows).
int AlbedoDivisorRow(const FrameRows& frames, int row, int first, int last, int peak);
// frames: for AlbedoDivisorRow (with o.albedo_end_rows and noise_on_lit); null: the row's own laser-off row.
bool MeasurePoint(const Candidate& c, const uint8_t* a, const uint8_t* b, const uint8_t* d, int cols, int row,
                  const ExtractOptions& o, uint8_t flags, bool noise_on_lit, LinePoint* point,
                  PointTerms* terms, double* column, const FrameRows* frames = nullptr);

// Step 5, after the row loop: each point's width, uncertainty and quality from its terms, both scaled by
// the line's slope at the point (a steep line's centre per row is less certain); sets kFlagLopsided
// (cleared at the end).
void ScorePoints(const PointTerms* terms, const FrameScale& frame, std::vector<LinePoint>* points);
// ScorePoints' last step: a point whose albedo was divided out (kFlagAlbedoEdge) has no texture term but
// kAlbedoResidualPx in its uncertainty, and its quality lowered to match.
void ScoreAlbedoDivision(std::vector<LinePoint>* points);
// A point's uncertainty set to `with`, its quality lowered as ScorePoints' 1 / (1 + u^2) would have it
// (point.cc; used by every step that widens a point: the albedo division, the line breaks, the rim step, the
// end step's tails).
void WidenUncertainty(double with, LinePoint* p);

// After ScorePoints: the quality of the kLineEndRows points at either end of each stretch of line (rows at
// most 2 apart, no jump over max_jump_px per row) falls to 1 / (kLineEndRows + 1), 2 / ... of its value:
// a line ends at a depth edge, a rim or a silhouette, where the sheet's footprint is cut and the profile
// partial. Ends at the frame's first or last 2 rows (of `rows`) are the frame's, and keep their quality.
void ScoreLineEnds(double max_jump_px, int rows, std::vector<LinePoint>* points);

// Last of all (after the smoothing: the centres are final and the steps before read the uncertainty): where
// the line jumps between consecutive rows (at most 2 apart) by more than kBreakJumpPx against its slope on
// the row before (the row after where there is none before), the points within kBreakReachRows rows of
// the jump get an uncertainty of at least the jump (the row may have taken either line's light), and
// their quality lowered to match (as ScoreAlbedoDivision). The centres are not changed.
void WidenAtLineBreaks(std::vector<LinePoint>* points);

// After ScorePoints: flags the points of a compact overexposed stretch as glints (kFlagGlint), lowers
// their quality and widens their uncertainty; returns how many. `rows`: the frame's.
int FlagGlints(const PointTerms* terms, int rows, std::vector<LinePoint>* points);

// After SmoothAlongLine: each point moves from its own centre `own[i]` by at most its uncertainty, and
// not at all where the profile changes (saturation begins or ends, but for kFlagAlbedoEdge; kFlagLopsided).
void LimitSmoothing(const std::vector<float>& own, std::vector<LinePoint>* points);

// After ScorePoints (it reads each point's row width and peak): the points on a steep stretch of line
// moved to where the centre measured across the line crosses their row (steep.cc); `on`, `off` the frames,
// `channel` the laser's, `threshold` the row pass's. Returns how many moved.
int RecentreSteepLines(const cv::Mat& on, const cv::Mat& off, int channel, int threshold,
                       std::vector<LinePoint>* points);

// After RecentreSteepLines, before the smoothing: the end rows of a steep stretch (whose row profile the
// line's end cuts) moved to where the centre measured across the line, the line's direction from the
// stretch's interior, crosses their row (ends.cc, which says why and how the constants act). Returns how
// many were measured. Chosen on the webcam sets (8 steps x 2 lasers, f/4; TableRowsTest's rows over 1 px
// across, glossy object / table, textured object / table; before 83 / 81 / 108 / 59): the interior from 8
// points in, the end rows within the width over the slope, steep.cc's residual test: 81 / 57 / 108 / 56;
// the end rows put on the interior's straight line (no centre measured): 109 / 52 / 108 / 49 (the object's
// lines bend near a silhouette); that only where a parabola's curvature is under 3 standard errors:
// 87 / 54 / 108 / 55; the final (16 points in, twice the width, residual 0.8, no end followed by the line
// after a gap): 84 / 60 / 108 / 58. Eleventh session (rftabrows), after the steep step's loose line test
// (75 / 46 / 112 / 49 with 12 points): the interior over 24 points, 75 / 45 / 112 / 45 (16 or 32 points: 75 /
// 45 / 112 / 47; from 10 or 12 points in: 75-79 / 45-46 / 112 / 45-47); at 12 steps, a set it was not chosen
// on, 146 / 75 / 183 / 73 -> 146 / 70 / 183 / 70; LineEndTest's last rows over 1 px 11 -> 5 of 60.
constexpr int kEndMaxRows = 16;
constexpr int kEndFitRows = 24;
constexpr double kEndMaxMoveWidths = 0.5;
constexpr double kEndMaxResidual = 0.8;
constexpr int kEndResumeRows = 16;
// The end's last kEndOnLineRows rows are put on the interior's straight line, no centre measured (thirteenth
// session, rftable3): at the table's rim, a cut along the rows, every step's two lasers had their last row
// 1.0-2.6 px past the truth's end along the row (the window across the line reaches past the rim, the lit
// side pulls it). `bench accuracy`, 8 steps, over 1 px across, with the junction step: 0 / 1 / 2 / 3 rows
// (1 = the last row only): f/4 glossy 1.60 / 1.58 / 1.53 / 1.50 %, textured 0.98 / 0.98 / 0.93 / 0.90 %; f/2.4
// 1.21 / 1.19 / 1.18 / 1.13 %, 1.33 / 1.28 / 1.22 / 1.20 %; 2 kept (3: textured f/4's RMS per row 0.318 ->
// 0.319 px); all end rows so: the tenth session's 52 / 49 and worse rows 2-7 from the end (doc/issue15-log.md).
// (Those were measured on rftable3's branch, without rfalbedo3's change; on the merged main, 0 -> 2 rows: f/4
// glossy 1.595 -> 1.533 %, textured 0.910 -> 0.862 %; f/2.4 1.208 -> 1.177 %, 1.221 -> 1.114 %; LineEndTest.
// TableRimLastRowsNearTheTruthOnWebcamFrames: 17 -> 10 of 64-65 rows over 1 px.)
constexpr int kEndOnLineRows = 2;
// CentreAcross's window (ends.cc): the sums of its kept pixels, each a whole number (c relative to an
// integer column c0 near the foot, dr the pixel's row less the window's r0), so exact in double and the same
// bits in any order or vector width: count, d, d c, c, d dr, dr. The centre across, sum w across / sum w
// with w = d - level and across = (c - foot_c - s dr) / L, follows from them (AcrossCentre). Sixteenth
// session and before, the two sums w and w across were added pixel by pixel in column order for their
// bits: 4 dependent additions a block of 4 pixels, which left the window's loads waiting (seventeenth
// session, rfspeed6: laser_bench BM_WebcamStep/2/0, the line ends from memory, 23.3-23.8 -> 21.4-21.5 µs, min
// of 5, 3 rounds alternated; cached, /2/1, ~21 either way; the same points, laser_digest and bench accuracy).
struct AcrossSums {
  double n = 0, d = 0, dc = 0, c = 0, ddr = 0, dr = 0;
};
// The centre across the line from a window's sums (foot_rel = foot_c - c0): false where no pixel has weight.
inline bool AcrossCentre(const AcrossSums& sums, double foot_rel, double s, double length, double level, double* t) {
  const double sum_w = sums.d - sums.n * level;
  if (sums.n == 0 || !(sum_w > 0)) return false;
  const double sum_dw = (sums.dc - foot_rel * sums.d - s * sums.ddr) - level * (sums.c - foot_rel * sums.n - s * sums.dr);
  *t = sum_dw / length / sum_w;
  return true;
}
int RecentreLineEnds(const cv::Mat& on, const cv::Mat& off, int channel, int threshold,
                     std::vector<LinePoint>* points);

// After RecentreLineEnds, before the smoothing: the table's faint steep line's rows just past its corner with
// a bright line (the object's foot), whose profiles the bright line's blur fills, put on the faint line's
// straight fit from further in (ends.cc, which says why and how the constants act); `threshold` the frame's
// detection threshold. Returns how many rows moved. Chosen on the webcam sets (8 steps x 2 lasers, f/4 and
// f/2.4, `rotoscan bench accuracy`; doc/issue15-log.md, thirteenth session): the table's rows over 1 px
// across, f/4 glossy 1.70 -> 1.54 %, textured 2.53 -> 1.06 %; f/2.4 1.39 -> 1.24 %, 2.99 -> 1.75 %; the
// object's no worse. Each constant was a choice among few: the ratio 3 (4: textured's table 1.33 %), the
// reach 5 rows past the corner (3 / 4: 1.38 / 1.15 %; the rows over 1 px ran to 5 rows past the object's,
// TableRowsTest), the move at most 8 px (unlimited: the glossy object's rows moved onto the table's line,
// its rows over 1 px 1.63 -> 2.04 %), the faint-line gate (without it the glossy object at f/2.4, a 47 DN
// stretch beside a highlight, lost 6 rows along the row), the turn 1 column per row.
constexpr double kJunctionRatio = 3.0;
constexpr double kJunctionDimMax = 2.0;
constexpr int kJunctionSkipRows = 8;
constexpr int kJunctionSideRows = 6;
constexpr double kJunctionMinTurn = 1.0;
constexpr int kJunctionReachRows = 5;
constexpr double kJunctionMaxMovePx = 8.0;
// The faint rows at the corner (fifteenth session, rfglossy5): where the object's line fades at a sphere's
// limb it curves into the corner, so its straight side fit crosses the table's line 1-5 rows past the true
// corner, and the table's first rows there were left where the row pass put them: on the object's faded tail
// or a noise grain 10-27 px off (`BenchObjectRowsByPlace` with ROTOSCAN_BENCH_PART=table: 22 of the glossy
// table's 36 rows over 1 px at f/4 were within 6 rows of the object's line). A row between b and the interior
// whose peak is at most kJunctionFaintRatio times the interior's mean peak is the faint line's on either side
// of the crossing, and goes on the interior's fit if that moves it at most kJunctionFaintMaxMovePx. `bench
// accuracy`, 8 steps x 2 lasers, over 1 px across, glossy / textured: f/4 1.362 / 0.635 -> 1.115 / 0.611 %,
// f/2.4 1.022 / 0.754 -> 0.852 / 0.718 % (ratio 1.3: 1.161 / 0.623, 0.882 / 0.730; 2: 1.146 / 0.551, 0.867 /
// 0.647, but the glossy object 52 -> 55 rows over 1 px at f/4; 2.5: 1.177 / 0.575; a move of at most 12 px:
// 1.208 / 0.635, 0.929 / 0.718; 50 px: as 30). The glossy object's rows over 1 px 52 -> 53 at f/4 (its
// faded last row, peak 14, moved onto the table's line extended), textured's and f/2.4's unchanged. Turns not
// used to choose it (6, 7, 12 steps, both apertures): over 1 px across lower in all 12 set-and-aperture pairs
// (glossy f/4 2.028 / 1.240 / 1.960 -> 1.987 / 0.992 / 1.882 %); over 1 px per row higher in 3 of them (glossy
// f/4 6 steps 5.070 -> 5.151 %, 7 steps 4.628 -> 4.744 %; textured f/2.4 6 steps 2.538 -> 2.570 %).
constexpr double kJunctionFaintRatio = 1.6;
constexpr double kJunctionFaintMaxMovePx = 30.0;
// Rows past the corner whose point lies further from the fit than those moves allow (seventeenth session,
// rftabend; ExtractOptions::junction_light). On the textured webcam set the table's rows over 1 px across at the
// object's foot were mostly a narrow bump (3-6 px wide, 13-22 DN) 3-5 px beside the object's line's end
// column, 4-8 rows past its end, brighter than the table's line (~8-12 DN, its row width 13-16 px), so the row
// pass took it; absent from the render without noise, speckle or JPEG, and from the noisy render with JPEG
// alone off (the bench's frames: the textured table's rows over 1 px across 13 / 25 at f/4 / f/2.4 -> 4 / 6
// without JPEG): the object's 150-200 DN line ends inside a 16-row MJPEG block and its red channel (4:2:0
// chroma) rings below. 9-17 px from the table line's fit, beyond kJunctionMaxMovePx, or past the reach, so the
// step left them. Such a row (past the crossing, over kJunctionMaxMovePx from the fit, not moved by the rules
// above) goes on the fit where the table line's own light in the row shows it: the difference summed over the
// interior's half row width each side of the fit, less the same box kGapSideShift half widths to the
// side away from the point (a level or a glow cancels; the point's light is not in it), at least
// kJunctionLightZ noise units, the box pair's variance kGapCorrelation times 2 N sigma^2 (the gap step's box
// pair; z its kGapHalfZ, the row's own light in a filled row): set a priori
// (with the rule's first form, without the rows past the reach: z 2 moved the same rows on the 16 bench cells,
// z 6 fewer). The move comes after the smoothing (extract.cc), each row's uncertainty at least its move:
// moved before it, the stretch ran on through the corner and its rows there went over 1 px along the row
// (textured f/4, 8 steps: per row 2.167 -> 2.191 %). `bench accuracy` (all lit rows, over 1 px across / per
// row), main a704d52 -> this, textured f/4 at 6 / 7 / 8 / 12 steps: 0.766 -> 0.750 / 0.739 -> 0.712 / 0.503 ->
// 0.455 / 0.934 -> 0.902 %, per row 2.506 -> 2.458 / 2.600 -> 2.559 / 2.167 -> 2.095 / 2.498 -> 2.458 %;
// f/2.4: 0.766 / 0.876 -> 0.862 / 0.587 -> 0.503 / 0.694 -> 0.686 %, per row 2.490 -> 2.474 / 2.477 -> 2.436
// / 2.778 -> 2.694 / 2.482 -> 2.474 %; found and RMS across unchanged, RMS per row unchanged but f/2.4 7 steps
// 0.328 -> 0.329 px (two rows 11.1 and 1.23 px off along the row now 0.76 and 0.64: within 1 px they count in
// the RMS); the glossy set identical in all 8 cells (its foot has no such row); the object's rows unchanged.
constexpr double kJunctionLightZ = kGapHalfZ;
int RecentreJunctionRows(const cv::Mat& on, const cv::Mat& off, int channel, int threshold, double noise_dn,
                         std::vector<LinePoint>* points, std::vector<std::pair<int, float>>* deferred);
// The deferred moves (row, column) put in after the smoothing, each row's uncertainty at least its move.
void ApplyJunctionGhostRows(const std::vector<std::pair<int, float>>& deferred, std::vector<LinePoint>* points);

// After the smoothing: a stretch's fading tail past a rim put on the flat top's faint line through the
// corner (ends.cc, RecentreRimRows); `noise_dn` the frame's noise sigma. Returns how many rows moved.
// Issue 15, fourteenth session (rfglossy4): the object's rows over 1 px across on both webcam sets were
// mostly at a rim (ObjectRowsTest.BenchObjectRowsByPlace, the bench's frames, 8 steps, f/4 / f/2.4: glossy
// 14 / 17 of 53 / 38, textured 34 / 50 of 53 / 65): the side line's tail, 1-6 rows past the rim (its peak
// 8-170 DN, falling), where the truth is the flat top's line at 9.3 px per row, 4-13 DN in the noise-free
// render; summed over its width in the row (11 px) at the true column, z 5.6 / 6.3 at the median, so found
// over several rows, not per row. The tail: the end points under kRimTailRatio of the interior's peak (the
// median of kRimInteriorPoints points from kRimInteriorFrom in; a blurred end falls to half at the rim);
// at most kRimMaxTail - 1 of them; the stretch at least kRimMinStretch points, running along the columns
// (kRimMaxInteriorSlope) at the corner. The line through the rim (half a row past the corner) at 2-12
// columns per row (ExtendLineEnds' range, gaps.cc) either way, in steps of kRimSlopeStep, summed over the
// tail's rows and kRimBeyondRows more, as wide in each row as its slope, without the pixels within the
// corner's half width and kRimTailClearPx of its column; kept at kRimMinZ sigmas of the frame's noise
// (at least kRimMinSigmaDn) over at least kRimMinPixels pixels (the best of 82 lines: a high bar), and only
// where the best slope lies inside the range, not at a bound (POV-Ray's sphere, PovrayTest.SphereFigures:
// at its foot the table's bright line, steeper than 12 columns per row, was taken at 12 and two rows moved
// onto it, 1 -> 3 rows over 1 px). Set before measuring (the bound rule after that test failed), not tuned on
// the bench; tried and dropped: a 4 px per row floor, tails required on the interior's line. bench accuracy,
// all lit rows over 1 px across, 8 steps, f/4 / f/2.4: glossy 1.378 -> 1.362 % / 1.053 -> 1.022 %, textured
// 0.862 -> 0.635 % / 1.114 -> 0.754 % (object 0.858 -> 0.615 %, 1.052 -> 0.567 %; table 0.873 -> 0.689
// %, 1.287 %); 6, 7 and 12 steps lower or equal in all 12 set and aperture pairs (doc/issue15-log.md); found
// unchanged; RMS across +0.001-0.002 px (rows that were over 1 px now within it); per row, where a 9 px per
// row line's error is 9 times that across, -0.08 to +0.07 points (the textured object's at f/4 1.198 -> 1.295
// %).
// At the steep bound (fifteenth session, rfrim6; ExtractOptions::rim_rows_at_bound): on textured f/2.4, 11 of
// the 14 rim rows left over 1 px were at 3 ends whose best box sum lay at the 12 px per row bound with z over
// kRimMinZ (the cap's blurred light past the top's last row, 30-60 px wide in a row, pulls the box sums'
// slope up; rfrim5). Those ends (the end point, the direction past it: at_bound) go to ExtendLineEnds' tails
// (gaps.cc), whose Gaussian matched filter also fits the offset and finds ~9 px per row there. bench accuracy
// (8 steps, all lit rows, across / per row): textured f/2.4 0.754 -> 0.623 % / 2.886 -> 2.862 %; textured
// f/4, glossy at both: identical; 12 steps (not used to choose): textured f/4 1.030 -> 1.014 %, the rest
// identical; found and RMS unchanged. A moved row's uncertainty (rfrim6): at least the move and |s| /
// sqrt(3), its quality lowered to match (WidenUncertainty). A moved row may hold the light of
// either line: the step's wrong moves (the side line's real last rows, whose peak a dark cell halved, taken
// for its tail) are off along the row by about the move (10-14 px on the quality test's renders); and on a
// line of s columns per row the box sum places the line anywhere within its box, |s| columns wide (a
// uniform's two standard deviations: |s| / sqrt(3), ~5 px at 9 px per row). Measured on
// RenderedLineTest.WebcamQualityPredictsErrorAndFigures' renders at 8 steps (f/4, both sets; 71 moved rows,
// the tails' included): beyond 1x / 2x their uncertainty 33 / 19 before, 15 / 1 with the move, 8 / 1 with |s|
// / sqrt(3) too. With the fallback and without this, that test fails on textured (worst quality tenth
// RMS 1.47 px against the second's 1.74: the tails' moved rows, their uncertainty the move, 6-45 px, fill the
// worst tenth with 4-7 px errors and push this step's wrong moves, uncertainty 3.5 px, into the second); with
// it 1.82 against 1.38 px.
constexpr double kRimTailRatio = 0.5;
constexpr int kRimInteriorFrom = 6;
constexpr int kRimInteriorPoints = 6;
constexpr int kRimMaxTail = 6;
constexpr int kRimMinStretch = 16;
constexpr double kRimMaxInteriorSlope = 1.0;
constexpr double kRimMinSlope = 2.0, kRimMaxSlope = 12.0, kRimSlopeStep = 0.25;
constexpr int kRimBeyondRows = 4;
constexpr double kRimTailClearPx = 2.0;
constexpr double kRimMinZ = 10.0;
constexpr double kRimMinSigmaDn = 0.5;
constexpr int kRimMinPixels = 8;
// The tail judged by each row's albedo (fifteenth session, rfrim7; ExtractOptions::rim_rows_albedo): the
// step's wrong moves on the textured set (the bench's frames, 8 steps, f/4: 9 rows within 1 px made over it,
// at 4 ends) were the side line's real last rows taken for its tail: at 2 ends (5 rows) on a dark checker
// cell (laser-off 4-7 DN, peaks 15-34 DN) while the interior reaches onto a brighter one (off 5 -> 19 DN,
// peaks 30 -> 150 DN), at 2 (4 rows) a slower fade on mid cells. After: 2 rows, one at each of the latter
// (ObjectRowsTest.RimTailsJudgedByTheirAlbedo). The laser's light scales with the albedo, which the laser-off frame
// shows (ambient times albedo): a tail row is one under kRimTailRatio of the interior's peak and of the
// interior's gain (the median over its unsaturated points, at least 3, of peak over albedo) times the row's
// own albedo (the laser-off frame's mean over the row's column and kRimAlbedoHalfPx either side, at least
// kRimAlbedoFloorSigmas noise sigmas: below that the ratio is the noise's). This can only shorten the tail
// (the corner moves out to the first row at its albedo's level); where it would leave no tail (the end
// point itself at its albedo's level), the end keeps the interior's tail: a row past the rim shows the
// flat top's albedo, not the side's, so its albedo does not say that the side's line reaches it. Both set a
// priori (3 pixels, as wide as the line's core; 2 sigmas), not tuned. Figures: doc/issue15-log.md (rfrim7).
constexpr int kRimAlbedoHalfPx = 1;
constexpr double kRimAlbedoFloorSigmas = 2.0;
int RecentreRimRows(const cv::Mat& on, const cv::Mat& off, int channel, double noise_dn,
                    std::vector<LinePoint>* points, std::vector<std::pair<int, int>>* at_bound = nullptr,
                    bool by_albedo = true);

// After ScorePoints, before RecentreSteepLines: rows missing inside a stretch of line, looked for along the
// stretch's curve by a matched filter over several rows (gaps.cc); `noise_dn` the frame's noise sigma.
// A row is filled where the matched filter's contrast reaches min_z times its noise (gaps.cc). The filled
// points are inserted in row order. Returns how many.
constexpr double kGapMinZ = 6.0;
int FillLineGaps(const cv::Mat& on, const cv::Mat& off, int channel, double noise_dn,
                 std::vector<LinePoint>* points, double min_z = kGapMinZ);
// The gap step's end part (gaps.cc; ExtractOptions::extend_line_ends, run by the extractor after the
// smoothing): a stretch's faint continuation past its end, along a straight line from its end, where the
// matched filter summed over the run of rows reaches min_z (kEndMinZ at the gap step's kGapMinZ). Returns how
// many rows it filled. CountLineEnds: the ends it looks past.
// With tails, an end's blur tail (the points past the anchor) is put on the line found past it where that
// line passes the tails' tests (gaps.cc); only_ends, when given, the (end point, direction) pairs looked
// past.
constexpr double kEndMinZ = 8.0;
int ExtendLineEnds(const cv::Mat& on, const cv::Mat& off, int channel, double noise_dn,
                   std::vector<LinePoint>* points, double min_z = kEndMinZ, bool fill = true,
                   bool tails = false, const std::vector<std::pair<int, int>>* only_ends = nullptr);
int CountLineEnds(const std::vector<LinePoint>& points, int rows);

}  // namespace rotoscan::laser::detail
