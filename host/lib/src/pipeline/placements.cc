// Aligning and merging the clouds of several placements (placements.h has the method and its figures).
#include "rotoscan/pipeline/placements.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <memory>
#include <random>
#include <sstream>

#include <omp.h>

#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/KDTreeSearchParam.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/pipelines/registration/CorrespondenceChecker.h>
#include <open3d/pipelines/registration/Feature.h>
#include <open3d/pipelines/registration/Registration.h>
#include <open3d/pipelines/registration/RobustKernel.h>
#include <open3d/pipelines/registration/TransformationEstimation.h>
#include <open3d/utility/Random.h>

#include "rotoscan/core/logging.h"

namespace rotoscan::pipeline {
namespace {

namespace reg = open3d::pipelines::registration;
using O3dCloud = open3d::geometry::PointCloud;
constexpr double kPi = 3.14159265358979323846;
constexpr size_t kMinPoints = 100;

// The cloud for Open3D, thinned on a voxel grid (0: every point). Normals: the scan's (oriented to the
// camera, so outwards), averaged per voxel and renormalised; points without one get (0, 0, 1) and are few.
std::shared_ptr<O3dCloud> ToOpen3d(const cloud::PointCloud& cloud, double voxel_mm) {
  auto out = std::make_shared<O3dCloud>();
  out->points_.reserve(cloud.size());
  out->normals_.reserve(cloud.size());
  for (const cloud::CloudPoint& p : cloud.points) {
    out->points_.push_back(p.position_in_table.cast<double>());
    out->normals_.push_back(p.normal.squaredNorm() > 0.5f ? Eigen::Vector3d(p.normal.cast<double>())
                                                          : Eigen::Vector3d::UnitZ());
  }
  if (voxel_mm > 0) out = out->VoxelDownSample(voxel_mm);
  for (Eigen::Vector3d& n : out->normals_) {
    const double norm = n.norm();
    n = norm > 1e-9 ? Eigen::Vector3d(n / norm) : Eigen::Vector3d::UnitZ();
  }
  return out;
}

double AngleDeg(const Eigen::Matrix3d& r) {
  const double c = std::clamp((r.trace() - 1.0) / 2.0, -1.0, 1.0);
  return std::acos(c) * 180.0 / kPi;
}

Eigen::Isometry3d FromMatrix(const Eigen::Matrix4d& m) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.matrix() = m;
  return t;
}

// Open3D's ICP sums its normal equations over OpenMP threads in the order they finish, so the same clouds
// gave alignments differing in the last bits from run to run, and `merge` wrote different files. Its ICP
// runs on one thread (this thread's OpenMP setting, restored after): the merge is byte-reproducible, for
// ~0.3 s more on the demo's pair.
class OneOpenMpThread {
 public:
  OneOpenMpThread() : saved_(omp_get_max_threads()) { omp_set_num_threads(1); }
  ~OneOpenMpThread() { omp_set_num_threads(saved_); }
  OneOpenMpThread(const OneOpenMpThread&) = delete;
  OneOpenMpThread& operator=(const OneOpenMpThread&) = delete;

