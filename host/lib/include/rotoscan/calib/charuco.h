// ChArUco boards (DESIGN.md "Calibration targets"): a checkerboard whose white squares carry ArUco markers
// (OpenCV's aruco module). Every marker names the corners around it, so the corners that are seen are
// identified even when part of the board is hidden, in shadow or out of the image, where a plain
// checkerboard detector needs the whole board. Detection: cv::aruco::detectMarkers (adaptive thresholds,
// which copes with a half-dark board), cv::aruco::refineDetectedMarkers (recovers markers missed at the
// first pass from the board's layout), cv::aruco::interpolateCornersCharuco (local homographies + corner
// refinement), then cv::cornerSubPix again to 1e-4 px.
//
// Frames and units: the board frame is the checkerboard's (calib/camera_calibration.h): origin at the
// first inner corner, x along the columns, y along the rows, z = 0 on the board (into it), mm; OpenCV's
// ChArUco frame has the same axes with its origin one square up-left (at the board's outer corner).
// Corner id i (OpenCV's ChArUco corner id) is inner corner (i % (squares_x - 1), i / (squares_x - 1)),
// the same row-by-row order as CheckerboardPattern::CornersInTarget. The board is described by its
// squares (as OpenCV's CharucoBoard and printed boards are), e.g. "7x5": 6 x 4 inner corners.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"

namespace rotoscan::calib {

struct CharucoBoard {
  int squares_x = 0;                        // squares per row (columns)
  int squares_y = 0;                        // squares per column (rows)
  double square_mm = 0.0;                   // side of one square
  double marker_mm = 0.0;                   // side of one marker (black border included), < square_mm
  std::string dictionary = "DICT_5X5_100";  // OpenCV's predefined dictionary name

  // Sizes, the dictionary's name and that it has a marker for every white square.
  Status Check() const;
  int CornerCount() const { return (squares_x - 1) * (squares_y - 1); }
  int MarkerCount() const { return squares_x * squares_y / 2; }
  // Inner corner `id` in the board frame (mm). ROTOSCAN_CHECK: 0 <= id < CornerCount().
  Eigen::Vector3d CornerInTarget(int id) const;
  // Every inner corner, by id.
  std::vector<Eigen::Vector3d> CornersInTarget() const;
  // The board image (CV_8UC1, 0 black / 255 white), `pixels_per_square` pixels per square, no margin:
  // pixel (u, v) (integer indices) covers [u, u + 1) x [v, v + 1) * square_mm / pixels_per_square of the
  // board measured from its outer corner, i.e. target point x = (u / pixels_per_square - 1) * square_mm.
  // Call Check() first (ROTOSCAN_CHECK).
  cv::Mat Draw(int pixels_per_square) const;
  // A pixels_per_square in [min, max] for which every marker cell and margin falls on whole pixels
  // (OpenCV then draws the markers without resampling), else the largest value <= max.
  int CrispPixelsPerSquare(int min_pixels, int max_pixels) const;
  std::string ToString() const;  // "7x5 squares of 10 mm, markers 7 mm, DICT_5X5_100"
};

// The names CharucoBoard::dictionary accepts (DICT_4X4_50 ... DICT_APRILTAG_36h11).
std::vector<std::string> CharucoDictionaryNames();

// Parses "COLSxROWS" (squares, e.g. "7x5") into a checked board; kInvalidArgument naming the bad value.
// `dictionary` may omit the "DICT_" prefix and is case-insensitive ("5x5_100").
Result<CharucoBoard> ParseCharucoBoard(const std::string& squares, double square_mm, double marker_mm,
                                       const std::string& dictionary = "DICT_5X5_100");

struct CharucoDetection {
  std::vector<int> ids;                            // corner ids, ascending
  std::vector<Eigen::Vector2d> pixels;             // same order, sub-pixel (geometry/camera.h convention)
  std::vector<Eigen::Vector3d> corners_in_target;  // same order, board frame, mm
  int markers = 0;                                 // ArUco markers decoded
};

// The board's corners seen in an 8-bit grey or BGR image. A corner is kept when both markers next to it
// (every inner corner touches two white squares) are decoded. kNotFound when fewer than `min_corners` corners
// are found, or when they all lie on one line (no pose from them); kInvalidArgument for a bad image or board.
Result<CharucoDetection> DetectCharuco(const cv::Mat& image, const CharucoBoard& board, int min_corners = 4);

struct CharucoCalibrationOptions {
  CharucoBoard board;
  int min_views = 6;              // fewer views with the board found is an error saying what to capture
  int min_corners = 8;            // fewer corners found in an image: the image is not used
  bool fix_aspect_ratio = false;  // fx = fy
  bool zero_tangential = false;   // p1 = p2 = 0
  Status Check() const;
};

// Camera intrinsics from per-view detections (all images of one size), cv::calibrateCamera on the
// corners found (any subset of the board per view). corner_pixels of the result hold each view's
// detected corners. kInvalidArgument when fewer than options.min_views; kNotConverged when OpenCV fails.
Result<CameraCalibration> CalibrateCameraCharuco(const std::vector<CharucoDetection>& views,
                                                 const std::vector<std::string>& view_names, int image_width,
                                                 int image_height, const CharucoCalibrationOptions& options);

// Every image (png, jpg, jpeg, bmp, tif, tiff; sorted by name) in `directory`, as
// CalibrateCameraFromDirectory does for checkerboards; the errors name the directory and say what to
// capture (no image, no board found in any image, found in too few).
Result<CameraCalibration> CalibrateCameraFromCharucoDirectory(const std::filesystem::path& directory,
                                                              const CharucoCalibrationOptions& options,
                                                              Progress* progress = nullptr);

}  // namespace rotoscan::calib
