#include "rotoscan/calib/calibration_object.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "rotoscan/geometry/dlt.h"

namespace rotoscan::calib {
namespace {

// The largest DLT reprojection RMS of a correctly labelled object (noise and the lens' distortion, which
// the DLT does not model, stay well below it).
constexpr double kMaxDltRmsPx = 3.0;

struct FaceGrid {
  // pixel[a][b]: a = index along the face away from the fold, b = index up the fold.
  std::vector<std::vector<Eigen::Vector2d>> pixel;
  cv::Mat index_to_image;  // homography from (a, b) to pixels
  double mean_x = 0.0;
};

std::string Size(const CalibrationObjectSpec& spec) {
  return std::to_string(spec.corners_per_side) + "x" + std::to_string(spec.corners_per_side);
}

// One face's n x n grid found by OpenCV, with its grid directions labelled so that b runs up the image;
// `a` runs in the image's +x direction for now (SetFoldSide flips it).
bool FindFace(const cv::Mat& gray, int n, FaceGrid* face) {
  std::vector<cv::Point2f> corners;
  if (!cv::findChessboardCornersSB(gray, cv::Size(n, n), corners, cv::CALIB_CB_ACCURACY) ||
      static_cast<int>(corners.size()) != n * n) {
    return false;
  }
  const double window = 5.0;
  cv::cornerSubPix(gray, corners, cv::Size(static_cast<int>(window), static_cast<int>(window)),
                   cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-3));
  // OpenCV's order: corners[r * n + c]. Which of r and c runs up the image, and which way?
  auto at = [&](int r, int c) { return Eigen::Vector2d(corners[r * n + c].x, corners[r * n + c].y); };
  const Eigen::Vector2d along_c = at(0, n - 1) - at(0, 0);
  const Eigen::Vector2d along_r = at(n - 1, 0) - at(0, 0);
  const bool c_is_vertical = std::abs(along_c.y()) * along_r.norm() > std::abs(along_r.y()) * along_c.norm();
  const Eigen::Vector2d vertical = c_is_vertical ? along_c : along_r;
  const Eigen::Vector2d horizontal = c_is_vertical ? along_r : along_c;
  const bool flip_b = vertical.y() > 0;    // b must run up the image (towards smaller rows)
  const bool flip_a = horizontal.x() < 0;  // a runs towards +x for now
  face->pixel.assign(n, std::vector<Eigen::Vector2d>(n));
  std::vector<cv::Point2f> index_points, image_points;
  face->mean_x = 0.0;
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      int a = c_is_vertical ? r : c;
      int b = c_is_vertical ? c : r;
      if (flip_a) a = n - 1 - a;
      if (flip_b) b = n - 1 - b;
      face->pixel[a][b] = at(r, c);
      index_points.emplace_back(static_cast<float>(a), static_cast<float>(b));
      image_points.push_back(corners[r * n + c]);
      face->mean_x += corners[r * n + c].x / (n * n);
    }
  }
  face->index_to_image = cv::findHomography(index_points, image_points, 0);
  return !face->index_to_image.empty();
}

// Image points of grid positions (a, b) (fractional, outside the grid too) of a face.
std::vector<cv::Point2f> GridToImage(const FaceGrid& face, const std::vector<cv::Point2f>& grid) {
  std::vector<cv::Point2f> image;
  cv::perspectiveTransform(grid, image, face.index_to_image);
  return image;
}

// Re-labels `a` of a face so that it runs away from the fold, given on which side of the image the fold is.
void SetFoldSide(bool fold_on_the_right, FaceGrid* face) {
  // `a` runs towards +x: away from the fold when the fold is on the left.
  if (!fold_on_the_right) return;
  std::reverse(face->pixel.begin(), face->pixel.end());
  const int n = static_cast<int>(face->pixel.size());
  cv::Mat flip = (cv::Mat_<double>(3, 3) << -1, 0, n - 1, 0, 1, 0, 0, 0, 1);
  face->index_to_image = face->index_to_image * flip;
}

}  // namespace

