#include "rotoscan/calib/charuco.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <utility>

#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "opencv_calibration.h"
#include "rotoscan/core/check.h"
#include "rotoscan/core/logging.h"

namespace rotoscan::calib {
namespace {

struct DictionaryName {
  const char* name;
  cv::aruco::PREDEFINED_DICTIONARY_NAME id;
};

constexpr DictionaryName kDictionaries[] = {
    {"DICT_4X4_50", cv::aruco::DICT_4X4_50},
    {"DICT_4X4_100", cv::aruco::DICT_4X4_100},
    {"DICT_4X4_250", cv::aruco::DICT_4X4_250},
    {"DICT_4X4_1000", cv::aruco::DICT_4X4_1000},
    {"DICT_5X5_50", cv::aruco::DICT_5X5_50},
    {"DICT_5X5_100", cv::aruco::DICT_5X5_100},
    {"DICT_5X5_250", cv::aruco::DICT_5X5_250},
    {"DICT_5X5_1000", cv::aruco::DICT_5X5_1000},
    {"DICT_6X6_50", cv::aruco::DICT_6X6_50},
    {"DICT_6X6_100", cv::aruco::DICT_6X6_100},
    {"DICT_6X6_250", cv::aruco::DICT_6X6_250},
    {"DICT_6X6_1000", cv::aruco::DICT_6X6_1000},
    {"DICT_7X7_50", cv::aruco::DICT_7X7_50},
    {"DICT_7X7_100", cv::aruco::DICT_7X7_100},
    {"DICT_7X7_250", cv::aruco::DICT_7X7_250},
    {"DICT_7X7_1000", cv::aruco::DICT_7X7_1000},
    {"DICT_ARUCO_ORIGINAL", cv::aruco::DICT_ARUCO_ORIGINAL},
    {"DICT_APRILTAG_16h5", cv::aruco::DICT_APRILTAG_16h5},
    {"DICT_APRILTAG_25h9", cv::aruco::DICT_APRILTAG_25h9},
    {"DICT_APRILTAG_36h10", cv::aruco::DICT_APRILTAG_36h10},
    {"DICT_APRILTAG_36h11", cv::aruco::DICT_APRILTAG_36h11},
};

std::string Upper(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::toupper(c); });
  return s;
}

// The table entry for `name` (case-insensitive, "DICT_" optional), or nullptr.
const DictionaryName* FindDictionary(const std::string& name) {
  std::string wanted = Upper(name);
  if (wanted.rfind("DICT_", 0) != 0) wanted = "DICT_" + wanted;
  for (const DictionaryName& d : kDictionaries) {
    if (Upper(d.name) == wanted) return &d;
  }
  return nullptr;
}

cv::Ptr<cv::aruco::Dictionary> Dictionary(const CharucoBoard& board) {
  const DictionaryName* d = FindDictionary(board.dictionary);
  ROTOSCAN_CHECK(d != nullptr) << "unknown dictionary " << board.dictionary << " (call Check() first)";
  return cv::aruco::getPredefinedDictionary(d->id);
}

cv::Ptr<cv::aruco::CharucoBoard> OpenCvBoard(const CharucoBoard& board) {
  return cv::aruco::CharucoBoard::create(board.squares_x, board.squares_y,
                                         static_cast<float>(board.square_mm),
                                         static_cast<float>(board.marker_mm), Dictionary(board));
}

bool NearInteger(double x) {
  return std::abs(x - std::round(x)) < 1e-6;
}

std::string Squares(const CharucoBoard& board) {
  return std::to_string(board.squares_x) + "x" + std::to_string(board.squares_y);
}

}  // namespace

std::vector<std::string> CharucoDictionaryNames() {
  std::vector<std::string> names;
  for (const DictionaryName& d : kDictionaries) names.emplace_back(d.name);
  return names;
}

Status CharucoBoard::Check() const {
  if (squares_x < 3 || squares_y < 3 || squares_x > 100 || squares_y > 100) {
    return InvalidArgumentError("ChArUco board must have 3..100 squares each way, got " + Squares(*this));
  }
  if (!(square_mm > 0) || !std::isfinite(square_mm))
    return InvalidArgumentError("square size must be > 0 mm");
  if (!(marker_mm > 0) || !(marker_mm < square_mm)) {
    return InvalidArgumentError("marker size must be > 0 mm and smaller than the square (" +
                                std::to_string(square_mm) + " mm)");
  }
  const DictionaryName* d = FindDictionary(dictionary);
  if (d == nullptr) {
    std::string known;
    for (const DictionaryName& k : kDictionaries) known += std::string(known.empty() ? "" : ", ") + k.name;
    return InvalidArgumentError("unknown ArUco dictionary '" + dictionary + "' (one of " + known + ")");
  }
  const int available = cv::aruco::getPredefinedDictionary(d->id)->bytesList.rows;
  if (MarkerCount() > available) {
    return InvalidArgumentError("ChArUco board " + Squares(*this) + " needs " +
                                std::to_string(MarkerCount()) + " markers but " + d->name + " has " +
                                std::to_string(available) + ": use a larger dictionary");
  }
  return Status::Ok();
}

