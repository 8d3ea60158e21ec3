#include "rotoscan/calib/axis_fit.h"

#include <cmath>
#include <string>

#include <Eigen/QR>

#include "rotoscan/calib/plane_fit.h"

namespace rotoscan::calib {

Result<CircleFit2d> FitCircle2d(const std::vector<Eigen::Vector2d>& points) {
  const int n = static_cast<int>(points.size());
  if (n < 3) return InvalidArgumentError("a circle needs at least 3 points, got " + std::to_string(n));
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : points) {
    if (!p.allFinite()) return InvalidArgumentError("circle point is not finite");
    mean += p;
  }
  mean /= n;
  // Eq. 14 on points taken relative to their mean (same solution, better conditioned), eq. 15 by QR.
  Eigen::MatrixXd a(n, 3);
  Eigen::VectorXd b(n);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d q = points[i] - mean;
    a.row(i) << -2.0 * q.x(), -2.0 * q.y(), 1.0;
    b(i) = -q.squaredNorm();
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  qr.setThreshold(1e-10);
  if (qr.rank() < 3) return InvalidArgumentError("circle points are collinear: no rotation centre");
  const Eigen::Vector3d x = qr.solve(b);
  const double r2 = x.head<2>().squaredNorm() - x(2);  // eq. 13: l = x_r^2 + y_r^2 - r^2
  if (!(r2 > 0.0)) return InvalidArgumentError("circle fit gave no real radius (points not on a circle)");
  CircleFit2d fit;
  fit.centre = x.head<2>() + mean;
  fit.radius = std::sqrt(r2);
  double sum_sq = 0.0;
  for (const auto& p : points) {
    const double e = (p - fit.centre).norm() - fit.radius;
    sum_sq += e * e;
  }
  fit.rms = std::sqrt(sum_sq / n);
  return fit;
}

Result<CircleFit3d> FitCircle3d(const std::vector<Eigen::Vector3d>& points) {
  if (points.size() < 3) {
    return InvalidArgumentError("a circle needs at least 3 points, got " + std::to_string(points.size()));
  }
  ROTOSCAN_ASSIGN_OR_RETURN(const PlaneFit plane, FitPlaneTotalLeastSquares(points));
  const Eigen::Vector3d normal = plane.plane.normal;
  const Eigen::Vector3d origin = -plane.plane.offset * normal;  // the plane point closest to the origin
  const Eigen::Vector3d u = normal.unitOrthogonal();
  const Eigen::Vector3d v = normal.cross(u);
  std::vector<Eigen::Vector2d> in_plane;
  in_plane.reserve(points.size());
  for (const auto& p : points) in_plane.emplace_back(u.dot(p - origin), v.dot(p - origin));
  ROTOSCAN_ASSIGN_OR_RETURN(const CircleFit2d circle, FitCircle2d(in_plane));
  CircleFit3d fit;
  fit.normal = normal;
  fit.centre = origin + circle.centre.x() * u + circle.centre.y() * v;
  fit.radius = circle.radius;
  double sum_sq = 0.0;
  for (const auto& p : points) {
    const double h = normal.dot(p - fit.centre);
    const double rho = ((p - fit.centre) - h * normal).norm();
    sum_sq += h * h + (rho - fit.radius) * (rho - fit.radius);
  }
  fit.rms = std::sqrt(sum_sq / points.size());
  return fit;
}

