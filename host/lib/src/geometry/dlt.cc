#include "rotoscan/geometry/dlt.h"

#include <cmath>
#include <string>

#include <Eigen/QR>
#include <Eigen/SVD>

#include "rotoscan/core/check.h"

namespace rotoscan::geometry {
namespace {

// Similarity that moves the centroid of `points` to the origin and scales their mean distance from it to
// sqrt(dim) (Hartley normalisation). Returns false when all points coincide.
template <int kDim>
bool NormalisingTransform(const std::vector<Eigen::Matrix<double, kDim, 1>>& points,
                          Eigen::Matrix<double, kDim + 1, kDim + 1>* transform) {
  Eigen::Matrix<double, kDim, 1> centroid = Eigen::Matrix<double, kDim, 1>::Zero();
  for (const auto& p : points) centroid += p;
  centroid /= static_cast<double>(points.size());
  double mean_distance = 0.0;
  for (const auto& p : points) mean_distance += (p - centroid).norm();
  mean_distance /= static_cast<double>(points.size());
  if (!(mean_distance > 0.0) || !std::isfinite(mean_distance)) return false;
  const double scale = std::sqrt(static_cast<double>(kDim)) / mean_distance;
  transform->setIdentity();
  transform->template topLeftCorner<kDim, kDim>() *= scale;
  transform->template topRightCorner<kDim, 1>() = -scale * centroid;
  return true;
}

}  // namespace

Eigen::Vector2d ProjectWithMatrix(const ProjectionMatrix& projection,
                                  const Eigen::Vector3d& point_in_object) {
  const Eigen::Vector3d h = projection * point_in_object.homogeneous();
  ROTOSCAN_CHECK(h.z() != 0.0) << "point on the principal plane of the projection";
  return h.hnormalized();
}

Result<DltEstimate> EstimateProjectionDlt(const std::vector<Eigen::Vector3d>& points_in_object,
                                          const std::vector<Eigen::Vector2d>& pixels) {
  ROTOSCAN_CHECK_EQ(points_in_object.size(), pixels.size());
  const int n = static_cast<int>(points_in_object.size());
  if (n < 6) {
    return InvalidArgumentError(
        "DLT needs at least 6 point correspondences (11 unknowns, 2 equations each), got " +
        std::to_string(n));
  }
  for (int i = 0; i < n; ++i) {
    if (!points_in_object[i].allFinite() || !pixels[i].allFinite()) {
      return InvalidArgumentError("DLT correspondence " + std::to_string(i) + " is not finite");
    }
  }
  Eigen::Matrix4d t3;
  Eigen::Matrix3d t2;
  if (!NormalisingTransform<3>(points_in_object, &t3)) {
    return InvalidArgumentError("DLT object points all coincide");
  }
  if (!NormalisingTransform<2>(pixels, &t2)) return InvalidArgumentError("DLT pixels all coincide");

  // Coplanar (or collinear) object points: the smallest principal extent vanishes next to the largest.
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const auto& p : points_in_object) {
    const Eigen::Vector3d q = (t3 * p.homogeneous()).head<3>();
    scatter += q * q.transpose();
  }
  const Eigen::Vector3d extents = Eigen::JacobiSVD<Eigen::Matrix3d>(scatter).singularValues();
  if (extents(2) < 1e-8 * extents(0)) {
    return InvalidArgumentError(
        "DLT object points are coplanar or collinear: the projection matrix is not determined; use points "
        "on at least two planes (e.g. the two orthogonal faces of the calibration object)");
  }

  // Eq. 9 on normalised coordinates: rows [0, -X, y X] and [X, 0, -x X] per point.
  Eigen::MatrixXd a(2 * n, 12);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector4d x = t3 * points_in_object[i].homogeneous();
    const Eigen::Vector3d u = t2 * pixels[i].homogeneous();
    a.row(2 * i) << Eigen::RowVector4d::Zero(), -x.transpose(), u.y() * x.transpose();
    a.row(2 * i + 1) << x.transpose(), Eigen::RowVector4d::Zero(), -u.x() * x.transpose();
  }
  // Eq. 10: the unit X minimising |A X|.
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeFullV);
  const Eigen::VectorXd sv = svd.singularValues();
  if (sv(10) < 1e-10 * sv(0)) {
    return InvalidArgumentError("DLT system is rank deficient (degenerate point configuration)");
  }
  const Eigen::VectorXd x = svd.matrixV().col(11);
  ProjectionMatrix normalised;
  normalised.row(0) = x.segment<4>(0).transpose();
  normalised.row(1) = x.segment<4>(4).transpose();
  normalised.row(2) = x.segment<4>(8).transpose();
  ProjectionMatrix projection = t2.inverse() * normalised * t3;

  // Fix scale and sign: unit third row direction, points in front (w > 0) for most of the input.
  const double row_norm = projection.block<1, 3>(2, 0).norm();
  if (!(row_norm > 0.0))
    return InvalidArgumentError("DLT solution has a zero principal ray (degenerate input)");
  projection /= row_norm;
  int in_front = 0;
  for (const auto& p : points_in_object) in_front += (projection.row(2) * p.homogeneous() > 0.0) ? 1 : 0;
  if (2 * in_front < n) projection = -projection;

  DltEstimate estimate;
  estimate.projection = projection;
  double sum_sq = 0.0;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d h = projection * points_in_object[i].homogeneous();
    if (h.z() <= 0.0)
      return InvalidArgumentError("DLT: point " + std::to_string(i) + " lies behind the camera");
    const double e = (h.hnormalized() - pixels[i]).norm();
    sum_sq += e * e;
    estimate.max_px = std::max(estimate.max_px, e);
  }
  estimate.rms_px = std::sqrt(sum_sq / n);
  return estimate;
}

