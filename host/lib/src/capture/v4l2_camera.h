// The `v4l2` camera backend: UVC webcams (and any V4L2 capture node) through the kernel's V4L2 API
// directly (linux/videodev2.h), not OpenCV's VideoCapture, which hides the controls and timestamps a
// scanner needs. Private to the capture module; tests include it for the counters and the pure helpers.
//
// Spec: "v4l2:/dev/videoN" ("v4l2" alone: the first capture node). Options (OpenContext::options):
//   format=mjpeg|yuyv     pixel format (default: YUYV when the size is offered in YUYV, else MJPEG; the
//                         Logitech C270 of the bq Ciclop delivers 1280x960 only as MJPEG)
//   io=mmap|userptr       streaming I/O method (default mmap; uvcvideo supports both)
//   buffers=N             driver buffers (default 4)
//   gain=N                V4L2_CID_GAIN in the camera's own units (UVC gain has no unit; default: the
//                         control's default value). CameraSettings::gain_db must then be 0.
//   wb_temperature=K      V4L2_CID_WHITE_BALANCE_TEMPERATURE in kelvin (default: the control's default)
//   readout_us=N          the sensor's rolling-shutter readout time, first row to last row (see below)
//
// Timestamps. V4L2 says in each buffer's flags which clock stamped it (V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC:
// CLOCK_MONOTONIC, the host clock of the scan) and what instant it marks (V4L2_BUF_FLAG_TSTAMP_SRC_SOE:
// the start of exposure; V4L2_BUF_FLAG_TSTAMP_SRC_EOF, value 0: the end of the frame, i.e. the last row's
// end of exposure, when its last byte reached the host). uvcvideo declares MONOTONIC | SOE: its stamp is
// the camera's presentation time stamp (PTS, start of the frame's capture) converted to the host clock
// through the UVC source clock reference when the camera sends both, else the host time of the frame's
// first USB packet, which is late by up to one frame. The exposure window is derived from the flag:
//   SOE: first row starts at t;                  whole frame in [t, t + readout + exposure]
//   EOF: last row ends at t (transfer included); whole frame in [t - readout - exposure, t]
//   COPY/UNKNOWN clock: the host time of the dequeue is used as an EOF stamp, uncertain by one frame.
// The uncertainty of the start (CameraCapabilities::timestamp_uncertainty_us) is one frame period for
// UVC (the first-packet fallback cannot be told apart from PTS/SCR), as the timing of a free-running scan
// must assume.
//
// Rolling shutter. UVC does not report the readout time. It is taken from the option readout_us; without
// it the backend says so (Description(), a warning at open) and uses the frame period, the largest a
// rolling readout can be at that rate, so that the exposure window is a safe (wide) bound.
//
// Frame ids are the buffers' sequence numbers extended to 64 bits: a gap is a frame the driver dropped.
// A buffer flagged V4L2_BUF_FLAG_ERROR, empty, or whose JPEG does not decode cleanly (a corrupt or
// truncated MJPEG frame: libjpeg's warnings count as errors) is dropped too, counted, and requeued; it
// leaves a gap in the frame ids the caller sees.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "rotoscan/capture/camera.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/core/status.h"

namespace rotoscan::capture {

// Decodes one MJPEG frame into CV_8UC3 (BGR) or CV_8UC1 (gray) of the expected size, with libjpeg. A
// corrupt or truncated JPEG (any libjpeg error or warning: "premature end of data", "corrupt data") or a
// size other than expected is kCorruptData; it never crashes and never returns a partly decoded image.
// UVC MJPEG frames usually carry no Huffman tables; libjpeg-turbo supplies the standard ones.
Result<cv::Mat> DecodeMjpeg(const uint8_t* data, size_t size, int width, int height, PixelFormat format);

// YUYV 4:2:2 (bytes_per_line >= 2 * width) to BGR or gray. kCorruptData when `size` is short.
Result<cv::Mat> ConvertYuyv(const uint8_t* data, size_t size, int width, int height, int bytes_per_line,
                            PixelFormat format);

// What a V4L2 buffer's timestamp marks, from its flags (see the file comment).
struct V4l2Timestamp {
  bool monotonic = false;        // V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC: on CLOCK_MONOTONIC
  bool start_of_exposure = false;  // V4L2_BUF_FLAG_TSTAMP_SRC_SOE (else end of frame)
};
V4l2Timestamp DecodeTimestampFlags(uint32_t flags);
// The first row's start of exposure from a stamp `t_us` (host clock), per the file comment.
int64_t ExposureStartFromStamp(int64_t t_us, const V4l2Timestamp& kind, int64_t exposure_us, int64_t readout_us);

// Extends 32-bit sequence numbers to 64 bits across wraps.
class SequenceExtender {
 public:
  uint64_t Extend(uint32_t sequence);

 private:
  bool first_ = true;
  uint64_t last_ = 0;
};

struct V4l2Counters {
  uint64_t frames = 0;         // frames handed to the caller
  uint64_t dropped = 0;        // frame ids missing between frames handed out (includes the ones below)
  uint64_t corrupt_jpeg = 0;   // MJPEG frames that did not decode
  uint64_t error_buffers = 0;  // V4L2_BUF_FLAG_ERROR or empty buffers
};

class V4l2Camera : public Camera {
 public:
  // Opens `path` ("/dev/video0"; empty: the first capture node) and reads its capabilities and formats.
  static Result<std::unique_ptr<V4l2Camera>> Open(const std::string& path, const OpenContext& context);
  ~V4l2Camera() override;

  const CameraCapabilities& capabilities() const override;
  std::string Description() const override;
  Result<CameraSettings> Configure(const CameraSettings& settings) override;
  const CameraSettings& settings() const override;
  Status Start() override;
  Status Stop() override;
  Status SetExposure(int64_t exposure_us) override;
  Result<std::optional<Frame>> NextFrame(int64_t timeout_us) override;

  V4l2Counters counters() const;
  uint32_t pixel_format() const;  // the V4L2 fourcc in use (after Configure)

  struct Impl;

 private:
  explicit V4l2Camera(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Every /dev/video* node with video capture, for `rotoscan devices`: "v4l2:/dev/video0", "Logitech C270
// (uvcvideo): MJPEG 1280x960 640x480 ...; YUYV ...". Nodes that cannot be opened are listed in `errors`.
Result<std::vector<DeviceListing>> ListV4l2Cameras();

}  // namespace rotoscan::capture
