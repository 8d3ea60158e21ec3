// The lamp from a scan of a white sphere (lamp.h has the method).
#include "rotoscan/pipeline/lamp.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <vector>

#include <Eigen/Cholesky>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/core/file.h"
#include "rotoscan/pipeline/process.h"

namespace rotoscan::pipeline {
namespace {

struct Sphere {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double radius = 0;
};

// Algebraic least squares: |p|^2 = 2 c . p + k, k = r^2 - |c|^2.
bool FitSphere(const std::vector<Eigen::Vector3d>& points, Sphere* sphere) {
  if (points.size() < 10) return false;
  Eigen::Matrix4d ata = Eigen::Matrix4d::Zero();
  Eigen::Vector4d atb = Eigen::Vector4d::Zero();
  for (const Eigen::Vector3d& p : points) {
    const Eigen::Vector4d row(2 * p.x(), 2 * p.y(), 2 * p.z(), 1.0);
    ata += row * row.transpose();
    atb += row * p.squaredNorm();
  }
  const Eigen::LDLT<Eigen::Matrix4d> solver(ata);
  if (solver.info() != Eigen::Success) return false;
  const Eigen::Vector4d x = solver.solve(atb);
  sphere->centre = x.head<3>();
  const double r2 = x[3] + sphere->centre.squaredNorm();
  if (!(r2 > 0) || !x.allFinite()) return false;
  sphere->radius = std::sqrt(r2);
  return true;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

struct Sample {
  Eigen::Vector3d normal;  // camera frame
  double level = 0;        // luminance, 8-bit
};

}  // namespace

Status LampCalibrationOptions::Check() const {
  if (max_frames < 1 || max_frames > 4096) return InvalidArgumentError("lamp: max_frames in [1, 4096]");
  if (!(min_cos_view >= 0 && min_cos_view < 1)) return InvalidArgumentError("lamp: min_cos_view in [0, 1)");
  if (!(terminator_band >= 0 && terminator_band < 0.5))
    return InvalidArgumentError("lamp: terminator_band in [0, 0.5)");
  if (saturation < 1 || saturation > 256) return InvalidArgumentError("lamp: saturation in [1, 256]");
  if (!(std::isfinite(min_height_mm) && min_height_mm >= 0))
    return InvalidArgumentError("lamp: min_height_mm >= 0");
  if (threads < 0 || threads > 256) return InvalidArgumentError("lamp: threads in [0, 256]");
  return Status::Ok();
}

Result<LampCalibration> CalibrateLamp(const std::filesystem::path& bundle_dir, const geometry::Rig& rig,
                                      const LampCalibrationOptions& options, Progress* progress) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  ROTOSCAN_RETURN_IF_ERROR(rig.Validate().WithContext("lamp calibration"));
  LampCalibration out;

  // The sphere, from the laser points above the table.
  ProcessOptions process;
  process.color.enabled = false;
  process.threads = options.threads;
  ROTOSCAN_ASSIGN_OR_RETURN(ProcessResult scan, ProcessBundle(bundle_dir, rig, process, progress));
  std::vector<Eigen::Vector3d> points;
  for (const cloud::CloudPoint& p : scan.cloud.points) {
    if (p.position_in_table.z() >= options.min_height_mm)
      points.push_back(p.position_in_table.cast<double>());
  }
  Sphere sphere;
  std::vector<Eigen::Vector3d> kept = points;
  for (int round = 0; round < 3; ++round) {
    if (!FitSphere(kept, &sphere)) break;
    std::vector<double> residual;
    for (const Eigen::Vector3d& p : points)
      residual.push_back(std::abs((p - sphere.centre).norm() - sphere.radius));
    const double mad = Median(residual);
    kept.clear();
    for (size_t i = 0; i < points.size(); ++i) {
      if (residual[i] <= std::min(0.3, std::max(3 * mad, 0.02))) kept.push_back(points[i]);
    }
  }
  if (kept.size() < 100 || 10 * kept.size() < 8 * points.size() || !FitSphere(kept, &sphere) ||
      sphere.radius < 2 || sphere.radius > 200) {
    return FailedPreconditionError(bundle_dir.string() + ": no sphere in the laser points (" +
                                   std::to_string(kept.size()) + " of " + std::to_string(points.size()) +
                                   " points above the table lie on one): lamp calibration needs a scan of a "
                                   "matte white sphere (data/scenes/lamp-sphere.json)");
  }
  double ss = 0;
  for (const Eigen::Vector3d& p : kept) ss += std::pow((p - sphere.centre).norm() - sphere.radius, 2);
  out.sphere_centre_in_table = sphere.centre;
  out.sphere_radius_mm = sphere.radius;
  out.sphere_points = kept.size();
  out.sphere_rms_mm = std::sqrt(ss / static_cast<double>(kept.size()));

