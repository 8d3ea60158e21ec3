#include "rotoscan/mesh/report.h"

#include <opencv2/imgcodecs.hpp>

#include "rotoscan/core/file.h"

namespace rotoscan::mesh {
namespace {

std::string Escape(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out.push_back(c);
    }
  }
  return out;
}

}  // namespace

std::string Base64(const std::string& bytes) {
  static const char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = static_cast<uint32_t>(static_cast<unsigned char>(bytes[i])) << 16 |
                       static_cast<uint32_t>(static_cast<unsigned char>(bytes[i + 1])) << 8 |
                       static_cast<unsigned char>(bytes[i + 2]);
    for (int k = 3; k >= 0; --k) out.push_back(kAlphabet[(v >> (6 * k)) & 63]);
  }
  if (i < bytes.size()) {
    uint32_t v = static_cast<uint32_t>(static_cast<unsigned char>(bytes[i])) << 16;
    if (i + 1 < bytes.size()) v |= static_cast<uint32_t>(static_cast<unsigned char>(bytes[i + 1])) << 8;
    out.push_back(kAlphabet[(v >> 18) & 63]);
    out.push_back(kAlphabet[(v >> 12) & 63]);
    out.push_back(i + 1 < bytes.size() ? kAlphabet[(v >> 6) & 63] : '=');
    out.push_back('=');
  }
  return out;
}

Result<std::string> ReportHtml(const ScanReport& report) {
  std::string html =
      "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>" + Escape(report.title) +
      "</title>\n<style>body{font-family:sans-serif;margin:2em;background:#fafafa}table{border-collapse:collapse}"
      "td{border:1px solid #ccc;padding:4px 10px}img{max-width:100%;border:1px solid #888}"
      "pre{background:#eee;padding:8px;overflow-x:auto}</style></head><body>\n<h1>" +
      Escape(report.title) + "</h1>\n";
  if (!report.figures.empty()) {
    html += "<table>\n";
    for (const auto& [name, value] : report.figures) {
      html += "<tr><td>" + Escape(name) + "</td><td>" + Escape(value) + "</td></tr>\n";
    }
    html += "</table>\n";
  }
  for (const ReportPicture& picture : report.pictures) {
    std::string png;
    if (picture.image.empty() && !picture.file.empty()) {
      auto bytes = ReadFile(picture.file, std::size_t{1} << 28);
      if (!bytes.ok()) return bytes.status().WithContext("report picture '" + picture.caption + "'");
      if (bytes->compare(0, 8, "\x89PNG\r\n\x1a\n") != 0)
        return InvalidArgumentError("report picture " + picture.file.string() + " is not a PNG file");
      png = std::move(*bytes);
    } else {
      std::vector<uchar> encoded;
      try {
        if (picture.image.empty() || !cv::imencode(".png", picture.image, encoded))
          return InvalidArgumentError("report picture '" + picture.caption + "' cannot be encoded");
      } catch (const cv::Exception& e) {
        return InvalidArgumentError("report picture '" + picture.caption + "': " + e.msg);
      }
      png.assign(encoded.begin(), encoded.end());
    }
    html += "<h2>" + Escape(picture.caption) + "</h2>\n<img alt=\"" + Escape(picture.caption) +
            "\" src=\"data:image/png;base64," + Base64(png) + "\">\n";
  }
  for (const ReportSection& section : report.sections) {
    html += "<h2>" + Escape(section.heading) + "</h2>\n<pre>" + Escape(section.text) + "</pre>\n";
  }
  html += "</body></html>\n";
  return html;
}

Status WriteReport(const std::filesystem::path& path, const ScanReport& report) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::string html, ReportHtml(report));
  return WriteFileAtomically(path, html);
}

}  // namespace rotoscan::mesh
