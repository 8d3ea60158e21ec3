// Laser line extraction by differential imaging (paper §3.1): per image row, the sub-pixel column of the
// laser line in the difference (laser-on minus laser-off) of the channel the laser lives in.
//
// Pixels are (column, row) with (0, 0) the centre of the top-left pixel, as in geometry/camera.h: a
// column of 10.0 is the centre of pixel 10.
//
// What real frames look like (DESIGN.md): lines 7-16 px wide at half maximum, the laser-on channel
// saturated in most rows (a flat-topped plateau in the difference), background noise of ~1.4 DN. None of
// the estimators below assumes a narrow line; see extract.cc for how each handles a plateau and why the
// default is what it is.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "rotoscan/core/status.h"

namespace rotoscan::laser {

// How the sub-pixel centre is computed from the difference profile of one row.
enum class Estimator {
  kCenterOfMass,  // centre of mass of (d - half maximum) over the run above half maximum
  kParabolic,     // 3-point parabola through the peak (a plateau collapsed to its middle)
  kGaussian,      // 3-point Gaussian (parabola of log d), same plateau handling
  kZeroCrossing,  // zero of the FIR derivative d[i+k] - d[i-k], k = half the line width
};
const char* EstimatorName(Estimator estimator);
Result<Estimator> ParseEstimator(const std::string& name);  // "com", "parabolic", "gaussian", "zero-crossing"

// Which channel carries the laser.
enum class Channel { kRed, kGreen, kBlue };
Result<Channel> ParseChannel(const std::string& name);  // "red", "green", "blue"

// How the bytes of an 8-bit image are laid out. kAuto: 1 channel = gray, 3 channels = BGR (OpenCV's
// imread order), 4 channels = BGRA. Bayer layouts are single-channel raw frames, demosaiced before use.
enum class PixelLayout { kAuto, kGray, kBgr, kRgb, kBayerRggb, kBayerGrbg, kBayerBggr, kBayerGbrg };
Result<PixelLayout> ParsePixelLayout(
    const std::string& name);  // "auto", "gray", "bgr", "rgb", "bayer-rggb"...

// Flags of one extracted point (bit set).
enum LinePointFlag : uint8_t {
  kFlagSaturated = 1,      // the laser-on channel is saturated at the peak (plateau)
  kFlagMultiplePeaks = 2,  // another plausible peak was in the row; the most plausible one was kept
  kFlagClipped = 4,        // the line touches the image border
  kFlagNotched = 8,        // saturated laser-on pixels inside the line had a low difference (a bright
                           // background under a saturated line): counted as laser (extract.cc)
  kFlagStrongerRejected = 16,  // a much stronger candidate in the row was rejected as too narrow (a hot
                               // pixel or a glint's core): this weaker, plausible one was kept
  kFlagAlbedoEdge = 32,  // the albedo changes inside the line (the laser-off frame shows an edge): the
                         // centre is that of the difference divided by the albedo (extract.cc)
  kFlagGlint = 64,  // a glint of the laser on a glossy surface: a compact stretch of rows where the line is
                    // overexposed far more than above and below it (extract.cc, "Glints"); its centre
                    // may be pulled by the glint's lobe, so its quality is lower and its uncertainty larger
};

struct LinePoint {
  int32_t row = 0;
  float column = 0;   // sub-pixel column of the line centre
  float peak = 0;     // peak height of the difference, DN
  float width = 0;    // full width at half maximum, px
  float quality = 0;  // 0 (barely accepted) .. 1 (strong, clean, plausible width); falls as the
                      // uncertainty grows, so the lowest qualities have the largest errors
  float uncertainty_px = 0;  // about two standard errors of `column` (extract.cc, "Uncertainty")
  uint8_t flags = 0;  // LinePointFlag bits
};

// Why rows gave no point, and what the frame looked like.
struct LineStats {
  int rows = 0;
  int found = 0;
  int low_contrast = 0;     // peak below the detection threshold (no laser in this row)
  int bad_width = 0;        // every candidate too narrow (glint, hot pixel) or too wide (ambient blob)
  int off_saturated = 0;    // the laser-off frame is saturated under the peak: a specular highlight
  int multiple_peaks = 0;   // rows flagged kFlagMultiplePeaks (also counted in found)
  int glints = 0;           // points flagged kFlagGlint (also counted in found)
  int stronger_rejected = 0;  // rows without a point because a much stronger candidate was rejected
                              // (too wide, or hidden by a saturated laser-off frame): see extract.cc
  double noise_dn = 0;      // background noise of the difference used for the threshold, DN (sigma)
  bool noise_on_lit = false;  // noise_dn was measured on lit pixels (or given): the lower floor applies
  double threshold_dn = 0;  // detection threshold used, DN
  int gap_filled = 0;       // points added by ExtractOptions::fill_gaps (also in found; the row pass's
                            // reason for their rows stays counted above)
};

struct Line {
  std::vector<LinePoint> points;  // ordered by row, at most one per row
  LineStats stats;
};

struct ExtractOptions {
  Estimator estimator = Estimator::kCenterOfMass;  // chosen by measurement, see extract.cc
  Channel channel = Channel::kRed;
  PixelLayout layout = PixelLayout::kAuto;
  // A peak must exceed max(floor, min_snr * noise) in the difference, the noise estimated per frame on
  // its lit pixels (extract.cc, "Detection threshold": 6 sigma is where false detections on laser-off
  // rows stop). The floor is min_contrast_lit_dn when the noise was measured there (or given in
  // noise_dn), min_contrast_dn when the frame had too few lit pixels and the noise came from dark ones,
  // which say nothing of the noise where a line can be.
  double min_contrast_dn = 12.0;
  double min_contrast_lit_dn = 6.0;
  double min_snr = 6.0;
  // Noise sigma of the difference, DN; <= 0: estimated per frame from a sparse sample of pixels.
  double noise_dn = 0.0;
  // Width limits (full width at half maximum, px): narrower is a glint or a hot pixel, wider a blob of
  // ambient light or a smeared reflection.
  double min_width_px = 1.5;
  double max_width_px = 40.0;
  // A second candidate whose peak is at least this fraction of the best one flags the row.
  double multiple_peak_ratio = 0.5;
  // Pixels of the laser-off channel at or above this value hide the laser: such peaks are rejected.
  int off_saturation_dn = 250;
  // Smoothing of the sub-pixel centre along the line (extract.cc, "Along-line smoothing"): each centre is
  // replaced by a weighted local polynomial fit over the points within +-smooth_half_rows rows of the
  // same stretch of line. A stretch ends where a row is missing or the column jumps by more than
  // smooth_max_jump_px between neighbouring rows (a depth edge is never smoothed across); neighbours
  // further than smooth_outlier_px from the first fit are dropped from the second. 0 rows: off.
  int smooth_half_rows = 12;
  int smooth_order = 1;  // of the local fit: 0 mean, 1 straight line, 2 parabola
  double smooth_max_jump_px = 1.5;
  double smooth_outlier_px = 0.5;
  // On frames whose noise was measured on lit pixels (LineStats::noise_on_lit: the webcam's), the
  // smoothing also joins rows whose column step exceeds smooth_max_jump_px but is within this of the
  // previous row's step (a steep line continuing its slope; extract.cc, "Along-line smoothing"). 0: off.
  double smooth_steep_step_px = 3.0;
  // The straight fit (smooth_order 1) less its bias on a curved line, from the curvature that the fit's
  // slopes show (extract.cc, "Along-line smoothing"; issue 15); only on frames whose noise was measured on
  // lit pixels (LineStats::noise_on_lit).
  bool smooth_curvature = true;
  // A steep line's centre (over kSteepSlope columns per row: the table top's line, a grazing surface)
  // measured across the line from the pixels of neighbouring rows, not along its row (steep.cc); only on
  // frames whose noise was measured on lit pixels (LineStats::noise_on_lit).
  bool steep_across = true;
  // The last rows of a steep stretch, whose row profile the line's end (a rim, a silhouette, a shadow) cuts
  // on one side, measured across the line with the direction of the stretch's interior (ends.cc); only on
  // frames whose noise was measured on lit pixels.
  bool line_ends = true;
  // Where a bright line (the object's) meets the table's faint steep line, the faint line's first rows past
  // the corner, whose light the bright line's blur fills, put on the faint line's straight fit from further
  // in (ends.cc, RecentreJunctionRows; issue 15); only on frames whose noise was measured on lit pixels.
  bool junction_rows = true;
  // With junction_rows: a row past that corner whose point lies further from the faint line's fit than the
  // step moves a row (another light there: the bright line's MJPEG ringing) put on the fit after the
  // smoothing, where the faint line's own light in the row shows it (ends.cc, extract_steps.h
  // kJunctionLightZ; issue 15).
  bool junction_light = true;
  // A stretch's last rows that fade past a rim (the blurred tail of a side's line where the truth is a flat
  // top's faint line, 2-12 columns per row), put on that line where its light summed along it over those
  // rows shows it (ends.cc, RecentreRimRows; issue 15); only on frames whose noise was measured on lit
  // pixels.
  bool rim_rows = true;
  // With rim_rows: the ends where that line's best slope is at the search's steep bound (the cap's blurred
  // light pulls it there) handed to the end step's matched filter, which also fits the line's offset
  // (gaps.cc, ExtendLineEnds' tails; extract_steps.h has the figures).
  bool rim_rows_at_bound = true;
  // With rim_rows: each tail row also judged against its own albedo (the laser-off frame) times the
  // interior's peak per albedo, so that a dark cell's real last rows are not taken for the tail (ends.cc,
  // extract_steps.h kRimAlbedoHalfPx; issue 15).
  bool rim_rows_albedo = true;
  // A line's first rows below its top end (a rim), where the laser-off row's blur mixes in the surface above
  // that the laser does not light, divided by the laser-off row of the line's body a row or two further
  // down (point.cc, AlbedoDivisorRow; issue 15); only on frames whose noise was measured on lit pixels.
  bool albedo_end_rows = true;
  // Rows missing inside a stretch of line (at most 16 between two found rows) looked for along the
  // stretch's curve with a matched filter over several rows, a threshold on their summed difference
  // (gaps.cc: the webcam table's weak, speckled line); only on frames whose noise was measured on lit
  // pixels. Counted in LineStats::gap_filled.
  bool fill_gaps = true;
  // With fill_gaps: a stretch's faint straight continuation past its end, found by the matched filter summed
  // over its run of rows (gaps.cc, ExtendLineEnds: the textured webcam object's flat top). Opt-in: on the
  // webcam sets it finds more rows (textured f/4 95.9 -> 97.4 %) but adds rows over 1 px (2.29 -> 2.65 %)
  // and ~17 % of a typical webcam frame's time (doc/issue15-log.md).
  bool extend_line_ends = false;