 private:
  int saved_;
};

// Point-to-plane ICP through the listed correspondence distances (mm), `iterations` each.
Eigen::Isometry3d Refine(const O3dCloud& source, const O3dCloud& target, Eigen::Isometry3d start,
                         std::initializer_list<double> distances, int iterations) {
  const OneOpenMpThread one_thread;
  for (const double d : distances) {
    const reg::RegistrationResult r =
        reg::RegistrationICP(source, target, d, start.matrix(), reg::TransformationEstimationPointToPlane(),
                             reg::ICPConvergenceCriteria(1e-7, 1e-7, iterations));
    if (r.correspondence_set_.size() >= 3) start = FromMatrix(r.transformation_);
  }
  return start;
}

// Robust scale of the point-to-plane residuals n_q . (q - t p) of `source` moved by `t` against its nearest
// `target` point within `distance` (mm): 1.4826 x their median absolute value, the standard deviation for
// Gaussian residuals (0 without pairs).
double ResidualScale(const O3dCloud& source, const O3dCloud& target,
                     const open3d::geometry::KDTreeFlann& tree, const Eigen::Isometry3d& t, double distance) {
  std::vector<int> index(1);
  std::vector<double> distance2(1);
  std::vector<double> residuals;
  residuals.reserve(source.points_.size());
  for (const Eigen::Vector3d& p : source.points_) {
    const Eigen::Vector3d q = t * p;
    if (tree.SearchHybrid(q, distance, 1, index, distance2) < 1) continue;
    const auto j = static_cast<size_t>(index[0]);
    residuals.push_back(std::abs(target.normals_[j].dot(target.points_[j] - q)));
  }
  if (residuals.empty()) return 0;
  const auto middle = residuals.begin() + static_cast<std::ptrdiff_t>(residuals.size() / 2);
  std::nth_element(residuals.begin(), middle, residuals.end());
  return 1.4826 * *middle;
}

// The robust fine alignment (placements.h): point-to-plane ICP with Tukey's biweight, c = tukey_constant x
// the residuals' robust scale, the scale estimated again after each round (at most 3, until it changes by
// less than 1 %). `scale_mm` gets the last scale.
Eigen::Isometry3d RefineRobust(const O3dCloud& source, const O3dCloud& target, Eigen::Isometry3d start,
                               double distance, double tukey_constant, double* scale_mm) {
  const OneOpenMpThread one_thread;
  const open3d::geometry::KDTreeFlann tree(target);
  double scale = ResidualScale(source, target, tree, start, distance);
  for (int round = 0; round < 3 && scale > 0; ++round) {
    const reg::RegistrationResult r = reg::RegistrationICP(
        source, target, distance, start.matrix(),
        reg::TransformationEstimationPointToPlane(std::make_shared<reg::TukeyLoss>(tukey_constant * scale)),
        reg::ICPConvergenceCriteria(1e-9, 1e-9, 50));
    if (r.correspondence_set_.size() < 3) break;
    start = FromMatrix(r.transformation_);
    const double next = ResidualScale(source, target, tree, start, distance);
    const bool settled = std::abs(next - scale) < 0.01 * scale;
    scale = next;
    if (settled) break;
  }
  *scale_mm = scale;
  return start;
}

// Point-to-plane ICP of the translation alone (the rotation of `start` kept), through the listed
// correspondence distances, 30 iterations each at most.
Eigen::Isometry3d RefineTranslation(const O3dCloud& source, const O3dCloud& target, Eigen::Isometry3d start,
                                    std::initializer_list<double> distances) {
  const open3d::geometry::KDTreeFlann tree(target);
  std::vector<int> index(1);
  std::vector<double> distance2(1);
  for (const double d : distances) {
    for (int iteration = 0; iteration < 30; ++iteration) {
      Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
      Eigen::Vector3d b = Eigen::Vector3d::Zero();
      for (const Eigen::Vector3d& p : source.points_) {
        const Eigen::Vector3d q = start * p;
        if (tree.SearchHybrid(q, d, 1, index, distance2) < 1) continue;
        const Eigen::Vector3d& n = target.normals_[static_cast<size_t>(index[0])];
        a += n * n.transpose();
        b += n * n.dot(target.points_[static_cast<size_t>(index[0])] - q);
      }
      const Eigen::Vector3d step = a.ldlt().solve(b);
      if (!step.allFinite()) break;
      start.pretranslate(step);
      if (step.norm() < 1e-6) break;
    }
  }
  return start;
}

// The 24 rotations of a cube (the proper rotations mapping the axes onto signed axes).
std::vector<Eigen::Matrix3d> CubeRotations() {
  std::vector<Eigen::Matrix3d> out;
  const int perms[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  for (const auto& p : perms) {
    for (int signs = 0; signs < 8; ++signs) {
      Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
      for (int i = 0; i < 3; ++i) m(i, p[i]) = (signs >> i) & 1 ? -1.0 : 1.0;
      if (m.determinant() > 0) out.push_back(m);
    }
  }
  return out;
}

}  // namespace

Status AlignOptions::Check() const {
  auto positive = [](double v) { return v > 0 && std::isfinite(v); };
  if (!positive(voxel_mm) || voxel_mm > 100)
    return InvalidArgumentError("align: voxel_mm must be in (0, 100]");
  if (!(fine_voxel_mm >= 0 && fine_voxel_mm <= voxel_mm)) {
    return InvalidArgumentError("align: fine_voxel_mm must be in [0, voxel_mm]");
  }
  if (!positive(feature_radius_mm)) return InvalidArgumentError("align: feature_radius_mm must be > 0");
  if (!positive(icp_distance_mm)) return InvalidArgumentError("align: icp_distance_mm must be > 0");
  if (ransac_iterations < 1000 || ransac_iterations > 100'000'000) {
    return InvalidArgumentError("align: ransac_iterations must be in [1000, 1e8]");
  }
  if (!(ransac_confidence > 0 && ransac_confidence <= 1)) {
    return InvalidArgumentError("align: ransac_confidence must be in (0, 1]");
  }
  if (!(min_overlap >= 0 && min_overlap <= 1))
    return InvalidArgumentError("align: min_overlap must be in [0, 1]");
  if (!(ambiguity_ratio > 0 && ambiguity_ratio <= 1)) {
    return InvalidArgumentError("align: ambiguity_ratio must be in (0, 1]");
  }
  if (!positive(distinct_deg) || !positive(distinct_mm)) {
    return InvalidArgumentError("align: distinct_deg and distinct_mm must be > 0");
  }
  if (!(tukey_constant >= 0 && tukey_constant <= 100))
    return InvalidArgumentError("align: tukey_constant must be in [0, 100] (0: no robust stage)");
  if (random_starts < 0 || random_starts > 10000)
    return InvalidArgumentError("align: random_starts in [0, 10000]");
  if (hint && !hint->matrix().allFinite()) return InvalidArgumentError("align: the hint is not finite");
  return Status::Ok();
}

Result<AlignResult> AlignClouds(const cloud::PointCloud& target, const cloud::PointCloud& source,
                                const AlignOptions& options, Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  if (target.size() < kMinPoints || source.size() < kMinPoints) {
    return InvalidArgumentError("align: each cloud needs at least " + std::to_string(kMinPoints) +
                                " points (target " + std::to_string(target.size()) + ", source " +
                                std::to_string(source.size()) + ")");
  }
  const int starts = 24 + options.random_starts;
  ProgressScope scope(progress, "align", static_cast<uint64_t>(starts + 2));
  open3d::utility::random::Seed(static_cast<int>(options.seed & 0x7FFFFFFF));
  const auto source_coarse = ToOpen3d(source, options.voxel_mm);
  const auto target_coarse = ToOpen3d(target, options.voxel_mm);
  if (source_coarse->points_.size() < 10 || target_coarse->points_.size() < 10) {
    return InvalidArgumentError("align: the clouds are smaller than a few voxels of " +
                                std::to_string(options.voxel_mm) + " mm");
  }
  const double coarse_distance = std::max(options.icp_distance_mm, options.voxel_mm);
  const double d0 = 6.0 * options.voxel_mm, d1 = 2.0 * options.voxel_mm;

  AlignResult result;
  Eigen::Isometry3d start = Eigen::Isometry3d::Identity();
  if (options.hint) {
    start = *options.hint;
    result.from_hint = true;
  } else {
    const open3d::geometry::KDTreeSearchParamHybrid feature_search(options.feature_radius_mm, 100);
    const auto source_features = reg::ComputeFPFHFeature(*source_coarse, feature_search);
    const auto target_features = reg::ComputeFPFHFeature(*target_coarse, feature_search);
    const double match = 1.5 * options.voxel_mm;
    const reg::CorrespondenceCheckerBasedOnEdgeLength edge(0.9);
    const reg::CorrespondenceCheckerBasedOnDistance distance(match);
    const reg::RegistrationResult global = reg::RegistrationRANSACBasedOnFeatureMatching(
        *source_coarse, *target_coarse, *source_features, *target_features, true, match,
        reg::TransformationEstimationPointToPoint(false), 3, {edge, distance},
        reg::RANSACConvergenceCriteria(options.ransac_iterations, options.ransac_confidence));
    start = FromMatrix(global.transformation_);
    result.global_fitness = global.fitness_;
  }
  scope.Advance();
  const Eigen::Isometry3d best = Refine(*source_coarse, *target_coarse, start, {d0, d1, coarse_distance}, 30);

  // The ambiguity test, on the clouds thinned twice as much: other starts, refined the same way, that end
  // elsewhere but score as well.
  const auto source_sparse = source_coarse->VoxelDownSample(2.0 * options.voxel_mm);
  const auto target_sparse = target_coarse->VoxelDownSample(2.0 * options.voxel_mm);
  const double sparse_distance = 2.0 * options.voxel_mm;
  auto sparse_score = [&](const Eigen::Isometry3d& t) {
    return reg::EvaluateRegistration(*source_sparse, *target_sparse, sparse_distance, t.matrix()).fitness_;
  };
  const double best_sparse = sparse_score(best);
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : source_coarse->points_) centroid += p;
  centroid /= static_cast<double>(source_coarse->points_.size());
  std::vector<Eigen::Matrix3d> rotations = CubeRotations();
  std::mt19937_64 random(options.seed);
  std::normal_distribution<double> normal;
  for (int i = 0; i < options.random_starts; ++i) {
    Eigen::Quaterniond q(normal(random), normal(random), normal(random), normal(random));
    rotations.push_back(q.normalized().toRotationMatrix());
  }
  const Eigen::Vector3d best_centroid = best * centroid;
  for (const Eigen::Matrix3d& r : rotations) {
    if (scope.Cancelled()) return CancelledError("alignment cancelled");
    scope.Advance();
    if (AngleDeg(r) < 1e-6) continue;  // the identity: the best itself
    Eigen::Isometry3d turn = Eigen::Isometry3d::Identity();
    turn.linear() = r;
    turn.translation() = centroid - r * centroid;
    const Eigen::Isometry3d alternative = Refine(*source_sparse, *target_sparse, best * turn, {d0, d1}, 10);
    ++result.alternatives_tried;
    const double deg = AngleDeg(best.linear().transpose() * alternative.linear());
    const double mm = (alternative * centroid - best_centroid).norm();
    if (deg < options.distinct_deg && mm < options.distinct_mm) continue;  // the same answer
    const double s = sparse_score(alternative);
    if (s > result.alternative_overlap) {
      result.alternative_overlap = s;
      result.alternative_deg = deg;
      result.alternative_mm = mm;
    }
  }
  result.coarse_overlap = best_sparse;
  std::ostringstream figures;
  figures.precision(3);
  figures << "best overlap " << best_sparse << " at " << sparse_distance
          << " mm, the best distinct alternative " << result.alternative_overlap << " ("
          << result.alternative_deg << " deg, " << result.alternative_mm << " mm away)";
  const bool ambiguous =
      best_sparse <= 0 || result.alternative_overlap >= options.ambiguity_ratio * best_sparse;
  if (ambiguous && !options.hint) {
    return FailedPreconditionError(
        "the alignment is ambiguous: another pose of the cloud fits nearly as well (" + figures.str() +
        "): a symmetric object (a sphere, a cylinder) or too little shape in the overlap; give a rough pose "
        "with --hint");
  }
  if (ambiguous) {
    ROTOSCAN_LOG(kInfo) << "align: ambiguous, the hint decides (" << figures.str() << ")";
  }

