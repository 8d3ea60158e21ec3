#include "rotoscan/geometry/image_file.h"

#include <png.h>

#include <cstring>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rotoscan/core/file.h"

namespace rotoscan::geometry {
namespace {

int OpenCvFlags(ImageRead mode) {
  switch (mode) {
    case ImageRead::kGray: return cv::IMREAD_GRAYSCALE;
    case ImageRead::kColor: return cv::IMREAD_COLOR;
    case ImageRead::kUnchanged: break;
  }
  return cv::IMREAD_UNCHANGED;
}

Result<cv::Mat> DecodeWithOpenCv(const std::string& bytes, const std::string& name, ImageRead mode) {
  cv::Mat image;
  try {
    const cv::Mat buffer(1, static_cast<int>(bytes.size()), CV_8U, const_cast<char*>(bytes.data()));
    image = cv::imdecode(buffer, OpenCvFlags(mode));
  } catch (const cv::Exception& e) {  // e.g. a header declaring more pixels than OpenCV allows
    return CorruptDataError(name + " cannot be decoded as an image: " + e.err);
  }
  if (image.empty()) return CorruptDataError(name + " cannot be decoded as an image");
  return image;
}

// libpng's simplified API: errors and warnings land in `png.message`, nothing is printed.
Result<cv::Mat> DecodePng(const std::string& bytes, const std::string& name, ImageRead mode,
                          bool* use_opencv) {
  png_image png;
  std::memset(&png, 0, sizeof(png));
  png.version = PNG_IMAGE_VERSION;
  if (png_image_begin_read_from_memory(&png, bytes.data(), bytes.size()) == 0) {
    const std::string why = png.message;
    png_image_free(&png);
    return CorruptDataError(name + " is not a readable PNG: " + why);
  }
  if (static_cast<int64_t>(png.width) * static_cast<int64_t>(png.height) > kMaxImagePixels) {
    png_image_free(&png);
    return CorruptDataError(name + " declares " + std::to_string(png.width) + " x " +
                            std::to_string(png.height) + " pixels, more than " +
                            std::to_string(kMaxImagePixels));
  }
  if ((png.format & PNG_FORMAT_FLAG_LINEAR) != 0) {  // 16 bits per channel: OpenCV keeps them as they are
    png_image_free(&png);
    *use_opencv = true;
    return cv::Mat();
  }
  const bool color = (png.format & PNG_FORMAT_FLAG_COLOR) != 0;
  const bool alpha = (png.format & PNG_FORMAT_FLAG_ALPHA) != 0;
  // With alpha, BGRA is read and the alpha dropped after for gray or color (as OpenCV does: libpng would
  // composite onto black instead).
  png_uint_32 format = PNG_FORMAT_BGR;
  int type = CV_8UC3;
  if (alpha) {
    format = PNG_FORMAT_BGRA;
    type = CV_8UC4;
  } else if (!color && mode != ImageRead::kColor) {
    format = PNG_FORMAT_GRAY;
    type = CV_8UC1;
  }
  png.format = format;
  cv::Mat image(static_cast<int>(png.height), static_cast<int>(png.width), type);
  if (png_image_finish_read(&png, nullptr, image.data, static_cast<png_int_32>(image.step[0]), nullptr) ==
      0) {
    const std::string why = png.message;
    png_image_free(&png);
    return CorruptDataError(name + " does not decode as PNG: " + why);
  }
  if (mode == ImageRead::kGray && image.channels() == 3) cv::cvtColor(image, image, cv::COLOR_BGR2GRAY);
  if (mode == ImageRead::kGray && image.channels() == 4) cv::cvtColor(image, image, cv::COLOR_BGRA2GRAY);
  if (mode == ImageRead::kColor && image.channels() == 4) cv::cvtColor(image, image, cv::COLOR_BGRA2BGR);
  return image;
}

bool LooksLikePng(const std::string& bytes) {
  static const char kSignature[8] = {'\x89', 'P', 'N', 'G', '\r', '\n', '\x1a', '\n'};
  return bytes.size() >= 8 && std::memcmp(bytes.data(), kSignature, 8) == 0;
}

}  // namespace

Result<cv::Mat> DecodeImage(const std::string& bytes, const std::string& name, ImageRead mode) {
  if (bytes.empty()) return CorruptDataError(name + " is empty");
  if (LooksLikePng(bytes)) {
    bool use_opencv = false;
    Result<cv::Mat> image = DecodePng(bytes, name, mode, &use_opencv);
    if (!use_opencv) return image;
  }
  return DecodeWithOpenCv(bytes, name, mode);
}

Result<cv::Mat> ReadImageFile(const std::filesystem::path& path, ImageRead mode) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::string bytes, ReadFile(path, std::size_t{1} << 31));
  return DecodeImage(bytes, path.string(), mode);
}

}  // namespace rotoscan::geometry