  // OK, or kInvalidArgument naming the bad field.
  Status Check() const;
};

// Extracts the line from a laser-on / laser-off pair (same size and type, 8-bit, 1, 3 or 4 channels).
// Reuses its buffers between calls; one extractor per thread.
class LineExtractor {
 public:
  explicit LineExtractor(const ExtractOptions& options = {});  // options must pass Check()

  const ExtractOptions& options() const { return options_; }

  // kInvalidArgument for empty images, different sizes or types, non-8-bit data, a layout that does not
  // fit the channel count.
  Status Extract(const cv::Mat& on, const cv::Mat& off, Line* line);

  // The lower level: the laser channel of both frames, as two CV_8UC1 images (continuous or not).
  Status ExtractFromChannel(const cv::Mat& on_channel, const cv::Mat& off_channel, Line* line);

 private:
  // The row loop, on single-channel frames (channel 0) or on one channel of color frames.
  Status ExtractRows(const cv::Mat& on, const cv::Mat& off, int channel, Line* line);

  ExtractOptions options_;
  std::vector<uint8_t> diff_;
  std::vector<int> block_starts_;      // the row's pixel groups holding a pixel >= threshold: start
  std::vector<uint64_t> block_masks_;  // and bits of d >= threshold (bit k: pixel start + k)
  std::vector<float> raw_columns_;     // along-line smoothing: the centres before smoothing
  std::vector<float> row_columns_;     // the rows' own centres, kept for the smoothing's limits
  std::vector<cv::Mat> on_planes_, off_planes_;  // a band of color frames, split into channels
  std::vector<uint8_t> on_row_, off_row_;        // or one row's laser channel of both (extract.cc)
  cv::Mat on_bgr_, off_bgr_;                     // demosaiced Bayer frames
};

// The along-line smoothing of ExtractOptions (smooth_*), applied in place to points ordered by row; exposed
// for tests. `scratch` is reused between calls. Points keep their row, peak, width, quality and flags.
// steep_step_change_px > 0 also joins rows whose column step is larger than max_jump_px but within
// steep_step_change_px of the previous step (a steep line continuing its slope; extract.cc).
// curvature (order 1 only) takes out the straight fit's bias on a curved line (ExtractOptions::
// smooth_curvature).
void SmoothAlongLine(std::vector<LinePoint>* points, int half_rows, int order, double max_jump_px,
                     double outlier_px, std::vector<float>* scratch, double steep_step_change_px = 0.0,
                     bool curvature = false);

// One-shot convenience.
Result<Line> ExtractLine(const cv::Mat& on, const cv::Mat& off, const ExtractOptions& options = {});

// The sub-pixel centre of the peak of one difference profile, given the run [first, last] (inclusive) of
// the candidate above half maximum and its peak value. Exposed for tests and benchmarks. Returns the
// column, or a negative value when the estimator fails (e.g. a flat profile).
double EstimateCentre(Estimator estimator, const uint8_t* diff, int size, int first, int last, int peak);

namespace internal {
// For tests: which x86 vector extensions the extractor may use when the CPU has them (both by default).
// Every path gives the same result; tests run each.
void AllowVectorExtensions(bool avx2, bool ssse3);
// Whether AVX2 paths run now (the CPU has AVX2 and AllowVectorExtensions allows it); for triangulate.cc.
bool UseAvx2();
}  // namespace internal

// Reads an 8-bit image file (PNG, JPEG, ... as OpenCV decodes it, channels as stored: BGR for color).
// kNotFound if missing, kCorruptData if it does not decode, kInvalidArgument if it is not 8-bit.
Result<cv::Mat> ReadImage8(const std::filesystem::path& path);

}  // namespace rotoscan::laser
