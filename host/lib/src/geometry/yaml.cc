#include "rotoscan/geometry/yaml.h"

#include <exception>
#include <system_error>

#include <opencv2/core.hpp>

#include "rotoscan/core/file.h"

namespace rotoscan::geometry {

std::size_t InvalidYamlByteAt(const std::string& text) {
  std::size_t i = 0;
  while (i < text.size()) {
    const auto c = static_cast<unsigned char>(text[i]);
    const std::size_t length = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E ? 4 : 0;
    if (length == 0 || c == 0xC0 || c == 0xC1 || c > 0xF4 || i + length > text.size()) return i;
    for (std::size_t k = 1; k < length; ++k) {
      if ((static_cast<unsigned char>(text[i + k]) & 0xC0) != 0x80) return i;
    }
    if (c < 0x20 && c != '\n' && c != '\r' && c != '\t') return i;  // control bytes
    i += length;
  }
  return std::string::npos;
}

Status ReadYamlText(const std::string& text, const std::string& name,
                    const std::function<Status(const cv::FileNode& root)>& read) {
  if (const std::size_t at = InvalidYamlByteAt(text); at != std::string::npos) {
    return CorruptDataError(name + " is not a YAML text: byte " + std::to_string(at) +
                            " is a control character or not UTF-8");
  }
  try {
    cv::FileStorage storage(text, cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
    if (!storage.isOpened()) return CorruptDataError(name + " is not an OpenCV YAML file");
    return read(storage.root()).WithContext(name);
  } catch (const cv::Exception& e) {
    return CorruptDataError(name + ": " + e.msg);
  } catch (const std::exception& e) {
    return CorruptDataError(name + " is not a readable OpenCV YAML file (" + e.what() + ")");
  }
}

Status ReadYamlFile(const std::filesystem::path& path, const std::string& what,
                    const std::function<Status(const cv::FileNode& root)>& read) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    if (std::filesystem::exists(path, ec)) {
      return InvalidArgumentError(what + " " + path.string() + " is not a regular file");
    }
    return NotFoundError(what + " " + path.string() + " does not exist");
  }
  ROTOSCAN_ASSIGN_OR_RETURN(const std::string text, ReadFile(path, std::size_t{64} << 20));
  return ReadYamlText(text, path.string(), read);
}

}  // namespace rotoscan::geometry