  // The sphere's pixels in the natural frames: normal and luminance.
  ROTOSCAN_ASSIGN_OR_RETURN(bundle::Bundle bundle, bundle::ReadBundle(bundle_dir));
  BundleStepSource source(std::move(bundle));
  const int steps = source.StepCount();
  const int wanted = std::min(options.max_frames, steps);
  const geometry::CameraModel& camera = rig.camera;
  std::vector<Sample> samples;
  for (int v = 0; v < wanted; ++v) {
    const int index = static_cast<int>(static_cast<int64_t>(v) * steps / wanted);
    double angle = 0;
    auto natural = source.LoadNatural(index, &angle);
    if (!natural.ok() || natural->empty()) continue;
    const cv::Mat image = NaturalImageOf(source, *natural);
    if (image.cols != camera.width || image.rows != camera.height || image.channels() != 3) continue;
    const Eigen::Vector3d centre = rig.WorldFromCamAtAngle(angle).inverse() * sphere.centre;
    if (centre.z() <= sphere.radius) continue;
    const Eigen::Vector2d c = camera.Project(centre);
    const double reach = 1.5 * camera.fx * sphere.radius / (centre.z() - sphere.radius) + 4;
    const int x0 = std::max(0, static_cast<int>(c.x() - reach)),
              x1 = std::min(camera.width - 1, static_cast<int>(c.x() + reach));
    const int y0 = std::max(0, static_cast<int>(c.y() - reach)),
              y1 = std::min(camera.height - 1, static_cast<int>(c.y() + reach));
    size_t found = 0;
    for (int y = y0; y <= y1; ++y) {
      const cv::Vec3b* row = image.ptr<cv::Vec3b>(y);
      for (int x = x0; x <= x1; ++x) {
        const Eigen::Vector3d d = camera.PixelToRay(Eigen::Vector2d(x, y)).normalized();
        const double b = d.dot(centre), disc = b * b - centre.squaredNorm() + sphere.radius * sphere.radius;
        if (disc <= 0) continue;
        const Eigen::Vector3d n = (d * (b - std::sqrt(disc)) - centre) / sphere.radius;
        if (-n.dot(d) < options.min_cos_view) continue;
        const cv::Vec3b& px = row[x];
        if (std::max({px[0], px[1], px[2]}) >= options.saturation) continue;
        samples.push_back({n, (px[0] + px[1] + px[2]) / 3.0});
        ++found;
      }
    }
    if (found > 0) ++out.frames;
  }
  if (samples.size() < 200) {
    return FailedPreconditionError(bundle_dir.string() + ": the sphere shows in no natural frame (" +
                                   std::to_string(samples.size()) + " usable pixels)");
  }