Eigen::Vector3d CharucoBoard::CornerInTarget(int id) const {
  ROTOSCAN_CHECK(id >= 0 && id < CornerCount()) << "corner id " << id << " of " << CornerCount();
  return Eigen::Vector3d((id % (squares_x - 1)) * square_mm, (id / (squares_x - 1)) * square_mm, 0.0);
}

std::vector<Eigen::Vector3d> CharucoBoard::CornersInTarget() const {
  std::vector<Eigen::Vector3d> corners;
  for (int id = 0; id < CornerCount(); ++id) corners.push_back(CornerInTarget(id));
  return corners;
}

cv::Mat CharucoBoard::Draw(int pixels_per_square) const {
  const Status ok = Check();
  ROTOSCAN_CHECK(ok.ok()) << ok.ToString();
  ROTOSCAN_CHECK(pixels_per_square >= 8 && pixels_per_square <= 4096)
      << "pixels_per_square " << pixels_per_square;
  cv::Mat image;
  OpenCvBoard(*this)->draw(cv::Size(squares_x * pixels_per_square, squares_y * pixels_per_square), image, 0,
                           1);
  return image;
}

int CharucoBoard::CrispPixelsPerSquare(int min_pixels, int max_pixels) const {
  ROTOSCAN_CHECK(min_pixels >= 1 && min_pixels <= max_pixels) << min_pixels << " .. " << max_pixels;
  const int cells = Dictionary(*this)->markerSize + 2;  // data bits + a one-cell black border each side
  for (int p = min_pixels; p <= max_pixels; ++p) {
    const double marker_px = marker_mm / square_mm * p;
    if (NearInteger(marker_px / cells) && NearInteger((p - marker_px) / 2)) return p;
  }
  return max_pixels;
}

std::string CharucoBoard::ToString() const {
  std::ostringstream s;
  s << Squares(*this) << " squares of " << square_mm << " mm, markers " << marker_mm << " mm, " << dictionary;
  return s.str();
}

Result<CharucoBoard> ParseCharucoBoard(const std::string& squares, double square_mm, double marker_mm,
                                       const std::string& dictionary) {
  CharucoBoard board;
  if (!internal::ParseColsByRows(squares, &board.squares_x, &board.squares_y)) {
    return InvalidArgumentError("ChArUco board '" + squares + "' is not COLSxROWS (squares, e.g. 7x5)");
  }
  board.square_mm = square_mm;
  board.marker_mm = marker_mm;
  const DictionaryName* d = FindDictionary(dictionary);
  board.dictionary = d != nullptr ? d->name : dictionary;
  ROTOSCAN_RETURN_IF_ERROR(board.Check());
  return board;
}

Result<CharucoDetection> DetectCharuco(const cv::Mat& image, const CharucoBoard& board, int min_corners) {
  ROTOSCAN_RETURN_IF_ERROR(board.Check());
  if (image.empty()) return InvalidArgumentError("empty image");
  if (image.depth() != CV_8U || (image.channels() != 1 && image.channels() != 3)) {
    return InvalidArgumentError("ChArUco detection needs an 8-bit grey or BGR image");
  }
  if (min_corners < 1) return InvalidArgumentError("min_corners must be >= 1");
  cv::Mat gray;
  if (image.channels() == 3) {
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  } else {
    gray = image;
  }
  const cv::Ptr<cv::aruco::CharucoBoard> cv_board = OpenCvBoard(board);
  const cv::Ptr<cv::aruco::DetectorParameters> parameters = cv::aruco::DetectorParameters::create();
  std::vector<std::vector<cv::Point2f>> marker_corners, rejected;
  std::vector<int> marker_ids;
  std::vector<cv::Point2f> corners;
  std::vector<int> ids;
  try {
    cv::aruco::detectMarkers(gray, cv_board->dictionary, marker_corners, marker_ids, parameters, rejected);
    if (!marker_ids.empty()) {
      cv::aruco::refineDetectedMarkers(gray, cv_board, marker_corners, marker_ids, rejected);
      // Each inner corner lies between two markers (diagonally): both must be decoded (minMarkers = 2).
      cv::aruco::interpolateCornersCharuco(marker_corners, marker_ids, gray, cv_board, corners, ids,
                                           cv::noArray(), cv::noArray(), 2);
    }
  } catch (const cv::Exception& e) {
    return InternalError("ChArUco detection failed: " + e.msg);
  }
  const std::string what = "ChArUco board " + board.ToString();
  if (static_cast<int>(ids.size()) < min_corners) {
    return NotFoundError(what + ": " + std::to_string(ids.size()) + " corners found (" +
                         std::to_string(marker_ids.size()) +
                         " markers), need >= " + std::to_string(min_corners));
  }
  if (cv::aruco::testCharucoCornersCollinear(cv_board, ids)) {
    return NotFoundError(what + ": the " + std::to_string(ids.size()) + " corners found lie on one line");
  }
  // interpolateCornersCharuco refines to 0.01 px; finish to 1e-4 px in a window that stays inside the
  // squares around the corner: the markers' edges are (square - marker) / 2 away from it (measured on the
  // simulator's boards, sim/charuco_render_test.cc: a window of 0.9 of that margin is best; a smaller one
  // is ill-conditioned on blurred edges, a larger one is pulled by the markers).
  std::vector<double> sides;
  for (const auto& m : marker_corners) {
    for (int k = 0; k < 4; ++k) {
      const cv::Point2f d = m[k] - m[(k + 1) % 4];
      sides.push_back(std::hypot(d.x, d.y));
    }
  }
  std::nth_element(sides.begin(), sides.begin() + sides.size() / 2, sides.end());
  const double margin_px =
      sides[sides.size() / 2] * (board.square_mm - board.marker_mm) / (2.0 * board.marker_mm);
  const int half = std::clamp(static_cast<int>(std::floor(0.9 * margin_px)), 3, 10);
  cv::cornerSubPix(gray, corners, cv::Size(half, half), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));

  std::vector<std::size_t> order(ids.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return ids[a] < ids[b]; });
  CharucoDetection out;
  out.markers = static_cast<int>(marker_ids.size());
  for (std::size_t i : order) {
    out.ids.push_back(ids[i]);
    out.pixels.emplace_back(corners[i].x, corners[i].y);
    out.corners_in_target.push_back(board.CornerInTarget(ids[i]));
  }
  return out;
}

