// The scan bundle (DESIGN.md "Files"): what the capture code and the virtual scanner write, and what
// calibration and processing read. A bundle is a directory:
//
//   bundle.json   the header and one record per frame (schema below)
//   frames/       lossless PNG images, 8- or 16-bit, gray or color (RGB on disk)
//   truth/        virtual scanner only: see bundle/truth.h
//
// bundle.json (format_version 1, or 2 for a bundle with a shared off frame). Angles are in degrees in the file (it is meant for people) and in
// radians in the structs below; lengths in mm, times in microseconds.
//
//   {
//     "format": "rotoscan-bundle", "format_version": 1,
//     "kind": "scan" | "calibration",
//     "created_by": "rotoscan simulate 0.1.0",
//     "camera": { "name": "...", "width": 1288, "height": 964, "channels": 3, "bit_depth": 8,
//                 "bayer": false, "pixel_size_um": 3.75,
//                 "K": [fx, 0, cx, 0, fy, cy, 0, 0, 1], "distortion": [k1, k2, p1, p2, k3],
//                 "laser_exposure_us": 2000, "natural_exposure_us": 20000, "gain_db": 0 },
//     "table_step_deg": 0.3,
//     "placement": 0,                                   (optional, default 0: the object's placement)
//     "shared_off_frame": true,                         (format_version 2 only; see BundleHeader)
//     "device": { "name": "...", "serial": "...", "firmware_version": "..." },
//     "target": { "kind": "none" | "calibration_object" | "checkerboard" | "table_checkerboard",
//                 "cols": 9, "rows": 6, "square_mm": 10, "description": "...",
//                 "origin_height_mm": 49 (optional) },                              (calibration only)
//     "frames": [ { "file": "frames/s0000_left.png", "step": 0, "table_angle_deg": 0.0,
//                   "laser": "left" | "right" | "off" | "natural", "trigger_seq": 0,
//                   "device_time_us": 0, "exposure_us": 2000, "pose": -1 }, ... ]
//   }
//
// The camera block is what the capture side knows (nominal intrinsics from the lens and sensor, or a
// previous calibration), not a calibration result: calibration estimates its own. Frames are ordered by
// (pose, step, laser: left, right, off, natural). `pose` is the calibration target pose index (-1 in scan
// bundles). In memory, frames are OpenCV matrices in OpenCV's channel order (BGR: red is channel 2).
//
// Reading is hardened: every count is bounded, every field is type-checked, errors name the field and the
// file, and a frame listed but missing on disk is kNotFound (ReadBundle with verify_frames) or reported
// when the frame is loaded. A bundle being written lives in "<dir>.partial" and is renamed to its final
// name only by BundleWriter::Finish(): a reader never sees half a bundle. An interrupted bundle (crash,
// Ctrl-C, unplugged device) stays in "<dir>.partial" with a journal of the frames safely written, and a
// writer created with `resume` continues it (DESIGN.md "Files").
#pragma once

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "rotoscan/core/status.h"
#include "rotoscan/geometry/camera.h"

