// Laser line extraction: design notes.
//
// The detection threshold T = max(min_contrast_dn, min_snr * noise) comes first, the noise from a sparse
// sample of the frame's lit pixels (EstimateNoise; those whose laser-off value is at least 16 DN: on a
// webcam frame 70-80 % of the pixels are black and clipped, and the frame-wide MAD was 0.05-0.1 DN
// against the lit surface's 1.1-1.8). Detection threshold: min_snr = 6, because on pairs of laser-off
// frames of the webcam scenes (no laser: every point false; DetectionFloorTest) 6 sigma gave 1 row
// with a point in 5,760 (4 sigma 25, 5 sigma 10); min_contrast_lit_dn = 6 DN is only a floor for frames
// with almost no noise (8-bit steps, JPEG ringing). It was a fixed 12 DN (8 x 1.5 DN), under which the
// webcam preset's dark table line (~10 DN) was lost in half its rows; now the threshold is 7-11 DN there.
// Where too few sampled pixels are lit to measure the noise (the machine-vision preset's dark frames:
// the estimate, from black pixels, is 0.16 DN), the floor stays min_contrast_dn = 12 DN: with 6 DN there,
// Spot's demo scan (100 frames, rotoscan evaluate --lines) found 464 more of its 55,323 true rows but
// took 106 more points > 2 px off and 143 more where there is no line (weak light that is not the line:
// not noise at 0.16 DN), and its RMS went from 0.208 to 0.214 px.
// Then one pass per row, row-major, no allocation per row (the row
// buffer lives in the extractor), the rows a few ahead prefetched so that memory and work overlap:
//  1. d[i] = max(on[i] - off[i], 0) on the laser channel (differential imaging, paper §3.1), 16 pixels
//     per SSE2 instruction, and the bit mask of d >= T per 64-pixel group, groups without a bit dropped.
//     A pixel saturated in the laser-on frame over an off pixel with headroom (off <= 255 - T) counts as
//     255 whatever its difference: on real webcam frames the on frame saturates over a bright texel and
//     the difference dips inside the line (DESIGN.md, the real row `146 145 53 164 44`), which split
//     the line into pieces that failed the width test, so that a weak candidate 8-16 px away won
//     (issue 15). A run holding such pixels then gives them all its plateau (the highest true difference
//     among them) before it is measured (step 3), so the notch is filled and the plateau stays flat.
//  2. No bit in the row: no laser (the common case for rows above and below the object: it costs only
//     step 1, which runs at the memory-bandwidth bound, laser_bench BM_RowPassOnly).
//  3. Otherwise the candidates are the runs of set bits. For each run: its peak p, the half-maximum extent
//     [a, b] around the peak (vector scans), the width at half maximum (edges interpolated linearly), and
//     whether the laser-off frame is saturated under it (a specular highlight that hides the laser).
//     Runs within kMergeGapPx of the previous candidate's half-maximum extent join it (a dark speckle
//     grain or a noise dip inside one line).
//  4. Candidates narrower than min_width (glints, hot pixels) or wider than max_width (ambient blobs) are
//     dropped. Of the others the highest peak wins; a rival within multiple_peak_ratio of it flags the row
//     (kFlagMultiplePeaks), and then the one nearer the previous row's point wins (lines are continuous).
//     The winner is never much weaker (below multiple_peak_ratio) than a rejected candidate unless that
//     one was too narrow (a hot pixel, a glint's core: kFlagStrongerRejected); a much stronger one that
//     was too wide or hidden under a saturated off pixel may be the laser, so the row gets no point
//     (stats.stronger_rejected) rather than a stray one (RealFramesTest.NeverAWeakCandidate...).
//  5. The sub-pixel centre of the winner, by the chosen estimator.
//
// Uncertainty (LinePoint::uncertainty_px, about two standard errors). The centre of mass of a profile of
// width W (px at half maximum) and peak P over noise sigma_n moves by sigma_n / P * sqrt(W / 12) from the
// noise; a multiplicative speckle field of contrast C and grain g px moves it by about C sqrt(g W / 12),
// which for the speckle of our presets and of real webcams (C ~ 0.3, g ~ 1-3 px) is ~0.08 sqrt(W)
// (kSpeckleTerm2); and a lopsided profile (texture across the line, a glint's lobe, an edge) shows as the
// distance between the centre of mass and the middle of the half-maximum extent, which enters whole.
// u = 2 sqrt(noise^2 + speckle^2 + asymmetry^2), computed for all of a frame's points after the row loop
// (a point whose albedo was divided out has the division's residual in place of the texture term, larger
// where the line is narrower than the frame's median: a dark cell cuts it; ScoreAlbedoDivision)
// (ScorePoints: its divisions and roots then overlap instead of stalling each row). The quality is
// divided by 1 + u^2, so that the points of lowest quality are those with the largest expected errors
// (RenderedLineTest.WebcamQuality...), and that of the 8 points at either end of a stretch of line falls
// by 1/9, 2/9, ... (ScoreLineEnds: a line ends at a rim, a depth edge or a silhouette, where the sheet's
// footprint is cut; on the textured webcam set the gross errors were there, and with 8 rather than 4 the
// best three tenths' clipped RMS went from 0.51 / 0.42 / 0.42 to 0.44 / 0.39 / 0.42 px). The
// along-line smoothing moves a point by at most u, and not at all where saturation begins or ends
// between neighbouring rows or where the profile is lopsided (its asymmetry over a quarter of W): there
// the row's own estimate stays (issue 15: on a real bust the smoothing had moved a fifth of the rows by
// 1-2 px from their own centres); but a saturation change at a point whose albedo was divided out is the
// texture's (the laser-on frame saturates over the white cells only), and is smoothed (smooth.cc).
// Where the line jumps (WidenAtLineBreaks, point.cc, after the smoothing: the centres are final and every
// step before reads the uncertainty; issue 15, the table's line meeting the object's): a row there may hold
// the light of either line, or of both in one run, so the points within kBreakReachRows (4) rows of a jump
// over kBreakJumpPx (3 px along the row, against the line's slope on the row before) get an uncertainty of
// at least the jump, their quality lowered to match. Measured on the webcam sets (8 steps x 2 lasers, f/4,
// error along the row to the nearest true crossing; laser_coverage_test): the points within 4 rows of the
// other part's line beyond 1x / 2x their uncertainty, glossy 26.0 / 16.0 % -> 8.0 / 4.0 % (50 points),
// textured 25.4 / 10.5 % -> 1.8 / 0 % (114); the line-end points, glossy 21.1 / 11.6 -> 17.7 / 6.1 %;
// 3.0-3.5 % of the steep points and 0-1.7 % of the plain ones widened too. A jump of 1.5 or 2 px widened
// more plain and steep points for no gain; a reach of 3 rows left textured 3.5 % beyond 1x, of 6 widened
// 83 % of those points (median error / uncertainty 0.14).
//
// Albedo inside the line (kFlagAlbedoEdge; issue 15's textured set: a white cylinder with a 3 mm checker
// of 10 % albedo cells, lines 8-11 px wide, cells ~15 px). The reflection is the laser's profile times
// the albedo, so an albedo step inside the line pulls the centre of mass towards the bright side, by up to
// a quarter of the width (±3 px measured). The laser-off frame shows the albedo through the same optics;
// where the laser-off row over the centre-of-mass run (widened by 3 px each side) changes sharply (an edge:
// its steepest change over 4 px holds half its range; highest > 1.6 x lowest + 4 DN, lowest >= 3 DN,
// highest >= 12 DN; at least 3 px above and 3 below the middle of the range, so that a feature narrower
// than the red channel resolves, or a small highlight of the lamp, is left alone), the centre
// is the centre of mass (same 0.15 level) of the difference divided by the laser-off row blurred by a
// Gaussian of 2 px, over the half-maximum extent widened by its width each side. Dividing by the raw
// laser-off row is not enough: the red channel is blurred, demosaiced and JPEG'd (4:2:0), and the product
// of the albedo and the line is blurred, not each alone. Measured per row, no smoothing, on the 1,986
// textured rows with an edge (3 steps x 2 lasers), RMS px / share over 1 px, by the blur of the laser-off
// row: plain centre of mass 1.67 / 64 %; divided, no blur 1.03 / 31 %; sigma 1: 0.84 / 22 %; 1.5: 0.72 /
// 16 %; 2: 0.67 / 12 % (chosen); 2.5: 0.69 / 13 %; 3: 0.76 / 17 %; 4.5: 1.04 / 33 %; (the rows without an
// edge: 0.55 / 0.9 %). A least-squares fit of blur(albedo x Gaussian) did worse (0.88 / 24 %). With the
// gates, per row on 3 steps x 2 lasers: textured, the divided rows over 1 px 155 of 1,979 against 978
// undivided (RMS within 2 px 0.58 against 1.23); glossy, 16 rows divided at a sphere's limb, where shading
// passes the gates (the laser, coming from elsewhere, is not shaded like the ambient light): 4 over 1 px
// against 1 (README.md's figures include it; since the fourteenth session a single gradual monotone ramp
// is taken for shading on the webcam's frames, kShadingRampNum in extract_steps.h). The
// 2 px blur is the webcam's; on frames blurred 1.2 px alone it over-blurs and the division removes only
// about half the pull (RealFramesTest.AlbedoStepInsideTheLineIsDividedOut).
//
// Glints (kFlagGlint; issue 15: on real frames 17 % of the rows near a glint were over 1 px off). The
// laser's specular lobe on a glossy surface adds a soft blob, tens of pixels across, centred near the
// line: where it meets the line, the line is overexposed several times over and widens, down to its
// foot (the run above 0.15 of the peak), while a line that is only clipped (a bright surface saturating
// the laser-on frame) widens at half maximum far more than at its foot (a triangular sheet's foot not at
// all; a Gaussian's by ~25 % at 3 times overexposed). So a saturated point's foot is compared with the
// same line's: over 1.15 times the median foot of the points 17 to 96 rows away (the earlier rule, foot
// under 1.3 times the half-maximum extent, was a Gaussian's and took every saturated row of POV-Ray's
// triangular sheet for a glint; still flagged: a compact bright patch on an otherwise unsaturated
// Gaussian line, our renderer's bright checker at 1280x960, 33 rows). A glint is a
// compact stretch of such rows (3 in 4 of the rows within +-8), not a line overexposed all along (at
// most half of the points within +-96 rows), grown through the saturated rows around it whose foot is
// still over 1.05 times theirs: its points are flagged, their quality halved, their
// uncertainty widened by 1.6 px (the glossy set's glint rows were 0.6-1.0 px off). Tested against the
// renderer's truth (RenderedLineTest.GlintsAreFlaggedWhereTheTruthHasThem: the glint is where the glossy
// scene's laser frame exceeds the same scene rendered matte).
//
// Estimators and the saturated plateau. Real lines are 7-16 px wide and flat-topped (the on-frame clips
// at 255), so any estimator that reads only the brightest pixel and its two neighbours is biased toward
// the first pixel of the plateau. Here:
//  * kCenterOfMass weighs (d - 0.15 p) over the run above 0.15 p around [a, b]: both edges enter
//  symmetrically, the weights vanish at
//    the half-maximum crossings so the estimate is continuous as the line moves, and a plateau is just a
//    flat weight. This is Horus's estimator without its bias (Horus uses the raw intensity over a fixed
//    window around the first maximum, so background and window clipping pull the centre).
//  * kParabolic / kGaussian collapse the plateau [pa, pb] of pixels equal to p to its midpoint and fit
//    the 3-point parabola (of d, or of ln d) through the two neighbours of the plateau. Exact for a narrow
//    Gaussian; for a wide line they see only the plateau edges.
//  * kZeroCrossing finds the zero of the FIR derivative g[i] = d[i+k] - d[i-k] with k = round(width / 2),
//    i.e. the point where the two flanks balance, interpolated linearly.
//
// Choice of the default, by measurement (host/tests/laser/extract_test.cc, EstimatorComparison, prints
// the table): 400 rows per case, pixel-integrated profiles, 1.4 DN noise per frame, 8-bit quantisation,
// random sub-pixel centres; RMS error in px:
//        case                          com    parabolic  gaussian  zero-crossing
//        Gaussian sigma 1.2, 150 DN    0.022  0.032      0.024     0.024
//        flat-top ~12 px, saturated    0.017  3.58       3.58      0.016
//        wide weak (60 DN, sigma 3.5)  0.073  0.85       0.84      0.118
// The 3-point fits fail on the saturated plateau (noise on the off frame leaves a single "brightest"
// pixel anywhere on the flat top) and on wide lines (they only see the top). Zero-crossing and centre of
// mass are both good on plateaus; the centre of mass is clearly better on weak wide lines and as good
// elsewhere, so it is the default.
//
// Along-line smoothing (ExtractOptions::smooth_*, on by default). Laser speckle is a multiplicative
// field correlated over a few pixels in both directions; it tilts the profile of a row, and the centre of
// mass follows the tilt. Neighbouring rows see the same speckle grain, so the error is correlated along
// the line too, over about the speckle size: averaging +-2 rows does little, averaging over a window
// several times the grain does a lot. The surface, in contrast, is smooth along the line except at depth
// edges. So after the rows are extracted, each centre is replaced by a weighted (triangular) local
// least-squares polynomial through the centres of its +-h rows, evaluated at its own row: unbiased for a
// straight or slanted line, biased by ~q * h^2 / 6 for a curved one (q the line's second derivative,
// px/row^2). It never crosses a depth edge or a gap: a stretch ends where a row is missing or the column
// jumps by more than smooth_max_jump_px; and a second fit drops neighbours more than smooth_outlier_px
// from the first (a wrong peak inside a stretch). Peak, width, quality and flags stay those of the row.
// Measured on rendered bundles with the default speckle (rotoscan evaluate --lines; plane-300mm 4 steps,
// spot 6 steps, both lasers), RMS px:
//        smoothing                    plane   spot
//        off                          0.173   0.195
//        +-4 rows, straight line      0.134   0.167
//        +-8 rows, straight line      0.108   0.164
//        +-12 rows, straight line     0.092   0.184   <- default
//        +-16 rows, straight line     0.081   0.217
//        +-12 rows, parabola          0.124   0.161
//        +-16 rows, parabola          0.111   0.162
// The plane (the paper's Table 1 test, and the target <= 0.1 px) needs +-12 rows; on Spot the curvature
// bias of the straight line starts to show beyond +-8 rows while the parabola stays at 0.16: Spot's
// error floor is not speckle alone (its texture changes the albedo across the line, which differencing
// does not remove). +-12 rows straight is the default because it meets the target on the plane and is
// still better than no smoothing on Spot; smooth_order = 2 is the better choice for strongly curved
// objects. (The parabola rows were measured before a fix to the parabola's curvature term, which only
// the outlier test of the second fit reads; SmoothAlongLineTest.MatchesTheDefiningWeightedFit checks
// every order against a direct weighted least-squares fit.)
// Steep steps (ExtractOptions::smooth_steep_step_px; issue 15, eleventh session). A stretch ends at a
// column step over smooth_max_jump_px, so a steep line (the table top's, over 1.5 px per row) was not
// smoothed at all: on the webcam sets 2,258 of the glossy table's 2,531 points (SmoothingClassesTest).
// On frames whose noise was measured on lit pixels the stretch goes on where the step is within
// smooth_steep_step_px of the previous one (the slope continues; a depth edge is a sudden jump), with
// the outlier test across the line (smooth.cc). Webcam sets, 8 steps x 2 lasers, f/4, RMS across (bench
// accuracy), main -> 1.5 / 3 px: glossy table 0.317 -> 0.262 / 0.249, object 0.363 -> 0.371 / 0.365
// (with runs of 6+ rows without a steep step kept as their own stretches; 0.373 without), textured table
// 0.300 -> 0.245 / 0.231, object 0.342 -> 0.340 / 0.343. A parabola for the joined fits: glossy object
// 0.348 but tables 0.282 / 0.264; a window shortened by the slope: no gain. Not on the machine-vision
// preset (the joining there cost Spot 0.208 -> 0.269, smooth.cc).
// Curvature (ExtractOptions::smooth_curvature; issue 15, twelfth session). The straight fit is off by
// ~28 q px on a line curving as q x^2 (the q h^2 / 6 above, for the triangular weights of +-12 rows): a
// sphere's line is an arc of ~100-200 px radius, so the smoothed rows sat 0.05-0.2 px off on the
// curve's inside (POV-Ray's sphere: its object's rows +0.19 px on average, blamed on the centre of mass
// until measured; GlossyRowsTest: the glossy set's smoothed rows' mean went from the own estimates'
// +0.111 / -0.119 px to +0.165 / -0.175 for the left / right laser). So each point's straight fit is
// corrected by q B, B from its window's weight sums and q from the change of the fit's slopes 12 rows
// before and after, averaged over +-24 rows (smooth.cc; a parabola fit per window costs the plane 0.092
// -> 0.124 px, above, and measures q from the window's own noise). Webcam sets, 8 steps x 2 lasers, f/4,
// object's rows across (bench accuracy): glossy 0.363 -> 0.336 px, 1.84 -> 1.63 % over 1 px; textured
// 0.289 -> 0.287, 1.04 % both; tables unchanged (the fits of joined steep steps stay straight); POV-Ray's
// sphere 0.115 -> 0.059. Only on frames whose noise is measured on lit pixels, as the joining of steep
// steps: on the machine-vision preset it took Spot (rotoscan evaluate --lines, 100 frames) from 0.2081 to
// 0.1958 px per row, but the scan's colour with the lamp estimated from it from 11.4 to 15.8 levels
// (ColorTest.ViewsDivideOutTheLampAndAgreeAcrossLasers, limit 12.5; 13.1 with whole windows alone
// corrected) and the demo pair's alignment from 0.0172 to 0.0211 deg (PlacementsTest, limit 0.02): not
// understood, so it is not used there.
//
// Where the code is: extract_steps.h names the steps and the file of each (noise, row pass, candidates,
// point, smoothing); kernels.h the instruction-set paths of their inner loops, each in its own file
// (portable, SSE2, and SSSE3 and AVX2 dispatched at run time), OpenCV's dispatched kernels as the model.
// This file holds the public entry points and the row loop that calls the steps.
#include "rotoscan/laser/extract.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "extract_steps.h"
#include "kernels.h"
#include "rotoscan/core/check.h"
#include "rotoscan/geometry/image_file.h"