  // The fine alignment on the dense clouds.
  const auto source_fine = ToOpen3d(source, options.fine_voxel_mm);
  const auto target_fine = ToOpen3d(target, options.fine_voxel_mm);
  if (ambiguous) {
    // The rotation is not observable (a symmetric object): keep the hint's and fit the translation alone.
    result.target_from_source = RefineTranslation(*source_fine, *target_fine, *options.hint,
                                                  {d0, d1, coarse_distance, options.icp_distance_mm});
  } else {
    result.target_from_source =
        Refine(*source_fine, *target_fine, best, {coarse_distance, options.icp_distance_mm}, 50);
    if (options.tukey_constant > 0) {
      result.target_from_source =
          RefineRobust(*source_fine, *target_fine, result.target_from_source, options.icp_distance_mm,
                       options.tukey_constant, &result.residual_scale_mm);
    }
  }
  const reg::RegistrationResult fit = reg::EvaluateRegistration(
      *source_fine, *target_fine, options.icp_distance_mm, result.target_from_source.matrix());
  result.overlap = fit.fitness_;
  result.residual_mm = fit.inlier_rmse_;
  scope.Advance();
  if (result.overlap < options.min_overlap) {
    std::ostringstream message;
    message.precision(3);
    message << "too little overlap to align: " << 100 * result.overlap << " % of the cloud lies within "
            << options.icp_distance_mm << " mm of the other (at least " << 100 * options.min_overlap
            << " % needed); scan the new placement so that it shares more surface with the first, or give a "
               "rough pose with --hint";
    return FailedPreconditionError(message.str());
  }
  return result;
}