Result<AxisFit> FitAxisFromTracks(const std::vector<std::vector<Eigen::Vector3d>>& tracks) {
  if (tracks.empty()) return InvalidArgumentError("no tracked points to fit the table axis to");
  std::vector<CircleFit3d> circles;
  std::vector<double> weights;
  for (std::size_t k = 0; k < tracks.size(); ++k) {
    Result<CircleFit3d> circle = FitCircle3d(tracks[k]);
    if (!circle.ok()) return circle.status().WithContext("track " + std::to_string(k));
    circles.push_back(*circle);
    weights.push_back(static_cast<double>(tracks[k].size()));
  }
  AxisFit fit;
  Eigen::Vector3d direction = Eigen::Vector3d::Zero();
  for (std::size_t k = 0; k < circles.size(); ++k) {
    const double sign = circles[k].normal.dot(circles[0].normal) < 0 ? -1.0 : 1.0;
    direction += weights[k] * sign * circles[k].normal;
  }
  fit.direction = direction.normalized();
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  double weight_sum = 0.0;
  for (std::size_t k = 0; k < circles.size(); ++k) {
    const Eigen::Vector3d c = circles[k].centre;
    point += weights[k] * (c - fit.direction.dot(c - circles[0].centre) * fit.direction);
    weight_sum += weights[k];
  }
  fit.point = point / weight_sum;
  double sum_sq = 0.0;
  for (std::size_t k = 0; k < circles.size(); ++k) {
    const Eigen::Vector3d off = circles[k].centre - fit.point;
    const double d = (off - fit.direction.dot(off) * fit.direction).norm();
    sum_sq += weights[k] * (circles[k].rms * circles[k].rms + d * d);
  }
  fit.rms_mm = std::sqrt(sum_sq / weight_sum);
  return fit;
}

Result<AxisFit> FitAxisFromPoses(const std::vector<Eigen::Isometry3d>& cam_from_target) {
  const int n = static_cast<int>(cam_from_target.size());
  if (n < 2)
    return InvalidArgumentError("the table axis needs the target in at least 2 table positions, got " +
                                std::to_string(n));
  const Eigen::Matrix3d r0 = cam_from_target[0].linear();
  const Eigen::Vector3d t0 = cam_from_target[0].translation();
  // Direction: angle-weighted mean of the axes of R_i R_0^T, signs aligned to the first turn.
  Eigen::Vector3d direction = Eigen::Vector3d::Zero();
  Eigen::Vector3d reference = Eigen::Vector3d::Zero();
  for (int i = 1; i < n; ++i) {
    const Eigen::AngleAxisd turn(cam_from_target[i].linear() * r0.transpose());
    if (turn.angle() < 1e-6) continue;
    if (reference.isZero()) reference = turn.axis();
    direction += turn.angle() * (turn.axis().dot(reference) < 0 ? -1.0 : 1.0) * turn.axis();
  }
  if (direction.norm() < 1e-9) {
    return InvalidArgumentError(
        "the target did not turn between the poses: the table axis is not determined");
  }
  AxisFit fit;
  fit.direction = direction.normalized();
  // Point: (I - R_i0) c = t_i - R_i0 t_0, and a . c = a . t_0 (the point at the target origin's height).
  Eigen::MatrixXd a(3 * (n - 1) + 1, 3);
  Eigen::VectorXd b(3 * (n - 1) + 1);
  for (int i = 1; i < n; ++i) {
    const Eigen::Matrix3d r = cam_from_target[i].linear() * r0.transpose();
    a.block<3, 3>(3 * (i - 1), 0) = Eigen::Matrix3d::Identity() - r;
    b.segment<3>(3 * (i - 1)) = cam_from_target[i].translation() - r * t0;
  }
  a.bottomRows<1>() = fit.direction.transpose();
  b(b.size() - 1) = fit.direction.dot(t0);
  fit.point = a.colPivHouseholderQr().solve(b);
  const Eigen::VectorXd residual = (a * fit.point - b).head(3 * (n - 1));
  fit.rms_mm = std::sqrt(residual.squaredNorm() / (n - 1));
  double step_sum = 0.0;
  for (int i = 1; i < n; ++i) {
    const Eigen::AngleAxisd turn(cam_from_target[i].linear() * cam_from_target[i - 1].linear().transpose());
    step_sum += turn.angle() * (turn.axis().dot(fit.direction) < 0 ? -1.0 : 1.0);
  }
  fit.mean_step_rad = step_sum / (n - 1);
  return fit;
}

}  // namespace rotoscan::calib
