// The one-page scan report: an HTML file a person opens in any browser, self-contained (the pictures are
// PNGs embedded as base64 data URIs), with the key figures as text.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "rotoscan/core/status.h"

namespace rotoscan::mesh {

struct ReportPicture {
  std::string caption;
  cv::Mat image;               // 8-bit BGR or gray, encoded as PNG; or
  std::filesystem::path file;  // a PNG file, embedded as it is (when `image` is empty)
};

struct ReportSection {
  std::string heading;
  std::string text;  // preformatted (shown as is, HTML-escaped)
};

struct ScanReport {
  std::string title = "Rotoscan scan report";
  std::vector<std::pair<std::string, std::string>> figures;  // name, value: the table at the top
  std::vector<ReportPicture> pictures;
  std::vector<ReportSection> sections;
};

// The report as HTML. kInvalidArgument if a picture cannot be encoded.
Result<std::string> ReportHtml(const ScanReport& report);
// Writes it atomically.
Status WriteReport(const std::filesystem::path& path, const ScanReport& report);

// RFC 4648 base64 with padding.
std::string Base64(const std::string& bytes);

}  // namespace rotoscan::mesh