Result<MergePlacementsResult> MergePlacements(const std::vector<cloud::PointCloud>& clouds,
                                              const AlignOptions& options,
                                              const std::vector<std::optional<Eigen::Isometry3d>>& hints,
                                              double overlap_radius_mm, Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  if (clouds.size() < 2 || clouds.size() > 256) {
    return InvalidArgumentError("merge: give 2 to 256 clouds (got " + std::to_string(clouds.size()) + ")");
  }
  if (!hints.empty() && hints.size() != clouds.size()) {
    return InvalidArgumentError("merge: one hint per cloud or none");
  }
  if (!(overlap_radius_mm > 0 && std::isfinite(overlap_radius_mm))) {
    return InvalidArgumentError("merge: overlap radius must be > 0");
  }
  MergePlacementsResult result;
  cloud::PointCloud& merged = result.cloud;
  merged.points = clouds[0].points;
  for (cloud::CloudPoint& p : merged.points) p.placement = 0;
  PlacementReport first;
  first.points = clouds[0].size();
  result.placements.push_back(first);
  for (size_t k = 1; k < clouds.size(); ++k) {
    AlignOptions align = options;
    align.hint = hints.empty() ? std::nullopt : hints[k];
    auto aligned = AlignClouds(merged, clouds[k], align, progress);
    if (!aligned.ok()) {
      return aligned.status().WithContext("cloud " + std::to_string(k) + " (placement " + std::to_string(k) +
                                          ")");
    }
    PlacementReport report;
    report.placement = static_cast<int>(k);
    report.points = clouds[k].size();
    report.alignment = *aligned;
    const Eigen::Isometry3d& t = aligned->target_from_source;
    const Eigen::Matrix3f rotation = t.linear().cast<float>();
    for (cloud::CloudPoint p : clouds[k].points) {
      p.position_in_table = (t * p.position_in_table.cast<double>()).cast<float>();
      p.normal = rotation * p.normal;
      p.placement = static_cast<uint8_t>(k);
      merged.points.push_back(p);
    }
    result.placements.push_back(report);
  }
  // Each placement's camera path, moved into the merged frame by its alignment (when every cloud is one
  // scan that knows its path): the sensor rays of meshing (mesh --watertight).
  merged.scan = cloud::ScanGeometry{};
  bool paths = true;
  for (const cloud::PointCloud& c : clouds) paths = paths && c.scan.known && c.scan.placements.empty();
  if (paths) {
    merged.scan = clouds[0].scan;
    for (size_t k = 0; k < clouds.size(); ++k) {
      cloud::ScanGeometry::Placement p;
      p.camera_at_step0 = clouds[k].scan.camera_at_step0;
      p.step_rad = clouds[k].scan.step_rad;
      if (k > 0) p.merged_from_table = result.placements[k].alignment.target_from_source;
      merged.scan.placements.push_back(p);
    }
  }
  for (PlacementReport& report : result.placements) {
    std::vector<uint32_t> mine, others;
    for (size_t i = 0; i < merged.size(); ++i) {
      (merged.points[i].placement == report.placement ? mine : others).push_back(static_cast<uint32_t>(i));
    }
    report.disagreement = cloud::MeasureDisagreement(merged, mine, others, overlap_radius_mm);
  }
  return result;
}

