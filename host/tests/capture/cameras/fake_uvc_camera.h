// A UVC webcam on a umockdev testbed, for the v4l2 backend's tests: the backend's real open/ioctl/mmap/
// poll calls reach /dev/videoN as emulated by umockdev (the test runs under umockdev-wrapper), and an ioctl
// handler answers the V4L2 ioctls the way uvcvideo does (QUERYCAP, ENUM_FMT, ENUM_FRAMESIZES, S_FMT, S_PARM,
// QUERYCTRL, S_CTRL, G_CTRL, REQBUFS, QUERYBUF, QBUF, DQBUF, STREAMON, STREAMOFF).
//
// Frames are made on demand: a DQBUF with a buffer queued gets the next frame at once, stamped (CLOCK_
// MONOTONIC, start of exposure like uvcvideo, or end of frame) at t0 + sequence * frame period, where t0 is
// the host time of STREAMON. Images are synthetic BGR (a gradient and a bright column whose position is
// the sequence number), JPEG-encoded by OpenCV for MJPEG or converted to YUYV (BT.601) here.
//
// Memory: USERPTR buffers are written into the client's memory through umockdev's ioctl data; MMAP
// buffers live in the regular file that backs the emulated device node in the testbed (the client's
// mmap() of its fd maps that file), which the fake writes with pwrite() before it answers DQBUF.
//
// Faults: a frame dropped (its sequence number skipped), a truncated JPEG, a control the camera does not
// hold (set succeeds, reads back the default, as a camera whose firmware ignores it), a missing control.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

namespace rotoscan::capture::testing {

class FakeUvcCamera {
 public:
  struct Options {
    std::string devnode = "/dev/video0";
    int width = 64;
    int height = 48;
    bool mjpeg = true;
    bool yuyv = true;
    bool start_of_exposure = true;  // V4L2_BUF_FLAG_TSTAMP_SRC_SOE (uvcvideo); else EOF
    int64_t frame_period_us = 33'333;
    uint32_t ignored_control = 0;  // a control id the camera accepts but does not hold
    uint32_t missing_control = 0;  // a control id the camera does not have
  };

  static bool InMockEnvironment();

  explicit FakeUvcCamera(const Options& options);
  ~FakeUvcCamera();
  FakeUvcCamera(const FakeUvcCamera&) = delete;
  FakeUvcCamera& operator=(const FakeUvcCamera&) = delete;

  void DropNextFrame();     // skip a sequence number (the frame never reaches the host)
  void CorruptNextFrame();  // the next MJPEG frame truncated to a third of its bytes
  void Unplug();            // every ioctl fails with ENODEV from now on, as uvcvideo's after a disconnect

  // The frames the fake sent, in order.
  struct Sent {
    uint32_t sequence = 0;
    int64_t stamp_us = 0;
    bool corrupt = false;
    cv::Mat image;               // BGR, before encoding
    std::vector<uint8_t> bytes;  // what the buffer held (JPEG or YUYV)
  };
  std::vector<Sent> sent() const;
  int32_t control(uint32_t id) const;  // the value the camera holds
  std::string memory() const;          // "mmap" or "userptr": what the client used
  static cv::Mat MakeImage(int width, int height, uint32_t sequence);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace rotoscan::capture::testing
