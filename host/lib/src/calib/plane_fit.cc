#include "rotoscan/calib/plane_fit.h"

#include <cmath>
#include <random>
#include <string>

#include <Eigen/Eigenvalues>
#include <Eigen/QR>

#include "rotoscan/core/check.h"

namespace rotoscan::calib {
namespace {

Status CheckPoints(const std::vector<Eigen::Vector3d>& points) {
  if (points.size() < 3) {
    return InvalidArgumentError("a plane needs at least 3 points, got " + std::to_string(points.size()));
  }
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!points[i].allFinite())
      return InvalidArgumentError("plane point " + std::to_string(i) + " is not finite");
  }
  return Status::Ok();
}

// Fills rms / max / inliers from the points flagged in `mask`.
void Score(const std::vector<Eigen::Vector3d>& points, const std::vector<bool>& mask, PlaneFit* fit) {
  double sum_sq = 0.0;
  int count = 0;
  fit->max_abs_mm = 0.0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!mask[i]) continue;
    const double d = fit->plane.SignedDistance(points[i]);
    sum_sq += d * d;
    fit->max_abs_mm = std::max(fit->max_abs_mm, std::abs(d));
    ++count;
  }
  fit->inliers = count;
  fit->rms_mm = count > 0 ? std::sqrt(sum_sq / count) : 0.0;
  fit->inlier_mask = mask;
}

// Total least squares on the masked points; kInvalidArgument when they are collinear.
Result<geometry::Plane> TlsPlane(const std::vector<Eigen::Vector3d>& points, const std::vector<bool>& mask) {
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  int count = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (mask[i]) {
      centroid += points[i];
      ++count;
    }
  }
  if (count < 3) return InvalidArgumentError("a plane needs at least 3 points, got " + std::to_string(count));
  centroid /= count;
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (mask[i]) scatter += (points[i] - centroid) * (points[i] - centroid).transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(scatter);  // ascending eigenvalues
  const Eigen::Vector3d values = eigen.eigenvalues();
  if (!(values(1) > 1e-12 * std::max(values(2), 1e-300))) {
    return InvalidArgumentError("plane points are collinear: the plane is not determined");
  }
  return geometry::Plane::FromPointNormal(centroid, eigen.eigenvectors().col(0));
}

}  // namespace

Status RobustPlaneOptions::Check() const {
  if (!(inlier_threshold_mm > 0)) return InvalidArgumentError("inlier_threshold_mm must be > 0");
  if (iterations < 1) return InvalidArgumentError("iterations must be >= 1");
  if (!(min_inlier_fraction > 0 && min_inlier_fraction <= 1)) {
    return InvalidArgumentError("min_inlier_fraction must be in (0, 1]");
  }
  return Status::Ok();
}

Result<PlaneFit> FitPlanePaper(const std::vector<Eigen::Vector3d>& points) {
  ROTOSCAN_RETURN_IF_ERROR(CheckPoints(points));
  // Eq. 11: P_w C = -1; eq. 12 by a QR solve (same solution as the normal equations, better conditioned).
  Eigen::MatrixXd p(points.size(), 3);
  for (std::size_t i = 0; i < points.size(); ++i) p.row(i) = points[i].transpose();
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(p);
  if (qr.rank() < 3) {
    return InvalidArgumentError(
        "eq. 12 is singular: the points are collinear or on a plane through the origin");
  }
  const Eigen::Vector3d c = qr.solve(-Eigen::VectorXd::Ones(points.size()));
  if (!c.allFinite() || c.norm() == 0.0) return InvalidArgumentError("eq. 12 gave no plane");
  PlaneFit fit;
  fit.plane = geometry::Plane::FromPaperCoefficients(c);
  Score(points, std::vector<bool>(points.size(), true), &fit);
  return fit;
}

Result<PlaneFit> FitPlaneTotalLeastSquares(const std::vector<Eigen::Vector3d>& points) {
  ROTOSCAN_RETURN_IF_ERROR(CheckPoints(points));
  const std::vector<bool> all(points.size(), true);
  ROTOSCAN_ASSIGN_OR_RETURN(geometry::Plane plane, TlsPlane(points, all));
  PlaneFit fit;
  fit.plane = plane;
  Score(points, all, &fit);
  return fit;
}

Result<PlaneFit> FitPlaneRobust(const std::vector<Eigen::Vector3d>& points,
                                const RobustPlaneOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  ROTOSCAN_RETURN_IF_ERROR(CheckPoints(points));
  const int n = static_cast<int>(points.size());
  std::mt19937 rng(options.seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  int best_count = -1;
  double best_cost = 0.0;
  std::vector<bool> best_mask(n, false);
  std::vector<bool> mask(n);
  for (int it = 0; it < options.iterations; ++it) {
    const int i = pick(rng), j = pick(rng), k = pick(rng);
    const Eigen::Vector3d normal = (points[j] - points[i]).cross(points[k] - points[i]);
    if (!(normal.norm() > 1e-9 * (points[j] - points[i]).squaredNorm())) continue;  // degenerate sample
    const geometry::Plane candidate = geometry::Plane::FromPointNormal(points[i], normal);
    int count = 0;
    double cost = 0.0;  // MSAC-style truncated cost breaks ties between equal counts
    for (int m = 0; m < n; ++m) {
      const double d = std::abs(candidate.SignedDistance(points[m]));
      mask[m] = d <= options.inlier_threshold_mm;
      count += mask[m] ? 1 : 0;
      cost += std::min(d * d, options.inlier_threshold_mm * options.inlier_threshold_mm);
    }
    if (count > best_count || (count == best_count && cost < best_cost)) {
      best_count = count;
      best_cost = cost;
      best_mask = mask;
    }
  }
  if (best_count < 3) return InvalidArgumentError("plane points are collinear: the plane is not determined");
  // Refit on the inliers, then re-select the inliers against the refined plane once.
  ROTOSCAN_ASSIGN_OR_RETURN(geometry::Plane plane, TlsPlane(points, best_mask));
  for (int m = 0; m < n; ++m)
    best_mask[m] = std::abs(plane.SignedDistance(points[m])) <= options.inlier_threshold_mm;
  ROTOSCAN_ASSIGN_OR_RETURN(plane, TlsPlane(points, best_mask));
  PlaneFit fit;
  fit.plane = plane;
  Score(points, best_mask, &fit);
  if (fit.inliers < options.min_inlier_fraction * n) {
    return NotConvergedError("only " + std::to_string(fit.inliers) + " of " + std::to_string(n) +
                             " points lie within " + std::to_string(options.inlier_threshold_mm) +
                             " mm of the best plane: the points do not come from one plane");
  }
  return fit;
}

}  // namespace rotoscan::calib