Status CharucoCalibrationOptions::Check() const {
  ROTOSCAN_RETURN_IF_ERROR(board.Check());
  if (min_views < 3) return InvalidArgumentError("min_views must be >= 3");
  if (min_corners < 4) return InvalidArgumentError("min_corners must be >= 4");
  return Status::Ok();
}

Result<CameraCalibration> CalibrateCameraCharuco(const std::vector<CharucoDetection>& views,
                                                 const std::vector<std::string>& view_names, int image_width,
                                                 int image_height, const CharucoCalibrationOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  ROTOSCAN_CHECK_EQ(views.size(), view_names.size());
  ROTOSCAN_CHECK(image_width > 0 && image_height > 0) << "image size " << image_width << "x" << image_height;
  const int count = static_cast<int>(views.size());
  if (count < options.min_views) {
    return InvalidArgumentError("ChArUco board found in only " + std::to_string(count) +
                                " images: need >= " + std::to_string(options.min_views) +
                                " (capture the board at different tilts and positions across the image)");
  }
  std::vector<std::vector<Eigen::Vector3d>> corners_in_target;
  std::vector<std::vector<Eigen::Vector2d>> corner_pixels;
  for (const CharucoDetection& d : views) {
    corners_in_target.push_back(d.corners_in_target);
    corner_pixels.push_back(d.pixels);
  }
  return internal::CalibrateCorrespondences(corners_in_target, corner_pixels, view_names, image_width,
                                            image_height, options.fix_aspect_ratio, options.zero_tangential);
}

Result<CameraCalibration> CalibrateCameraFromCharucoDirectory(const std::filesystem::path& directory,
                                                              const CharucoCalibrationOptions& options,
                                                              Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  const std::string board = "ChArUco board " + options.board.ToString();
  std::vector<CharucoDetection> views;
  std::vector<std::string> names;
  ROTOSCAN_ASSIGN_OR_RETURN(
      const internal::ImageFolder folder,
      internal::ReadImageFolder(directory, board, options.min_views, "charuco", progress,
                                [&](const cv::Mat& gray, const std::string& name) -> Status {
                                  Result<CharucoDetection> found =
                                      DetectCharuco(gray, options.board, options.min_corners);
                                  if (!found.ok()) return found.status();
                                  views.push_back(std::move(found).value());
                                  names.push_back(name);
                                  return Status::Ok();
                                }));
  const std::string advice =
      " (check that --charuco counts squares, not inner corners, that --dictionary "
      "names the printed board's dictionary, and capture the board sharp, its "
      "markers at least ~20 px wide, at different tilts across the image)";
  if (views.empty()) {
    return NotFoundError(board + " not found in any of the " + std::to_string(folder.readable) +
                         " images in " + directory.string() + ": capture at least " +
                         std::to_string(options.min_views) + " views of it" + advice);
  }
  if (static_cast<int>(views.size()) < options.min_views) {
    return InvalidArgumentError(board + " found in only " + std::to_string(views.size()) + " of " +
                                std::to_string(folder.files) + " images in " + directory.string() +
                                ": need >= " + std::to_string(options.min_views) + advice);
  }
  Result<CameraCalibration> result =
      CalibrateCameraCharuco(views, names, folder.width, folder.height, options);
  if (result.ok()) result->rejected = folder.rejected;
  return result;
}

}  // namespace rotoscan::calib
