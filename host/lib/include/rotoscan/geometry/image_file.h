// Reading image files (frames, calibration pictures, textures) with every decoder message in the Status.
//
// OpenCV's PNG decoder leaves libpng's default handlers in place, so a corrupt PNG printed raw
// "libpng error: ..." / "libpng warning: ..." lines on stderr before our own error (issue 20). PNG files
// are therefore decoded here with libpng's simplified API, which reports into a message instead of
// printing; 16-bit PNGs and other formats (JPEG, ...) go to OpenCV. A header declaring more than
// `kMaxImagePixels` pixels is refused before anything is allocated.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

#include <opencv2/core/mat.hpp>

#include "rotoscan/core/status.h"

namespace rotoscan::geometry {

enum class ImageRead {
  kUnchanged,  // as stored: gray 1 channel, color 3 (BGR), with alpha 4 (BGRA); 16-bit kept
  kGray,       // one 8-bit channel
  kColor,      // three 8-bit channels, BGR
};

constexpr int64_t kMaxImagePixels = int64_t{1} << 28;

// kNotFound if the file does not exist, kInvalidArgument if it is not a regular file, kCorruptData naming
// the file and the decoder's reason if it does not decode.
Result<cv::Mat> ReadImageFile(const std::filesystem::path& path, ImageRead mode = ImageRead::kUnchanged);
// The same from bytes in memory; `name` is for the messages.
Result<cv::Mat> DecodeImage(const std::string& bytes, const std::string& name,
                            ImageRead mode = ImageRead::kUnchanged);

}  // namespace rotoscan::geometry