namespace rotoscan::bundle {

inline constexpr int kFormatVersion = 1;  // what a bundle without version-2 fields is written as
// Version 2 adds "shared_off_frame". A writer uses it only for a bundle that has one (so that an older
// reader refuses such a bundle with a clear error instead of processing it without colors); readers
// accept 1..kMaxFormatVersion.
inline constexpr int kMaxFormatVersion = 2;
// Bounds on what a reader accepts (hardened parsing).
inline constexpr std::size_t kMaxFrames = 1'000'000;
inline constexpr int kMaxImageSide = 16384;

enum class BundleKind { kScan, kCalibration };
enum class LaserState { kLeft, kRight, kOff, kNatural };
enum class TargetKind { kNone, kCalibrationObject, kCheckerboard, kTableCheckerboard };

const char* BundleKindName(BundleKind kind);  // "scan", "calibration"
const char* LaserStateName(LaserState state);  // "left", "right", "off", "natural"
const char* TargetKindName(TargetKind kind);  // "none", "calibration_object", "checkerboard", ...
Result<BundleKind> ParseBundleKind(const std::string& name);
Result<LaserState> ParseLaserState(const std::string& name);
Result<TargetKind> ParseTargetKind(const std::string& name);

struct CameraInfo {
  std::string name;                 // e.g. "virtual machine-vision 1288x964", "Logitech C270"
  geometry::CameraModel model;      // nominal intrinsics (size, K, distortion)
  int channels = 3;                 // 1 (gray / raw Bayer) or 3 (color)
  int bit_depth = 8;                // 8, 10, 12 or 16 (stored in 8- or 16-bit PNG)
  bool bayer = false;               // frames are raw RGGB mosaics (channels == 1)
  double pixel_size_um = 0.0;       // 0: unknown
  double laser_exposure_us = 0.0;   // exposure of the left/right/off frames
  double natural_exposure_us = 0.0;  // exposure of the natural (color) frame
  double gain_db = 0.0;             // analogue gain, dB
};

struct DeviceInfo {
  std::string name;
  std::string serial;
  std::string firmware_version;
};

struct TargetInfo {
  TargetKind kind = TargetKind::kNone;
  int cols = 0;            // checkerboard inner corners across (0 when not a board)
  int rows = 0;            // checkerboard inner corners down
  double square_mm = 0.0;  // board square, or grid pitch of the calibration object
  std::string description;
  // Height of the target frame's origin above the table top, along the axis, for a target standing on
  // the table (table_checkerboard, calibration_object); NaN when unknown. Calibration needs it to put the
  // table frame's origin on the table top (DESIGN.md "Names and frames"): from the views alone the axis
  // is known, but not where along it the table top is. The virtual scanner writes the exact value; on a
  // real rig it is measured once (board margin below the first inner corner).
  double origin_height_mm = std::numeric_limits<double>::quiet_NaN();
};

struct FrameRecord {
  std::string file;               // relative to the bundle directory, e.g. "frames/s0012_left.png"
  int step = 0;                   // table step index (>= 0)
  double table_angle_rad = 0.0;   // table angle when the frame was exposed
  LaserState laser = LaserState::kOff;
  uint32_t trigger_seq = 0;       // hardware trigger sequence number
  uint64_t device_time_us = 0;    // device timestamp of the trigger edge
  double exposure_us = 0.0;       // exposure time of this frame
  int pose = -1;                  // calibration target pose index, -1 when not applicable
};

struct BundleHeader {
  int format_version = kFormatVersion;
  BundleKind kind = BundleKind::kScan;
  std::string created_by;
  CameraInfo camera;
  double table_step_rad = 0.0;  // commanded turn per table step (0: unknown)
  DeviceInfo device;
  TargetInfo target;  // calibration bundles
  // Which placement of the object on the table this scan is (0 the first; 1 e.g. the object on its side):
  // scans of several placements are aligned by `rotoscan merge` (pipeline/placements.h). In [0, 255].
  int placement = 0;
  // A shared off frame (`rotoscan scan --shared-off`, format_version 2): each step has left, right and off
  // frames but no natural frame, and its off frame, taken at the laser exposure, is also its color frame
  // (pipeline/process.h); camera.natural_exposure_us is then the laser exposure. 3 frames per step.
  bool shared_off_frame = false;
};

struct Bundle {
  std::filesystem::path directory;
  BundleHeader header;
  std::vector<FrameRecord> frames;
  bool has_truth = false;  // a truth/ directory is present