AlignmentError MeasureAlignmentError(const Eigen::Isometry3d& estimated, const Eigen::Isometry3d& truth,
                                     const std::vector<Eigen::Vector3f>& vertices,
                                     const std::vector<Eigen::Vector3i>& faces) {
  AlignmentError error;
  const Eigen::Isometry3d delta = estimated.inverse() * truth;
  error.angle_deg = AngleDeg(delta.linear());
  double area_sum = 0, sum = 0;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3i& f : faces) {
    const Eigen::Vector3d a = vertices[static_cast<size_t>(f[0])].cast<double>();
    const Eigen::Vector3d b = vertices[static_cast<size_t>(f[1])].cast<double>();
    const Eigen::Vector3d c = vertices[static_cast<size_t>(f[2])].cast<double>();
    const double area = 0.5 * (b - a).cross(c - a).norm();
    const Eigen::Vector3d m = (a + b + c) / 3.0;
    sum += area * (estimated * m - truth * m).squaredNorm();
    centroid += area * m;
    area_sum += area;
  }
  if (area_sum > 0) {
    error.rms_mm = std::sqrt(sum / area_sum);
    centroid /= area_sum;
    error.translation_mm = (delta * centroid - centroid).norm();
  }
  return error;
}

Result<Eigen::Isometry3d> ParsePoseHint(const std::string& text) {
  std::string content = text;
  std::error_code ec;
  if (text.find(',') == std::string::npos && std::filesystem::is_regular_file(text, ec)) {
    std::ifstream in(text);
    std::ostringstream all;
    all << in.rdbuf();
    if (!in && !in.eof()) return InvalidArgumentError("cannot read the hint file " + text);
    content = all.str();
    if (content.size() > 100000) return InvalidArgumentError("the hint file " + text + " is too large");
  } else if (text.find(',') == std::string::npos) {
    return InvalidArgumentError("--hint '" + text + "' is neither rx,ry,rz,tx,ty,tz nor a readable file");
  }
  for (char& c : content) {
    if (c == ',' || c == ';' || c == '[' || c == ']') c = ' ';
  }
  std::istringstream words(content);
  std::vector<double> v;
  std::string word;
  while (words >> word) {
    if (word[0] == '#') {
      std::getline(words, word);
      continue;
    }
    char* end = nullptr;
    const double x = std::strtod(word.c_str(), &end);
    if (end == word.c_str() || *end != '\0' || !std::isfinite(x) || std::abs(x) > 1e6) {
      return InvalidArgumentError("hint: '" + word + "' is not a finite number");
    }
    v.push_back(x);
    if (v.size() > 16) break;
  }
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  if (v.size() == 6) {
    const double k = kPi / 180.0;
    pose.linear() = (Eigen::AngleAxisd(v[2] * k, Eigen::Vector3d::UnitZ()) *
                     Eigen::AngleAxisd(v[1] * k, Eigen::Vector3d::UnitY()) *
                     Eigen::AngleAxisd(v[0] * k, Eigen::Vector3d::UnitX()))
                        .toRotationMatrix();
    pose.translation() = Eigen::Vector3d(v[3], v[4], v[5]);
    return pose;
  }
  if (v.size() == 16) {
    Eigen::Matrix4d m;
    for (int i = 0; i < 16; ++i) m(i / 4, i % 4) = v[static_cast<size_t>(i)];
    const Eigen::Matrix3d r = m.topLeftCorner<3, 3>();
    if ((r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-4 ||
        r.determinant() < 0 || m.row(3).cwiseAbs().sum() - 1.0 > 1e-9 || std::abs(m(3, 3) - 1.0) > 1e-9) {
      return InvalidArgumentError("hint: the 4x4 matrix is not a rigid transform");
    }
    pose.matrix() = m;
    return pose;
  }
  return InvalidArgumentError(
      "hint: expected 6 numbers (rx,ry,rz in degrees, tx,ty,tz in mm) or 16 (a 4x4 "
      "matrix, row-major), got " +
      std::to_string(v.size()));
}

std::string FormatPlacementReport(const MergePlacementsResult& result) {
  std::ostringstream out;
  out.setf(std::ios::fixed);
  for (const PlacementReport& p : result.placements) {
    out.precision(4);
    out << "placement " << p.placement << ": " << p.points << " points";
    if (p.placement > 0) {
      const AlignResult& a = p.alignment;
      const Eigen::AngleAxisd aa(a.target_from_source.linear());
      out << ", aligned " << (a.from_hint ? "from the hint" : "automatically") << ": overlap "
          << 100 * a.overlap << " %, residual " << a.residual_mm << " mm RMS";
      if (a.residual_scale_mm > 0) out << " (point-to-plane scale " << a.residual_scale_mm << " mm, robust)";
      out << "; rotation " << aa.angle() * 180 / kPi << " deg, translation "
          << a.target_from_source.translation().norm() << " mm; ambiguity test: " << 100 * a.coarse_overlap
          << " % against " << 100 * a.alternative_overlap << " % for the best distinct pose of "
          << a.alternatives_tried << " other starts";
    }
    const cloud::LaserDisagreement& d = p.disagreement;
    if (d.pairs == 0) {
      out << "; disagreement with the others: not measured (no overlapping pair)\n";
    } else {
      out << "; disagreement with the others: " << d.pairs << " pairs, mean offset " << d.mean_signed_mm
          << " mm, rms " << d.rms_mm << " mm, median |d| " << d.median_abs_mm << " mm; color (luminance, "
          << "the others minus this one) mean " << d.color_mean_signed << ", mean |d| " << d.color_mean_abs
          << " levels\n";
    }
  }
  return out.str();
}

}  // namespace rotoscan::pipeline