Result<ProjectionDecomposition> DecomposeProjection(const ProjectionMatrix& projection) {
  Eigen::Matrix3d m = projection.leftCols<3>();
  Eigen::Vector3d p4 = projection.col(3);
  const double det = m.determinant();
  if (!std::isfinite(det) || std::abs(det) < 1e-12 * std::pow(m.norm(), 3)) {
    return InvalidArgumentError("projection matrix has a singular left 3x3 block: not a finite camera");
  }
  if (det < 0) {  // T is defined up to scale, including its sign: pick det(M) > 0 so that det(R) = +1.
    m = -m;
    p4 = -p4;
  }
  // RQ of M through QR of the row-reversed transpose: with J the exchange matrix, (J M)^T = Q U gives
  // M = (J U^T J) (J Q^T), the first factor upper triangular, the second orthogonal.
  Eigen::Matrix3d j = Eigen::Matrix3d::Zero();
  j(0, 2) = j(1, 1) = j(2, 0) = 1.0;
  Eigen::HouseholderQR<Eigen::Matrix3d> qr((j * m).transpose());
  const Eigen::Matrix3d q = qr.householderQ();
  const Eigen::Matrix3d u = qr.matrixQR().triangularView<Eigen::Upper>();
  Eigen::Matrix3d k = j * u.transpose() * j;
  Eigen::Matrix3d r = j * q.transpose();
  // Make K's diagonal positive: K D, D R with D = diag(sign(K_ii)) (D D = I).
  const Eigen::Vector3d signs(k(0, 0) < 0 ? -1 : 1, k(1, 1) < 0 ? -1 : 1, k(2, 2) < 0 ? -1 : 1);
  k = k * signs.asDiagonal();
  r = signs.asDiagonal() * r;
  if (r.determinant() < 0) return InternalError("RQ decomposition produced a reflection");
  const Eigen::Vector3d t = k.inverse() * p4;
  ProjectionDecomposition out;
  out.K = k / k(2, 2);
  out.cam_from_object.linear() = r;
  out.cam_from_object.translation() = t;
  return out;
}

Result<Eigen::Vector3d> TriangulateWithPlane(const ProjectionMatrix& projection, const Plane& plane_in_object,
                                             const Eigen::Vector2d& pixel) {
  const double xp = pixel.x(), yp = pixel.y();
  const ProjectionMatrix& t = projection;
  // Eq. 6 with the third row n . X = -d (the paper divides by d to get c . X = -1).
  Eigen::Matrix3d a;
  a.row(0) = xp * t.block<1, 3>(2, 0) - t.block<1, 3>(0, 0);
  a.row(1) = yp * t.block<1, 3>(2, 0) - t.block<1, 3>(1, 0);
  a.row(2) = plane_in_object.normal.transpose();
  const Eigen::Vector3d b(-xp * t(2, 3) + t(0, 3), -yp * t(2, 3) + t(1, 3), -plane_in_object.offset);
  // The system is singular when the ray through the pixel is parallel to the plane; compare the
  // determinant with the product of the row norms (the determinant of orthogonal rows of the same lengths).
  const double scale = a.row(0).norm() * a.row(1).norm() * a.row(2).norm();
  if (!(std::abs(a.determinant()) > 1e-12 * scale)) {
    return InvalidArgumentError("the viewing ray of the pixel is parallel to the plane: no intersection");
  }
  return Eigen::Vector3d(a.partialPivLu().solve(b));
}

Result<Eigen::Matrix3d> EstimateHomographyDlt(const std::vector<Eigen::Vector2d>& from,
                                              const std::vector<Eigen::Vector2d>& to) {
  ROTOSCAN_CHECK_EQ(from.size(), to.size());
  const int n = static_cast<int>(from.size());
  if (n < 4) {
    return InvalidArgumentError(
        "homography needs at least 4 correspondences (8 unknowns, 2 equations each), got " +
        std::to_string(n));
  }
  for (int i = 0; i < n; ++i) {
    if (!from[i].allFinite() || !to[i].allFinite()) {
      return InvalidArgumentError("homography correspondence " + std::to_string(i) + " is not finite");
    }
  }
  Eigen::Matrix3d tf, tt;
  if (!NormalisingTransform<2>(from, &tf) || !NormalisingTransform<2>(to, &tt)) {
    return InvalidArgumentError("homography points all coincide");
  }
  // Rows [0, -x, y' x] and [x, 0, -x' x] per point, on normalised coordinates.
  Eigen::MatrixXd a(2 * n, 9);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d x = tf * from[i].homogeneous();
    const Eigen::Vector3d y = tt * to[i].homogeneous();
    a.row(2 * i) << Eigen::RowVector3d::Zero(), -x.transpose(), y.y() * x.transpose();
    a.row(2 * i + 1) << x.transpose(), Eigen::RowVector3d::Zero(), -y.x() * x.transpose();
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeFullV);
  if (svd.singularValues()(7) < 1e-9 * svd.singularValues()(0)) {
    return InvalidArgumentError("homography system is rank deficient (degenerate point configuration)");
  }
  const Eigen::VectorXd h = svd.matrixV().col(8);
  Eigen::Matrix3d normalised;
  normalised << h(0), h(1), h(2), h(3), h(4), h(5), h(6), h(7), h(8);
  const Eigen::Matrix3d homography = tt.inverse() * normalised * tf;
  if (!homography.allFinite()) return InvalidArgumentError("homography is not finite (degenerate input)");
  return homography;
}

}  // namespace rotoscan::geometry
