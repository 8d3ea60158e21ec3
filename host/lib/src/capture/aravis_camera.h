// The `aravis` camera backend: GenICam cameras (USB3 Vision, GigE Vision) through libaravis. Private to the
// capture module; tests include it to reach the ArvCamera (Aravis's fake camera is fed from the test).
//
// Spec: "aravis" (the first camera Aravis finds) or "aravis:ID" (an Aravis device id as `arv-tool-0.8`
// lists it: "Basler-21234567", or "Fake_1" for Aravis's own fake camera, whose interface this backend
// enables for ids starting with "Fake"). Options (OpenContext::options):
//   trigger_line=Line0     TriggerSource in triggered mode (the line the board's trigger output drives)
//   exposure_line=Line1    the output line set to LineSource ExposureActive (wired back to the board's
//                          exposure-active input); when the camera has no LineSelector the output is not
//                          configured unless this option is given, which is then an error
//   readout_us=N           rolling-shutter readout, first row to last (default 0: a global shutter)
//   buffers=N              stream buffers (default 8)
//
// Settings are written and read back (ExposureTime / ExposureTimeAbs, Gain / GainRaw, BalanceRatio,
// TriggerMode, TriggerSource, LineSource): a camera that does not hold one is kDeviceError naming the
// feature. Exposure and gain go manual first (ExposureAuto, GainAuto, BalanceWhiteAuto Off) where the
// camera has those features.
//
// Frames carry the camera's frame id (a gap is a dropped frame; GigE Vision 1.x block ids are 16 bits
// and skip 0 when they wrap: they are extended to 64 bits) and its device timestamp
// (arv_buffer_get_timestamp, ns: Frame::device_time_us, for matching triggers by device time). The
// host-clock exposure window comes from Aravis's system timestamp (arv_buffer_get_system_timestamp: the
// host's CLOCK_REALTIME when the frame was received, converted to CLOCK_MONOTONIC at dequeue), taken as
// the end of the frame: exposure start = that - readout - exposure (TimestampSource::kFrameEnd), late by
// the transfer time, which is the stated uncertainty (one frame period).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "rotoscan/capture/camera.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/core/status.h"

typedef struct _ArvCamera ArvCamera;  // NOLINT: Aravis's own declaration

namespace rotoscan::capture {

struct AravisCounters {
  uint64_t frames = 0;     // frames handed to the caller
  uint64_t dropped = 0;    // frame id gaps and failed buffers
  uint64_t failed = 0;     // buffers Aravis completed with an error status (missing packets, timeout)
};

// Extends GenICam frame ids to 64 bits: 16-bit GigE Vision 1.x block ids wrap from 65535 to 1.
class FrameIdExtender {
 public:
  uint64_t Extend(uint64_t raw);

 private:
  bool first_ = true;
  uint64_t last_raw_ = 0;
  uint64_t value_ = 0;
};

class AravisCamera : public Camera {
 public:
  static Result<std::unique_ptr<AravisCamera>> Open(const std::string& id, const OpenContext& context);
  ~AravisCamera() override;

  const CameraCapabilities& capabilities() const override;
  std::string Description() const override;
  Result<CameraSettings> Configure(const CameraSettings& settings) override;
  const CameraSettings& settings() const override;
  Status Start() override;
  Status Stop() override;
  Status SetExposure(int64_t exposure_us) override;
  Result<std::optional<Frame>> NextFrame(int64_t timeout_us) override;

  AravisCounters counters() const;
  // The Aravis camera (owned by this object), for tests and vendor-specific features.
  ArvCamera* arv_camera();
  // The trigger source and exposure-active line in force after Configure ("" when none).
  std::string trigger_source() const;
  std::string exposure_output_line() const;

  struct Impl;

 private:
  explicit AravisCamera(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

Result<std::vector<DeviceListing>> ListAravisCameras();

}  // namespace rotoscan::capture