Status CalibrationObjectSpec::Check() const {
  if (!(square_mm > 0) || !std::isfinite(square_mm)) {
    return InvalidArgumentError("calibration object: square size must be > 0 mm");
  }
  if (corners_per_side < 3 || corners_per_side > 50) {
    return InvalidArgumentError("calibration object: corners per side must be in [3, 50]");
  }
  return Status::Ok();
}

Result<CalibrationObjectCorners> DetectCalibrationObject(const cv::Mat& image,
                                                         const CalibrationObjectSpec& spec) {
  ROTOSCAN_RETURN_IF_ERROR(spec.Check());
  if (image.empty()) return InvalidArgumentError("empty image");
  if (image.depth() != CV_8U || (image.channels() != 1 && image.channels() != 3)) {
    return InvalidArgumentError("calibration object detection needs an 8-bit grey or BGR image");
  }
  cv::Mat gray;
  if (image.channels() == 3) {
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  } else {
    gray = image.clone();
  }
  const int n = spec.corners_per_side;
  std::array<FaceGrid, 2> found;
  cv::Mat work = gray.clone();
  for (int k = 0; k < 2; ++k) {
    if (!FindFace(work, n, &found[k])) {
      return NotFoundError("calibration object: " + std::string(k == 0 ? "no face" : "only one face") +
                           " with " + Size(spec) +
                           " inner corners found (both faces and their whole grids must be in view, neither "
                           "face edge-on)");
    }
    // Black out the face found, up to its edges, so that the next search finds the other face.
    const std::vector<cv::Point2f> edge =
        GridToImage(found[k], {{-1.0f, -1.0f},
                               {static_cast<float>(n), -1.0f},
                               {static_cast<float>(n), static_cast<float>(n)},
                               {-1.0f, static_cast<float>(n)}});
    std::vector<cv::Point> polygon;
    for (const auto& p : edge) polygon.emplace_back(cvRound(p.x), cvRound(p.y));
    cv::fillConvexPoly(work, polygon, cv::Scalar(0));
  }
  // The y = 0 face is the one on the left; its fold is on its right.
  if (found[0].mean_x > found[1].mean_x) std::swap(found[0], found[1]);
  SetFoldSide(true, &found[0]);
  SetFoldSide(false, &found[1]);

  CalibrationObjectCorners out;
  const double s = spec.square_mm;
  for (int f = 0; f < 2; ++f) {
    for (int a = 0; a < n; ++a) {
      for (int b = 0; b < n; ++b) {
        const double u = (a + 1) * s, z = (b + 1) * s;
        out.corners_in_target.push_back(f == 0 ? Eigen::Vector3d(u, 0, z) : Eigen::Vector3d(0, u, z));
        out.pixels.push_back(found[f].pixel[a][b]);
      }
    }
    out.faces[f].plane_in_target = f == 0 ? Eigen::Vector4d(0, 1, 0, 0) : Eigen::Vector4d(1, 0, 0, 0);
    const float lo = -0.5f, hi = static_cast<float>(n) - 0.5f;
    const std::vector<cv::Point2f> quad = GridToImage(found[f], {{lo, lo}, {hi, lo}, {hi, hi}, {lo, hi}});
    for (int i = 0; i < 4; ++i) out.faces[f].outline[i] = Eigen::Vector2d(quad[i].x, quad[i].y);
  }
  Result<geometry::DltEstimate> dlt = geometry::EstimateProjectionDlt(out.corners_in_target, out.pixels);
  if (!dlt.ok()) return NotFoundError("calibration object: " + dlt.status().message());
  out.dlt_rms_px = dlt->rms_px;
  if (dlt->rms_px > kMaxDltRmsPx) {
    return NotFoundError("calibration object: the corners found do not fit one camera (DLT RMS " +
                         std::to_string(dlt->rms_px) +
                         " px): a grid was found across the fold or on the wrong squares; turn the object so "
                         "that both faces are seen at a similar angle");
  }
  return out;
}

}  // namespace rotoscan::calib
