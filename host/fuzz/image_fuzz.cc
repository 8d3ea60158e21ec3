// libFuzzer target: image files as the frames of a bundle, calibration pictures and textures are read
// (geometry::DecodeImage: PNG through libpng's simplified API, other formats through OpenCV). What decodes
// is an image of the declared kind; nothing may be printed or crash on the way.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "rotoscan/geometry/image_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  using rotoscan::geometry::ImageRead;
  for (ImageRead mode : {ImageRead::kUnchanged, ImageRead::kGray}) {
    const rotoscan::Result<cv::Mat> image = rotoscan::geometry::DecodeImage(bytes, "fuzz", mode);
    if (!image.ok()) continue;
    if (image->empty() || image->total() > static_cast<size_t>(rotoscan::geometry::kMaxImagePixels))
      std::abort();
    if (mode == ImageRead::kGray && image->channels() != 1) std::abort();
  }
  return 0;
}
