// The scan (DESIGN.md "Capture"): per table step the frames left, right, off (short exposure) and
// natural (long exposure), written into a bundle as they arrive (bundle::BundleWriter: atomic, resumable).
//
// Timing, chosen from the capabilities (or forced by ScanOptions::timing):
//  * Hardware-triggered (the board has a trigger output, the camera a trigger input): the board runs a
//    scan program (move, settle, and per shot: lasers, trigger edge, exposure window) with no host round
//    trip; the camera exposes on each edge with the shot's exposure (CameraSettings::exposure_cycle_us).
//    Frames are matched to trigger edges by time (the edge's device time through the clock fit, within
//    `match_tolerance_us`) and by sequence: the difference frame id - trigger seq stays the same from one
//    frame to the next unless the camera dropped or added a frame, which is then seen and that frame not
//    used. A shot whose frame is missing, dropped, extra or whose trigger event was lost is re-taken
//    afterwards by a one-step program at that step: never mis-assigned, never silently left out.
//  * Free-running (no trigger line): the camera streams at its frame rate; each change (lasers, table,
//    exposure) is issued as soon as the previous state's frame has arrived, i.e. between frames, and a
//    frame counts for a state only if its whole exposure window (all rows: ExposureEndUs) begins after the
//    change's latest possible time plus the camera's timestamp uncertainty, and carries the exposure
//    asked for. No fixed sleeps, no frames flushed by count: frames are judged by their timestamps.
//
// Shared off frame (ScanOptions::shared_off): per step left, right and off only, all at the laser
// exposure, and the off frame is also the step's color frame (3 frames instead of 4; the bundle says so:
// bundle::BundleHeader::shared_off_frame, format_version 2). It is taken at the laser exposure, not the
// natural one with the background scaled down, because the background must match the laser frames
// exactly for the line extraction (a long exposure saturates where the surface is bright, and a webcam's
// response is not linear, so no scaling gives the short exposure's background back), whereas color only
// loses signal (darker by the exposure ratio, noisier, coarser in 8 bits) and is averaged over many views
// by the color pass. No exposure changes either: a free-running camera never waits for one to take effect.
//
// Resume: a scan interrupted (Ctrl-C, crash, unplug beyond the client's reconnect window) leaves
// "<out>.partial"; ScanOptions::resume continues it, re-taking only the frames it lacks.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>

#include <opencv2/core/mat.hpp>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/capture/board.h"
#include "rotoscan/capture/camera.h"
#include "rotoscan/capture/clock.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"

namespace rotoscan::capture {

enum class Timing { kAuto, kTriggered, kFreeRunning };
const char* TimingName(Timing timing);  // "auto", "triggered", "free-running"
Result<Timing> ParseTiming(const std::string& name);

// What a scan hands to an observer as it goes (live processing, calibration checks, tests).
struct CapturedFrame {
  int step = 0;
  bundle::LaserState laser = bundle::LaserState::kOff;
  double table_angle_rad = 0.0;
  const Frame* frame = nullptr;  // with its exposure window on the scan's clock
  // Written before an interruption and read back from the partial bundle (ScanOptions::replay_resumed):
  // only frame->image and frame->exposure_us mean anything.
  bool resumed = false;
};

struct ScanOptions {
  int steps = 200;       // table steps in the scan (360° / steps each), or views of a calibration capture
  double step_deg = 0.0;  // 0: 360 / steps
  Timing timing = Timing::kAuto;
  double frame_rate_hz = 30.0;
  int64_t laser_exposure_us = 2000;     // left, right, off
  int64_t natural_exposure_us = 20000;  // natural (color)
  int natural_every = 1;                // a natural frame every k steps (0: none); triggered: a second program
  bool shared_off = false;              // the off frame is also the color frame (see above): no natural frames
  bool lasers = true;                   // false: natural frames only (calibration views)
  bundle::BundleHeader header;          // camera, device, kind, target; table_step is set from step_deg
  bool resume = false;
  bool overwrite = false;
  int pose = -1;  // calibration pose index written in the frame records
  // Triggered: the board's program, and how frames are tied to edges.
  uint32_t settle_us = 500;
  uint32_t laser_lead_us = 200;
  int64_t match_tolerance_us = 1000;
  int max_retakes = 3;  // rounds of re-taking missing shots
  int64_t frame_timeout_us = 2'000'000;
  // Called for each frame written (from the scan's thread). An error stops the scan with that error.
  std::function<Status(const CapturedFrame&)> on_frame;
  // Called when every frame of a step is written (live processing).
  std::function<void(int step)> on_step_done;
  // With resume: hand the frames written before the interruption to on_frame (CapturedFrame::resumed) and
  // on_step_done first, read back from the partial bundle, so that live processing covers the whole scan.
  bool replay_resumed = false;
  Status Check() const;
};

struct ScanSummary {
  Timing timing = Timing::kAuto;  // the mode used
  int steps = 0;
  int steps_resumed = 0;  // complete before this run (resume)
  int frames_captured = 0;  // delivered by the camera
  int frames_used = 0;      // written to the bundle
  int frames_rejected = 0;  // exposed across a change, or with another exposure (free-running)
  int frames_dropped = 0;   // gaps in the camera's frame ids
  int frames_unmatched = 0;  // triggered: no trigger edge fits (extra frames, lost events)
  int shots_retaken = 0;     // triggered
  int lost_events = 0;       // the board's trigger events lost on the way
  int64_t elapsed_us = 0;    // on the scan's clock, first command to last frame
  int64_t frames_time_us = 0;  // frames_used frame periods: the least the camera's rate allows
  double measured_frame_period_us = 0.0;
  std::filesystem::path bundle;
  std::string Summary() const;  // one paragraph for people
};

// Runs the scan and writes `out` (atomic; "<out>.partial" until done). The board is left with lasers off
// and the motor disabled, also on errors and on Ctrl-C (kCancelled, the partial bundle kept for resume).
Result<ScanSummary> RunScan(Board& board, Camera& camera, Clock& clock, const std::filesystem::path& out,
                            const ScanOptions& options, Progress* progress);

}  // namespace rotoscan::capture
