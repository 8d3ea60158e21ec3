// libFuzzer target: a webcam's MJPEG frames as the V4L2 camera decodes them (capture::DecodeMjpeg, libjpeg).
// A camera is a device we do not control: a torn or corrupt frame must come back as an error (the frame is
// dropped and counted), never a crash or a hang. The first byte picks the expected size and pixel format.
#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "capture/v4l2_camera.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  static const int kSizes[4][2] = {{640, 480}, {320, 240}, {64, 48}, {8, 8}};
  const int* wh = kSizes[data[0] & 3];
  const auto format =
      (data[0] & 4) != 0 ? rotoscan::capture::PixelFormat::kGray8 : rotoscan::capture::PixelFormat::kBgr8;
  const rotoscan::Result<cv::Mat> image =
      rotoscan::capture::DecodeMjpeg(data + 1, size - 1, wh[0], wh[1], format);
  if (image.ok() && (image->cols != wh[0] || image->rows != wh[1])) std::abort();
  return 0;
}