  std::filesystem::path FramePath(const FrameRecord& frame) const { return directory / frame.file; }
  // The index of the frame with this step, laser state and pose, or -1.
  int FindFrame(int step, LaserState laser, int pose = -1) const;
  // Number of distinct steps (max step + 1, 0 when empty).
  int StepCount() const;
  std::filesystem::path TruthDirectory() const { return directory / "truth"; }
};

struct ReadOptions {
  bool verify_frames = true;  // check that every listed frame file exists (kNotFound otherwise)
};

// Reads bundle.json of the bundle in `directory`. kNotFound when the directory or bundle.json is missing,
// kCorruptData/kInvalidArgument naming the field when the content is wrong.
Result<Bundle> ReadBundle(const std::filesystem::path& directory, const ReadOptions& options = {});

// Loads a frame as stored (8U or 16U, 1 or 3 channels in BGR order). kNotFound if the file is missing,
// kCorruptData if it does not decode or its size/channels disagree with the header.
Result<cv::Mat> ReadFrame(const Bundle& bundle, const FrameRecord& frame);
Result<cv::Mat> ReadFrame(const Bundle& bundle, std::size_t index);

// Parses/serialises bundle.json content (used by the reader and writer; exposed for tests and tools).
Result<Bundle> ParseBundleJson(const std::string& json_text, const std::string& source_name);
std::string BundleJson(const BundleHeader& header, const std::vector<FrameRecord>& frames);

// The conventional frame file name: "frames/s0012_left.png", or "frames/p03_s0012_left.png" with a pose.
std::string FrameFileName(int step, LaserState laser, int pose = -1);

// Writes a bundle: frames are written as they come (from any thread), bundle.json at Finish(), and the
// directory appears under its final name only when Finish() succeeds. Destroyed without Finish(), the
// writer keeps its partial directory if it holds frames (so that the work can be resumed) and removes it
// otherwise.
class BundleWriter {
 public:
  struct Options {
    bool overwrite = false;  // replace an existing bundle at the final path, or an interrupted one
    bool resume = false;     // continue an interrupted bundle (same header) instead of refusing it
  };

  // Creates "<directory>.partial" with frames/ (and truth/), or with `resume` reopens an interrupted one.
  // kInvalidArgument if the header is invalid, kIoError if the directory cannot be created,
  // kFailedPrecondition if `directory` exists and overwrite is off, if an interrupted bundle is there and
  // neither resume nor overwrite is set, if it was started with another header, or if another process is
  // writing it. kCorruptData if its journal is damaged.
  // `run_hash`: what produced the frames beyond the header (scene, seed, options), recorded in the partial
  // bundle; resuming with another is refused (kFailedPrecondition), so that two runs never mix in one bundle.
  static Result<std::unique_ptr<BundleWriter>> Create(const std::filesystem::path& directory,
                                                     const BundleHeader& header, const Options& options,
                                                     const std::string& run_hash = "");
  static Result<std::unique_ptr<BundleWriter>> Create(const std::filesystem::path& directory,
                                                     const BundleHeader& header) {
    return Create(directory, header, Options{});
  }
  ~BundleWriter();
  BundleWriter(const BundleWriter&) = delete;
  BundleWriter& operator=(const BundleWriter&) = delete;

  // Writes `image` (CV_8U or CV_16U, 1 or 3 channels, BGR, of the header's size) as a PNG. An empty
  // record.file means FrameFileName(step, laser, pose). Thread-safe. kInvalidArgument for a wrong image or
  // a duplicate file name; kIoError if the write fails.
  Status AddFrame(FrameRecord record, const cv::Mat& image);

  // True when `file` (e.g. "frames/s0012_left.png") was written before the interruption of a resumed
  // bundle: the caller may skip it. Adding it again replaces it.
  bool HasFrame(const std::string& file) const;
  std::size_t resumed_frame_count() const;
  std::size_t frame_count() const;  // frames recorded so far (resumed ones included)
  // Where a bundle for `directory` is written until it is finished.
  static std::filesystem::path PartialDirectory(const std::filesystem::path& directory);

  // The partial directory, where truth/ files may be written before Finish() (truth/ exists already).
  const std::filesystem::path& working_directory() const { return working_; }
  const std::filesystem::path& final_directory() const { return final_; }

  // Writes bundle.json (frames sorted by pose, step, laser) and renames the directory to its final name.
  Status Finish();
  // Gives the bundle up: the partial directory is removed (nothing to resume). No call may follow.
  void Discard();

 private:
  BundleWriter(std::filesystem::path final_dir, std::filesystem::path working, BundleHeader header,
               Options options);

  std::filesystem::path final_;
  std::filesystem::path working_;
  BundleHeader header_;
  Options options_;
  mutable std::mutex mutex_;
  std::vector<FrameRecord> frames_;
  std::set<std::string> resumed_;  // files written before the interruption, not written again yet
  std::FILE* journal_ = nullptr;   // journal.jsonl of the partial directory
  int lock_fd_ = -1;               // flock on .lock of the partial directory
  bool started_ = false;           // the partial directory was created (or overwritten) by this writer
  bool finished_ = false;
};

}  // namespace rotoscan::bundle
