// The paper's calibration object (§4.1, Fig. 6): two orthogonal planes with a checker of 10 mm squares,
// standing on the table with its fold (the line where the planes meet) upright and its opening towards the
// camera. Its corners are not coplanar, which is what the DLT of step 1 (eq. 8-10) needs.
//
// Target frame (the virtual scanner's, sim/simulate.h): origin at the foot of the fold, z up the fold; the
// face seen on the left of the image is the plane y = 0 (x >= 0 along it, away from the fold), the face on
// the right is x = 0 (y >= 0 along it). Both faces are size x size mm with squares of square_mm from the
// fold and the foot, so their inner corners sit at (i * square, 0, j * square) and (0, i * square,
// j * square), i, j = 1 .. corners_per_side. The fold itself is no corner: the checker folds over it.
//
// Detection: each face is an n x n inner-corner checker (OpenCV's findChessboardCornersSB finds one face,
// whose area is then blacked out before looking for the other one); a face's grid is labelled by the
// camera being upright (z up the fold runs up the image) and by the face's side of the image. The 2 n^2
// corners are then checked against one projection matrix (DLT): a grid found across the fold, or a
// corner found on the wrong square, does not fit one and the view is refused.
#pragma once

#include <array>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include "rotoscan/core/status.h"

namespace rotoscan::calib {

struct CalibrationObjectSpec {
  double square_mm = 10.0;
  int corners_per_side = 5;  // inner corners per face and direction (a 60 mm face of 10 mm squares: 5)
  Status Check() const;
};

struct CalibrationObjectFace {
  Eigen::Vector4d plane_in_target;         // (n, d): n . X + d = 0, target frame
  std::array<Eigen::Vector2d, 4> outline;  // image quad of the face, half a square inside its edges
};

struct CalibrationObjectCorners {
  std::vector<Eigen::Vector3d> corners_in_target;  // mm; the y = 0 face first, then the x = 0 face
  std::vector<Eigen::Vector2d> pixels;             // sub-pixel, same order
  std::array<CalibrationObjectFace, 2> faces;      // [0]: y = 0 (left in the image), [1]: x = 0 (right)
  double dlt_rms_px = 0.0;                         // consistency check of the labelled corners
};

// Finds both faces of the object in an 8-bit grey or BGR image. kNotFound (saying what to capture) when
// a face is not found whole or the corners do not fit one camera; kInvalidArgument for a bad image.
Result<CalibrationObjectCorners> DetectCalibrationObject(const cv::Mat& image,
                                                         const CalibrationObjectSpec& spec);

}  // namespace rotoscan::calib
