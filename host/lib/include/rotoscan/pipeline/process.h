// Processing a scan end to end (paper §3): per table step, the line of each laser by differential imaging
// against the step's laser-off frame, triangulation on that laser's plane, the table transform with the
// full 3D axis (Rig::WorldFromCamAtAngle; the paper's eq. 7 is the case of an axis along z), the color of
// each point from the step's natural frame at the same sub-pixel position (same camera: no
// correspondence problem, the paper's point), then normals, the two lasers' disagreement and their merge.
//
// Threads: steps are independent; `threads` workers (default: all cores) take steps from a shared counter,
// each with its own extractor and buffers, and write into per-step slots, so the output order (step, laser,
// row) does not depend on scheduling.
//
// Scans without laser-off frames: some rigs capture the laser-on frames in the dark only (FabScanPi does by
// default). When the source has no laser-off frame at all, every step's background is
// ProcessOptions::dark_frame if one is given (the lasers off, captured once), else zero, and the summary
// carries one warning (ambient light in the laser frames is then taken for laser). A source that has
// laser-off frames but lacks one at some step skips that step (frames were lost), unless a dark frame is
// given.
//
// Shared off frame (bundle::BundleHeader::shared_off_frame, `rotoscan scan --shared-off`): a step has no
// natural frame; its laser-off frame, taken at the laser exposure, is both the background and the color
// frame, so Load() and LoadNatural() hand it out as `natural` too, as it is (not brightened: colors are
// darker than a 4-frame scan's by the exposure ratio, and a brightening factor would saturate wherever
// the natural light is not the laser frames' ambient; the color pass and the evaluation fit one gain).
// No flag is needed: the bundle says so.
//
// Bad input: a frame whose size differs from the calibration is an error (kInvalidArgument naming the
// file), as is a dark frame of another size or type than the laser frames; a step missing its laser-off
// frame (see above) or both laser frames, or a frame that does not decode, is a counted skip
// (ProcessSummary::skipped_steps, reasons in `warnings`); no step at all is an error.
#pragma once

#include <array>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/cloud/merge.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/laser/extract.h"
#include "rotoscan/pipeline/color.h"

namespace rotoscan::pipeline {

// The frames of one table step as stored (8- or 16-bit, gray, Bayer raw or BGR); any may be empty.
struct StepFrames {
  int step = 0;
  double table_angle_rad = 0.0;
  std::array<cv::Mat, 2> laser;  // indexed by geometry::LaserId
  cv::Mat off;
  cv::Mat natural;
  std::string name;  // for messages, e.g. "step 12"
  // Puts `image` where the step's frame of that laser state goes (the live sources of a scan use it).
  void Set(bundle::LaserState state, cv::Mat image) {
    switch (state) {
      case bundle::LaserState::kLeft: laser[0] = std::move(image); break;
      case bundle::LaserState::kRight: laser[1] = std::move(image); break;
      case bundle::LaserState::kOff: off = std::move(image); break;
      case bundle::LaserState::kNatural: natural = std::move(image); break;
    }
  }
};

// Where the frames come from: a bundle on disk, or memory in tests. Load() is called from several threads.
class StepSource {
 public:
  virtual ~StepSource() = default;
  virtual int StepCount() const = 0;
  // kNotFound / kCorruptData for a missing or undecodable frame (the step is skipped and counted).
  virtual Result<StepFrames> Load(int index) const = 0;
  virtual bool bayer() const { return false; }
  virtual int bit_depth() const { return 8; }
  // False when no step has a laser-off frame (a capture in the dark; see the file comment).
  virtual bool has_off_frames() const { return true; }
  // The natural frame of step `index` alone (empty when the step has none) and the step's table angle
  // (color.h reads many); by default through Load().
  virtual Result<cv::Mat> LoadNatural(int index, double* table_angle_rad) const;
};

// Steps of a scan bundle (bundle/bundle.h), by step index.
class BundleStepSource : public StepSource {
 public:
  explicit BundleStepSource(bundle::Bundle bundle);
  int StepCount() const override { return static_cast<int>(steps_.size()); }
  Result<StepFrames> Load(int index) const override;
  Result<cv::Mat> LoadNatural(int index, double* table_angle_rad) const override;
  bool bayer() const override { return bundle_.header.camera.bayer; }
  int bit_depth() const override { return bundle_.header.camera.bit_depth; }
  bool has_off_frames() const override { return has_off_frames_; }

 private:
  bundle::Bundle bundle_;
  std::vector<int> steps_;  // distinct step indices present, ascending
  bool has_off_frames_ = false;
};

struct ProcessOptions {
  laser::ExtractOptions extract;  // layout kAuto is replaced by the source's (Bayer or not)
  int threads = 0;                // 0: std::thread::hardware_concurrency()
  bool use_laser[2] = {true, true};
  float min_quality = 0.0f;  // drop points below this quality
  bool estimate_normals = true;
  bool merge = true;  // merge the two lasers without duplicate layers (cloud/merge.h)
  cloud::MergeOptions merge_options;
  double max_neighbor_mm = 3.0;  // normals: neighbours further than this are a different surface
  // Background for steps without a laser-off frame (see the file comment): stored like the frames (same
  // size, type and bit depth); empty: zero when the source has no laser-off frame at all.
  cv::Mat dark_frame;
  // ProcessBundle: each point's color from many natural frames, the lamp's shading divided out (color.h);
  // color.enabled = false keeps the color of the point's own step.
  ColorOptions color;

  Status Check() const;
};

struct ProcessSummary {
  int steps = 0;
  int processed_steps = 0;
  int skipped_steps = 0;
  int background_steps = 0;  // processed without their own laser-off frame (dark frame or zero)
  std::array<size_t, 2> points_per_laser{};  // after extraction and triangulation
  size_t points_with_normal = 0;
  size_t points_out = 0;
  cloud::MergeReport merge;           // disagreement of the lasers and the merge counts
  laser::LineStats line_totals;       // summed over all laser frames (rows, found, rejections)
  std::vector<std::string> warnings;  // skipped steps and why (at most 20, then a count)
  ColorSummary color;                 // ProcessBundle's color pass
  double seconds = 0.0;
};

struct ProcessResult {
  cloud::PointCloud cloud;
  ProcessSummary summary;
};

// Processes every step of `source` with `rig`. kCancelled if the progress asks to stop.
Result<ProcessResult> ProcessSteps(const geometry::Rig& rig, const StepSource& source,
                                   const ProcessOptions& options, Progress* progress = nullptr);

// Reads the bundle, checks it against the rig (image size) and processes it, then colors the cloud from
// the natural frames (options.color, color.h).
Result<ProcessResult> ProcessBundle(const std::filesystem::path& bundle_dir, const geometry::Rig& rig,
                                    const ProcessOptions& options, Progress* progress = nullptr);

// One line per figure, for the CLI and logs.
std::string FormatSummary(const ProcessSummary& summary);

// Converts a stored frame to 8 bits (16-bit frames of `bit_depth` bits are scaled to 0..255).
cv::Mat To8Bit(const cv::Mat& frame, int bit_depth);

// A natural frame of `source` in 8 bits, demosaiced when the source is Bayer raw; empty when `natural_frame` is.
cv::Mat NaturalImageOf(const StepSource& source, const cv::Mat& natural_frame);

// Bilinear sample of an 8-bit BGR (or gray) image at (column, row) as RGB; clamped at the border.
std::array<uint8_t, 3> SampleRgb(const cv::Mat& image, double column, double row);

}  // namespace rotoscan::pipeline