  // I = A + max(0, n . B): linear once each pixel is classified lit or unlit (lamp.h).
  Eigen::Vector4d x = Eigen::Vector4d::Zero();  // A, B
  std::vector<signed char> lit(samples.size(), 1), previous;
  for (int iteration = 0; iteration < 30; ++iteration) {
    Eigen::Matrix4d ata = Eigen::Matrix4d::Zero();
    Eigen::Vector4d atb = Eigen::Vector4d::Zero();
    size_t lit_count = 0;
    for (size_t i = 0; i < samples.size(); ++i) {
      if (lit[i] == 0) continue;
      const Eigen::Vector4d row =
          lit[i] > 0 ? Eigen::Vector4d(1, samples[i].normal.x(), samples[i].normal.y(), samples[i].normal.z())
                     : Eigen::Vector4d(1, 0, 0, 0);
      ata += row * row.transpose();
      atb += row * samples[i].level;
      lit_count += lit[i] > 0;
    }
    if (lit_count < 100) break;
    const Eigen::LDLT<Eigen::Matrix4d> solver(ata);
    x = solver.solve(atb);
    if (!x.allFinite()) break;
    previous = lit;
    const Eigen::Vector3d b = x.tail<3>();
    const double strength = b.norm();
    if (strength <= 0) break;
    for (size_t i = 0; i < samples.size(); ++i) {
      const double s = samples[i].normal.dot(b) / strength;
      lit[i] = s > options.terminator_band ? 1 : (s < -options.terminator_band ? -1 : 0);
    }
    if (lit == previous) break;
  }
  const double a = x[0];
  const Eigen::Vector3d b = x.tail<3>();
  if (!x.allFinite() || !(a > 1.0) || b.norm() <= 0) {
    return FailedPreconditionError("the sphere's shading does not follow one lamp (ambient level " +
                                   std::to_string(a) + "): is the lamp on, and the sphere matte?");
  }
  double residual = 0, mean = 0;
  size_t used = 0;
  for (size_t i = 0; i < samples.size(); ++i) {
    if (lit[i] == 0) continue;
    const double model = a + std::max(0.0, samples[i].normal.dot(b));
    residual += (samples[i].level - model) * (samples[i].level - model);
    mean += samples[i].level;
    ++used;
  }
  out.lamp_in_cam = b / a;
  out.ambient_level = a;
  out.pixels = used;
  out.relative_rms = used > 0 && mean > 0 ? std::sqrt(residual / static_cast<double>(used)) /
                                                (mean / static_cast<double>(used))
                                          : 0;
  return out;
}

std::string FormatLampCalibration(const LampCalibration& c) {
  char text[640];
  const double strength = c.lamp_in_cam.norm();
  const Eigen::Vector3d d =
      strength > 0 ? Eigen::Vector3d(c.lamp_in_cam / strength) : Eigen::Vector3d::Zero();
  std::snprintf(
      text, sizeof(text),
      "lamp: direction in the camera frame %.4f %.4f %.4f, diffuse/ambient %.3f (lamp %.4f %.4f %.4f)\n"
      "  from %zu pixels of %d natural frames, fit RMS %.2f %% of the mean level (ambient %.1f levels)\n"
      "  sphere: radius %.3f mm at %.3f %.3f %.3f mm (table frame), %zu laser points, RMS %.4f mm\n",
      d.x(), d.y(), d.z(), strength, c.lamp_in_cam.x(), c.lamp_in_cam.y(), c.lamp_in_cam.z(), c.pixels,
      c.frames, 100 * c.relative_rms, c.ambient_level, c.sphere_radius_mm, c.sphere_centre_in_table.x(),
      c.sphere_centre_in_table.y(), c.sphere_centre_in_table.z(), c.sphere_points, c.sphere_rms_mm);
  return text;
}

Status WriteLampIntoCalibration(const std::filesystem::path& path, const Eigen::Vector3d& lamp_in_cam) {
  if (!lamp_in_cam.allFinite() || lamp_in_cam.norm() > 1e3)
    return InvalidArgumentError("the lamp must be finite and below 1000");
  ROTOSCAN_ASSIGN_OR_RETURN(std::string text, ReadFile(path, size_t{16} << 20));
  ROTOSCAN_RETURN_IF_ERROR(geometry::ParseRigYaml(text, path.string()).status().WithContext("lamp"));
  // The top-level key `lamp` (an earlier calibration's) removed: from its line to the next top-level key.
  std::istringstream in(text);
  std::string line, kept;
  bool skipping = false;
  while (std::getline(in, line)) {
    const bool top_level = !line.empty() && line[0] != ' ' && line[0] != '\t';
    if (top_level) skipping = line.rfind("lamp:", 0) == 0;
    if (!skipping) kept += line + "\n";
  }
  char block[256];
  std::snprintf(block, sizeof(block),
                "lamp: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ %.17g, %.17g, %.17g ]\n",
                lamp_in_cam.x(), lamp_in_cam.y(), lamp_in_cam.z());
  kept += block;
  auto check = geometry::ParseRigYaml(kept, path.string());
  if (!check.ok() || !check->lamp_in_cam ||
      (*check->lamp_in_cam - lamp_in_cam).norm() > 1e-9 * (1 + lamp_in_cam.norm())) {
    return InternalError("the lamp written into " + path.string() + " does not read back");
  }
  return WriteFileAtomically(path, kept);
}

}  // namespace rotoscan::pipeline
