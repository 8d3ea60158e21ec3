// A camera behind one interface (STYLE.md 8); backends: `virtual` (the virtual scanner, this module),
// `v4l2` (UVC webcams), `aravis` (GenICam). Open one with OpenCamera() (factory.h).
//
// Clocks and units: all times are microseconds on the host clock of the scan (clock.h: CLOCK_MONOTONIC
// for real cameras). A frame's exposure window is what the timing of a scan rests on: row r of a frame
// is exposed from
//     exposure_start_us + r * readout_us / (height - 1)   to   that + exposure_us
// so the whole frame (all rows) lies in [exposure_start_us, exposure_start_us + readout_us + exposure_us]
// (ExposureEndUs()). readout_us is 0 for a global shutter. A backend whose driver stamps the end of the
// frame (most UVC drivers) converts to exposure start itself, and says so in capabilities().timestamp.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "rotoscan/core/status.h"

namespace rotoscan::capture {

// What the driver's timestamps mark, before the backend converted them to exposure start.
enum class TimestampSource {
  kExposureStart,  // the sensor's start of exposure (a virtual camera, a GenICam exposure-start event)
  kFrameEnd,       // the end of the frame's transfer (UVC webcams): start = end - readout - exposure - transfer
  kUnknown,        // a bound only: treat the exposure window as uncertain by one frame period
};

struct CameraCapabilities {
  bool trigger_input = false;           // can wait for a hardware trigger edge (the board's trigger line)
  bool exposure_active_output = false;  // drives a line while exposing (wired back to the board)
  bool rolling_shutter = false;         // rows start exposing one after another over readout_us
  int64_t readout_us = 0;               // first row to last row; 0 for a global shutter
  TimestampSource timestamp = TimestampSource::kUnknown;
  // The uncertainty of exposure_start_us (driver latency jitter, USB transfer), microseconds.
  int64_t timestamp_uncertainty_us = 0;
  bool device_timestamps = false;  // frames carry the camera's own clock (Frame::device_time_us)
  bool manual_exposure = false;
  bool manual_gain = false;
  bool manual_white_balance = false;
  bool exposure_while_streaming = false;  // SetExposure() works without stopping the stream
};

enum class PixelFormat { kGray8, kBgr8 };

struct CameraSettings {
  int width = 0;  // 0 = the camera's default (or largest) size
  int height = 0;
  PixelFormat format = PixelFormat::kBgr8;
  double frame_rate_hz = 30.0;  // free-running rate; in triggered mode the upper bound of trigger rates
  int64_t exposure_us = 10'000;
  double gain_db = 0.0;
  // Manual white balance as red, green, blue gains (green 1); nullopt leaves the camera's own (but never
  // automatic: a backend turns auto white balance off).
  std::optional<std::array<double, 3>> white_balance;
  bool triggered = false;  // expose on the trigger input instead of free-running (needs trigger_input)
  // Triggered: the exposures successive triggers use in turn from Start() (a GenICam sequencer, so a scan
  // program can alternate short laser shots and a long natural one); empty: exposure_us for every frame.
  std::vector<int64_t> exposure_cycle_us;
  Status Check() const;
};

struct Frame {
  cv::Mat image;          // CV_8UC1 (gray) or CV_8UC3 (BGR), settings' size
  uint64_t frame_id = 0;  // the camera's own counter: a gap means the camera dropped frames
  int64_t exposure_start_us = 0;  // first row's start of exposure, host clock (see file comment)
  int64_t exposure_us = 0;        // exposure actually used for this frame
  int64_t readout_us = 0;         // first row to last row start; 0 for a global shutter
  std::optional<uint64_t> device_time_us;  // the camera's own timestamp, when it has one
  // The last row's end of exposure: the whole frame was exposed inside [exposure_start_us, this].
  int64_t ExposureEndUs() const { return exposure_start_us + readout_us + exposure_us; }
};

class Camera {
 public:
  virtual ~Camera() = default;

  virtual const CameraCapabilities& capabilities() const = 0;
  // "virtual 640x480 rolling 30 fps", "v4l2 /dev/video0 (Logitech C270)": for messages and bundle.json.
  virtual std::string Description() const = 0;

  // Applies settings while stopped and reads them back: the result is what the camera will really do
  // (size, rate, exposure, gain). A camera that does not hold a manual setting is an error naming the
  // control (kDeviceError); an unsupported request (triggered without a trigger input) kInvalidArgument.
  virtual Result<CameraSettings> Configure(const CameraSettings& settings) = 0;
  // The settings in force (after Configure).
  virtual const CameraSettings& settings() const = 0;

  // Starts streaming (free-running) or arms the trigger input (triggered).
  virtual Status Start() = 0;
  // Stops; frames not yet read are discarded. Safe to call when stopped.
  virtual Status Stop() = 0;

  // Changes the exposure of the frames that follow, while streaming when
  // capabilities().exposure_while_streaming (otherwise kFailedPrecondition). Frames report the exposure
  // they were taken with, so the caller knows which frame has the new one.
  virtual Status SetExposure(int64_t exposure_us) = 0;

  // The next frame, waiting up to `timeout_us` (on the scan's clock); nullopt on timeout. kDeviceError
  // when the camera is gone.
  virtual Result<std::optional<Frame>> NextFrame(int64_t timeout_us) = 0;
};

}  // namespace rotoscan::capture