namespace rotoscan::laser {

const char* EstimatorName(Estimator estimator) {
  switch (estimator) {
    case Estimator::kCenterOfMass: return "com";
    case Estimator::kParabolic: return "parabolic";
    case Estimator::kGaussian: return "gaussian";
    case Estimator::kZeroCrossing: return "zero-crossing";
  }
  return "unknown";
}

Result<Estimator> ParseEstimator(const std::string& name) {
  for (Estimator e :
       {Estimator::kCenterOfMass, Estimator::kParabolic, Estimator::kGaussian, Estimator::kZeroCrossing}) {
    if (name == EstimatorName(e)) return e;
  }
  return InvalidArgumentError("estimator '" + name + "': expected com, parabolic, gaussian or zero-crossing");
}

Result<Channel> ParseChannel(const std::string& name) {
  if (name == "red") return Channel::kRed;
  if (name == "green") return Channel::kGreen;
  if (name == "blue") return Channel::kBlue;
  return InvalidArgumentError("channel '" + name + "': expected red, green or blue");
}

Result<PixelLayout> ParsePixelLayout(const std::string& name) {
  static const std::pair<const char*, PixelLayout> kNames[] = {{"auto", PixelLayout::kAuto},
                                                               {"gray", PixelLayout::kGray},
                                                               {"bgr", PixelLayout::kBgr},
                                                               {"rgb", PixelLayout::kRgb},
                                                               {"bayer-rggb", PixelLayout::kBayerRggb},
                                                               {"bayer-grbg", PixelLayout::kBayerGrbg},
                                                               {"bayer-bggr", PixelLayout::kBayerBggr},
                                                               {"bayer-gbrg", PixelLayout::kBayerGbrg}};
  for (const auto& [n, layout] : kNames) {
    if (name == n) return layout;
  }
  return InvalidArgumentError("pixel layout '" + name +
                              "': expected auto, gray, bgr, rgb or bayer-rggb/grbg/bggr/gbrg");
}

Status ExtractOptions::Check() const {
  auto bad = [](const std::string& field, const std::string& why) {
    return InvalidArgumentError("extract options: " + field + " " + why);
  };
  if (!(min_contrast_dn >= 1.0 && min_contrast_dn <= 255.0))
    return bad("min_contrast_dn", "must be in [1, 255]");
  if (!(min_contrast_lit_dn >= 1.0 && min_contrast_lit_dn <= 255.0))
    return bad("min_contrast_lit_dn", "must be in [1, 255]");
  if (!(min_snr >= 0.0 && std::isfinite(min_snr))) return bad("min_snr", "must be >= 0");
  if (!std::isfinite(noise_dn)) return bad("noise_dn", "must be finite");
  if (!(min_width_px >= 0.0 && max_width_px > min_width_px && std::isfinite(max_width_px))) {
    return bad("min_width_px/max_width_px", "must satisfy 0 <= min < max");
  }
  if (!(multiple_peak_ratio > 0.0 && multiple_peak_ratio <= 1.0))
    return bad("multiple_peak_ratio", "must be in (0, 1]");
  if (off_saturation_dn < 1 || off_saturation_dn > 256)
    return bad("off_saturation_dn", "must be in [1, 256]");
  if (smooth_half_rows < 0 || smooth_half_rows > 64) return bad("smooth_half_rows", "must be in [0, 64]");
  if (smooth_order < 0 || smooth_order > 2) return bad("smooth_order", "must be 0, 1 or 2");
  if (!(smooth_max_jump_px > 0.0 && std::isfinite(smooth_max_jump_px)))
    return bad("smooth_max_jump_px", "must be > 0");
  if (!(smooth_outlier_px > 0.0 && std::isfinite(smooth_outlier_px)))
    return bad("smooth_outlier_px", "must be > 0");
  if (!(smooth_steep_step_px >= 0.0 && std::isfinite(smooth_steep_step_px)))
    return bad("smooth_steep_step_px", "must be >= 0");
  return Status::Ok();
}

LineExtractor::LineExtractor(const ExtractOptions& options) : options_(options) {
  const Status status = options_.Check();
  ROTOSCAN_CHECK(status.ok()) << status.ToString();
}

Status LineExtractor::Extract(const cv::Mat& on, const cv::Mat& off, Line* line) {
  ROTOSCAN_CHECK(line != nullptr);
  if (on.empty() || off.empty()) return InvalidArgumentError("empty image (laser-on or laser-off frame)");
  if (on.size() != off.size()) {
    return InvalidArgumentError("image sizes differ: laser-on " + std::to_string(on.cols) + "x" +
                                std::to_string(on.rows) + ", laser-off " + std::to_string(off.cols) + "x" +
                                std::to_string(off.rows));
  }
  if (on.type() != off.type()) return InvalidArgumentError("laser-on and laser-off images differ in type");
  if (on.depth() != CV_8U) return InvalidArgumentError("only 8-bit images are supported");
  const int channels = on.channels();
  PixelLayout layout = options_.layout;
  if (layout == PixelLayout::kAuto) {
    if (channels == 1) {
      layout = PixelLayout::kGray;
    } else if (channels == 3 || channels == 4) {
      layout = PixelLayout::kBgr;
    } else {
      return InvalidArgumentError("unsupported channel count " + std::to_string(channels));
    }
  }
  const bool bayer = layout == PixelLayout::kBayerRggb || layout == PixelLayout::kBayerGrbg ||
                     layout == PixelLayout::kBayerBggr || layout == PixelLayout::kBayerGbrg;
  if ((layout == PixelLayout::kGray || bayer) && channels != 1) {
    return InvalidArgumentError("a gray or Bayer layout needs single-channel images, got " +
                                std::to_string(channels) + " channels");
  }
  if ((layout == PixelLayout::kBgr || layout == PixelLayout::kRgb) && channels != 3 && channels != 4) {
    return InvalidArgumentError("a color layout needs 3 or 4 channels, got " + std::to_string(channels));
  }
  if (layout == PixelLayout::kGray) return ExtractFromChannel(on, off, line);

  const cv::Mat* on_color = &on;
  const cv::Mat* off_color = &off;
  if (bayer) {
    // OpenCV names Bayer patterns by the second row's start; RGGB raw is COLOR_BayerBG2BGR.
    int code = cv::COLOR_BayerBG2BGR;
    if (layout == PixelLayout::kBayerGrbg) code = cv::COLOR_BayerGB2BGR;
    if (layout == PixelLayout::kBayerBggr) code = cv::COLOR_BayerRG2BGR;
    if (layout == PixelLayout::kBayerGbrg) code = cv::COLOR_BayerGR2BGR;
    cv::cvtColor(on, on_bgr_, code);
    cv::cvtColor(off, off_bgr_, code);
    on_color = &on_bgr_;
    off_color = &off_bgr_;
    layout = PixelLayout::kBgr;
  }
  int index = 2;  // red in BGR
  if (options_.channel == Channel::kGreen) index = 1;
  if (options_.channel == Channel::kBlue) index = 0;
  if (layout == PixelLayout::kRgb) index = 2 - index;
  return ExtractRows(*on_color, *off_color, index, line);
}

Status LineExtractor::ExtractFromChannel(const cv::Mat& on_channel, const cv::Mat& off_channel, Line* line) {
  ROTOSCAN_CHECK(line != nullptr);
  if (on_channel.empty() || on_channel.size() != off_channel.size() || on_channel.type() != CV_8UC1 ||
      off_channel.type() != CV_8UC1) {
    return InvalidArgumentError("laser channel images must be non-empty, single-channel 8-bit, same size");
  }
  return ExtractRows(on_channel, off_channel, 0, line);
}

// Color input (3 or 4 interleaved channels): on x86 with SSSE3 each row's laser channel is pulled out
// with byte shuffles into a row buffer (ChannelRowSsse3: 16 pixels from 3 or 4 loads, 3 or 4 shuffles),
// so the frames are read once and nothing else is written. Elsewhere the frames are read in bands of
// kBandRows rows that OpenCV's vectorised cv::split deinterleaves into small buffers in the L2 cache
// (cv::extractChannel goes through the generic, scalar mixChannels: 3x slower). laser_bench
// BM_ExtractBgr: split bands 673 µs, shuffles see README.
constexpr int kBandRows = 32;
// The row pass asks for the row this many rows ahead: the hardware prefetcher alone left the per-row
// work waiting on memory (laser_bench, smoothed, measured on a busy machine: no prefetch ~220 µs per frame,
// 2-4 rows ahead ~170 µs, 1 or 8 rows ~180-190 µs).
constexpr int kPrefetchRows = 3;

namespace {
std::vector<detail::PointTerms>& PointTermsScratch() {
  thread_local std::vector<detail::PointTerms> terms;
  return terms;
}
}  // namespace

Status LineExtractor::ExtractRows(const cv::Mat& on, const cv::Mat& off, int channel, Line* line) {
  using detail::kPad;
  const ExtractOptions& o = options_;
  const int rows = on.rows;
  const int cols = on.cols;
  const int channels = on.channels();
  bool shuffled = false;  // color rows through ChannelRowSsse3
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  shuffled = channels > 1 && detail::HaveSsse3();
  if (shuffled) {
    on_row_.resize(static_cast<size_t>(cols));
    off_row_.resize(static_cast<size_t>(cols));
  }
#endif
  const bool banded = channels > 1 && !shuffled;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  const bool avx2 = detail::HaveAvx2();  // the row pass 32 pixels at a time
#else
  const bool avx2 = false;
#endif
  line->points.clear();
  line->stats = LineStats{};
  LineStats& stats = line->stats;
  stats.rows = rows;
  stats.noise_on_lit = true;
  stats.noise_dn = o.noise_dn > 0 ? o.noise_dn : detail::EstimateNoise(on, off, channel, &stats.noise_on_lit);
  const double floor_dn = stats.noise_on_lit ? o.min_contrast_lit_dn : o.min_contrast_dn;
  const double threshold_real = std::max(floor_dn, o.min_snr * stats.noise_dn);
  const int threshold = static_cast<int>(std::ceil(std::min(threshold_real, 255.0)));
  stats.threshold_dn = threshold;
  // The row's difference with kPad zero bytes on either side, so that the extent scans below can read
  // whole vectors at the borders and stop there.
  diff_.assign(static_cast<size_t>(cols) + 2 * kPad, 0);
  block_starts_.resize(static_cast<size_t>(cols) / 16 + 3);
  block_masks_.resize(static_cast<size_t>(cols) / 16 + 3);
  uint8_t* d = diff_.data() + kPad;

  // The quality's factors (step 5), per frame.
  detail::FrameScale frame;
  frame.noise_dn = stats.noise_dn;
  frame.threshold = threshold;
  frame.quality_per_snr = stats.noise_dn > 0 ? 1.0 / (stats.noise_dn * std::max(1.0, 4 * o.min_snr)) : 0.0;
  frame.quality_per_contrast = 1.0 / std::max(1.0, 2.0 * threshold);
  frame.narrow_width = 1.5 * o.min_width_px;
  frame.wide_width = o.max_width_px / 1.5;

  // Both frames' row kPrefetchRows ahead of row r, read from memory while row r is worked on.
  auto prefetch_ahead = [&](int r) {
    if (r + kPrefetchRows >= rows) return;
    const char* pa = reinterpret_cast<const char*>(on.ptr<uint8_t>(r + kPrefetchRows));
    const char* pb = reinterpret_cast<const char*>(off.ptr<uint8_t>(r + kPrefetchRows));
    for (int k = 0; k < cols * channels; k += 64) {
      __builtin_prefetch(pa + k);
      __builtin_prefetch(pb + k);
    }
  };

  const bool centre_of_mass = o.estimator == Estimator::kCenterOfMass;
  std::array<detail::Candidate, 32> candidates;
  // Step 5's terms per point, scored after the loop: per thread (one extractor per thread), so that the
  // public class keeps its layout; allocation-free from the second frame on. Sized for every row up front
  // (the thread-local is looked up once, not per row).
  std::vector<detail::PointTerms>& terms = PointTermsScratch();
  if (terms.size() < static_cast<size_t>(rows)) terms.resize(static_cast<size_t>(rows));
  double previous_column = -1.0;
  int previous_row = -10;
  detail::FrameRows frame_rows;  // step 5's albedo division at a line's top end
  frame_rows.on = &on;
  frame_rows.off = &off;
  frame_rows.channel = channel;
  for (int r = 0; r < rows; ++r) {
    const uint8_t* a;
    const uint8_t* b;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
    if (shuffled) {
      prefetch_ahead(r);
      detail::ChannelRowSsse3(on.ptr<uint8_t>(r), cols, channels, channel, on_row_.data());
      detail::ChannelRowSsse3(off.ptr<uint8_t>(r), cols, channels, channel, off_row_.data());
      a = on_row_.data();
      b = off_row_.data();
    } else
#endif
    if (banded) {
      if (r % kBandRows == 0) {
        const cv::Range band(r, std::min(rows, r + kBandRows));
        cv::split(on.rowRange(band), on_planes_);
        cv::split(off.rowRange(band), off_planes_);
      }
      a = on_planes_[static_cast<size_t>(channel)].ptr<uint8_t>(r % kBandRows);
      b = off_planes_[static_cast<size_t>(channel)].ptr<uint8_t>(r % kBandRows);
    } else {
      a = on.ptr<uint8_t>(r);
      b = off.ptr<uint8_t>(r);
      prefetch_ahead(r);
    }
    // Steps 1-2: the row's difference, and its pixel groups that reach the threshold (row_pass.cc).
    const int block_count = detail::RowPass(a, b, cols, threshold, avx2, d, block_starts_.data(), block_masks_.data());
    if (block_count == 0) {  // no pixel reaches the threshold
      ++stats.low_contrast;
      continue;
    }
    // Steps 3-4: the candidates, and the one the row keeps (candidates.cc).
    const int count = detail::FindCandidates(a, b, d, cols, threshold, o.off_saturation_dn, centre_of_mass,
                                             block_starts_.data(), block_masks_.data(), block_count,
                                             candidates.data(), static_cast<int>(candidates.size()));
    uint8_t flags = 0;
    const bool continuous = previous_column >= 0 && r - previous_row <= 2;
    const int best = detail::ChooseCandidate(candidates.data(), count, o, previous_column, continuous, &stats, &flags);
    if (best < 0) continue;
    // Step 5: the point (point.cc); its uncertainty and quality after the loop.
    double column;
    const size_t index = line->points.size();
    LinePoint& p = line->points.emplace_back();
    if (!detail::MeasurePoint(candidates[static_cast<size_t>(best)], a, b, d, cols, r, o, flags,
                              stats.noise_on_lit, &p, &terms[index], &column, &frame_rows)) {
      line->points.pop_back();
      ++stats.bad_width;
      continue;
    }
    ++stats.found;
    if (p.flags & kFlagMultiplePeaks) ++stats.multiple_peaks;
    previous_column = column;
    previous_row = r;
  }
  detail::ScorePoints(terms.data(), frame, &line->points);
  detail::ScoreLineEnds(o.smooth_max_jump_px, rows, &line->points);
  stats.glints = detail::FlagGlints(terms.data(), rows, &line->points);
  // Rows missing inside a stretch, found along its curve (gaps.cc), on the same frames as steep.cc. Its end
  // part (extend_line_ends) runs after the smoothing, below.
  if (o.fill_gaps && stats.noise_on_lit) {
    stats.gap_filled = detail::FillLineGaps(on, off, channel, stats.noise_dn, &line->points);
    stats.found += stats.gap_filled;
  }
  // A steep line measured across itself (steep.cc), on frames whose noise was measured on lit pixels:
  // on the machine-vision preset's dark, clean frames the row's own centre is better (extract_steps.h).
  if (o.steep_across && stats.noise_on_lit) detail::RecentreSteepLines(on, off, channel, threshold, &line->points);
  // A steep stretch's end rows, whose row profile the line's end cuts, measured across the line (ends.cc).
  if (o.line_ends && stats.noise_on_lit) detail::RecentreLineEnds(on, off, channel, threshold, &line->points);
  // The faint line's rows past its corner with a bright one, whose light the bright line's blur fills (ends.cc).
  std::vector<std::pair<int, float>> junction_ghosts;
  if (o.junction_rows && stats.noise_on_lit)
    detail::RecentreJunctionRows(on, off, channel, threshold, stats.noise_dn, &line->points,
                                 o.junction_light ? &junction_ghosts : nullptr);
  if (o.smooth_half_rows > 0) {
    std::vector<LinePoint>& points = line->points;
    const size_t n = points.size();
    row_columns_.resize(n);
    for (size_t i = 0; i < n; ++i) row_columns_[i] = points[i].column;
    SmoothAlongLine(&points, o.smooth_half_rows, o.smooth_order, o.smooth_max_jump_px, o.smooth_outlier_px,
                    &raw_columns_, stats.noise_on_lit ? o.smooth_steep_step_px : 0.0, o.smooth_curvature && stats.noise_on_lit);
    detail::LimitSmoothing(row_columns_, &points);
  }
  // A stretch's fading tail past a rim, put on the flat top's faint line through the corner (ends.cc), after
  // the smoothing: nothing moves its rows afterwards (the smoothing reads a 9 px per row line as jumps).
  // Its ends at the slope's steep bound go to the end step's matched filter (gaps.cc, tails alone).
  if (o.rim_rows && stats.noise_on_lit) {
    std::vector<std::pair<int, int>> at_bound;
    detail::RecentreRimRows(on, off, channel, stats.noise_dn, &line->points,
                            o.rim_rows_at_bound ? &at_bound : nullptr, o.rim_rows_albedo);
    if (!at_bound.empty())
      detail::ExtendLineEnds(on, off, channel, stats.noise_dn, &line->points, detail::kEndMinZ,
                             /*fill=*/false, /*tails=*/true, &at_bound);
  }
  // The junction step's rows whose point was another light (ends.cc), on the faint line's fit: after the
  // smoothing, so that their neighbours are smoothed as before (moved before it, the stretch ran on through
  // the corner and its rows there moved over 1 px along the row: textured f/4, 8 steps, 2.167 -> 2.191 %).
  if (!junction_ghosts.empty()) detail::ApplyJunctionGhostRows(junction_ghosts, &line->points);
  // A stretch's faint continuation past its end (gaps.cc, ExtendLineEnds), after the smoothing (thirteenth
  // session): its lines pass through the stretch's smoothed points rather than their own noisy estimates, and
  // its rows, placed by a matched filter over the whole run, are not moved by the steep step, the line-end
  // step or the smoothing, which read them as rows of their own (textured webcam set, 8 steps, f/4 / f/2.4,
  // over 1 px across with the end part 1.664 -> 1.533 % / 1.964 -> 1.820 %; gaps.cc).
  if (o.fill_gaps && o.extend_line_ends && stats.noise_on_lit) {
    const int ended = detail::ExtendLineEnds(on, off, channel, stats.noise_dn, &line->points);
    stats.gap_filled += ended;
    stats.found += ended;
  }
  // Where the line jumps (the table's line meeting the object's): the uncertainty after the centres are final.
  detail::WidenAtLineBreaks(&line->points);
  for (LinePoint& p : line->points) p.flags &= static_cast<uint8_t>(~detail::kFlagLopsided);
  return Status::Ok();
}

Result<cv::Mat> ReadImage8(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    if (std::filesystem::exists(path, ec)) return InvalidArgumentError(path.string() + " is not a regular file");
    return NotFoundError(path.string() + " does not exist");
  }
  // Decoder messages (libpng's) come back in the status, never on stderr.
  ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat image, geometry::ReadImageFile(path));
  if (image.depth() != CV_8U)
    return InvalidArgumentError(path.string() + " is not 8-bit (only 8-bit is read)");
  return image;
}

Result<Line> ExtractLine(const cv::Mat& on, const cv::Mat& off, const ExtractOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  LineExtractor extractor(options);
  Line line;
  ROTOSCAN_RETURN_IF_ERROR(extractor.Extract(on, off, &line));
  return line;
}

}  // namespace rotoscan::laser
