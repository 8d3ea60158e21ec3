#include "povray_scene.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <random>
#include <sstream>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rotoscan/core/file.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::testing::povray {
namespace fs = std::filesystem;
namespace {

// A point or direction of our camera frame in POV-Ray's (y up).
std::string Vec(const Eigen::Vector3d& v) {
  char text[160];
  std::snprintf(text, sizeof text, "<%.12g, %.12g, %.12g>", v.x(), -v.y(), v.z());
  return text;
}
std::string Rgb(const Eigen::Vector3d& c) {
  char text[120];
  std::snprintf(text, sizeof text, "rgb <%.9g, %.9g, %.9g>", c.x(), c.y(), c.z());
  return text;
}

std::string Matrix(const Eigen::Vector3d& x, const Eigen::Vector3d& y, const Eigen::Vector3d& z,
                   const Eigen::Vector3d& t);

std::string Finish(const Surface& s, double ambient) {
  std::ostringstream out;
  out << "finish { ambient " << ambient << " diffuse 1 brilliance 1";
  if (s.phong > 0) out << " phong " << s.phong << " phong_size " << s.phong_size;
  out << " }";
  return out.str();
}

std::string Texture(const Surface& s, double ambient) {
  std::ostringstream out;
  out << "texture { pigment { ";
  if (s.checker_mm > 0) {
    // POV-Ray's checker takes its first colour where the cell indices' sum is even.
    const Eigen::Matrix3d r = s.checker_frame.linear();
    out << "checker " << Rgb(s.albedo) << ", " << Rgb(s.albedo * s.dark_albedo)
        << " translate <-0.25, -0.25, -0.25> scale " << s.checker_mm << " "
        << Matrix(r.col(0), r.col(1), r.col(2), s.checker_frame.translation());
  } else {
    out << Rgb(s.albedo);
  }
  out << " } " << Finish(s, ambient) << " }";
  return out.str();
}

// The laser's plate frame: u along the slit (in the plane, across the fan), n the plane's normal, m the
// fan's centre.
struct PlateFrame {
  Eigen::Vector3d u, n, m;
};
PlateFrame Plate(const LaserSheet& laser) {
  PlateFrame f;
  f.n = laser.plane.normal.normalized();
  f.m = (laser.fan_direction - f.n * f.n.dot(laser.fan_direction)).normalized();
  f.u = f.n.cross(f.m);
  return f;
}

// POV-Ray's matrix keyword maps a local point p to p.x * row0 + p.y * row1 + p.z * row2 + row3; the rows
// are given in POV-Ray coordinates.
std::string Matrix(const Eigen::Vector3d& x, const Eigen::Vector3d& y, const Eigen::Vector3d& z,
                   const Eigen::Vector3d& t) {
  char text[400];
  std::snprintf(text, sizeof text, "matrix <%.12g, %.12g, %.12g, %.12g, %.12g, %.12g, %.12g, %.12g, %.12g, %.12g, %.12g, %.12g>",
                x.x(), -x.y(), x.z(), y.x(), -y.y(), y.z(), z.x(), -z.y(), z.z(), t.x(), -t.y(), t.z());
  return text;
}

// The sub-light positions of the laser's area light: `sources` points from -source/2 to +source/2 along
// the normal (POV-Ray spreads an area light's lights over its axis, ends included).
std::vector<Eigen::Vector3d> SubLights(const LaserSheet& laser) {
  const PlateFrame f = Plate(laser);
  std::vector<Eigen::Vector3d> lights;
  const int n = std::max(1, laser.sources);
  for (int i = 0; i < n; ++i) {
    const double s = n == 1 ? 0.0 : laser.source_mm * (static_cast<double>(i) / (n - 1) - 0.5);
    lights.push_back(laser.origin + s * f.n);
  }
  return lights;
}

constexpr double kPlateHalfLength = 2000.0;  // along the slit, mm: the fan covers the half space
constexpr double kPlateHalfHeight = 60.0;    // across, beyond the slit, mm
constexpr double kPlateThickness = 0.001;    // mm

// Ray against one surface: the smallest t > min_t, or nullopt.
std::optional<double> Intersect(const Surface& s, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                                double min_t) {
  switch (s.kind) {
    case Surface::Kind::kPlane: {
      const std::optional<double> t = s.plane.IntersectRay(o, d);
      if (t && *t > min_t) return t;
      return std::nullopt;
    }
    case Surface::Kind::kSphere:
    case Surface::Kind::kCylinder: {
      Eigen::Vector3d oc = o - s.centre, dd = d;
      if (s.kind == Surface::Kind::kCylinder) {
        oc -= s.axis * s.axis.dot(oc);
        dd -= s.axis * s.axis.dot(dd);
      }
      const double a = dd.squaredNorm(), b = 2 * oc.dot(dd), c = oc.squaredNorm() - s.radius_mm * s.radius_mm;
      const double disc = b * b - 4 * a * c;
      if (a <= 0 || disc < 0) return std::nullopt;
      const double q = std::sqrt(disc);
      const double t0 = (-b - q) / (2 * a), t1 = (-b + q) / (2 * a);
      if (t0 > min_t) return t0;
      if (t1 > min_t) return t1;
      return std::nullopt;
    }
  }
  return std::nullopt;
}

// The surface's implicit function (zero on it).
double Implicit(const Surface& s, const Eigen::Vector3d& p) {
  switch (s.kind) {
    case Surface::Kind::kPlane: return s.plane.SignedDistance(p);
    case Surface::Kind::kSphere: return (p - s.centre).norm() - s.radius_mm;
    case Surface::Kind::kCylinder: {
      const Eigen::Vector3d r = p - s.centre;
      return (r - s.axis * s.axis.dot(r)).norm() - s.radius_mm;
    }
  }
  return 0.0;
}

}  // namespace

Status PovScene::Check() const {
  ROTOSCAN_RETURN_IF_ERROR(rig.camera.Validate());
  if (rig.camera.HasDistortion())
    return InvalidArgumentError("povray scene: the camera has lens distortion, which POV-Ray cannot render");
  if (laser.sources < 1 || laser.slit_mm <= 0 || laser.slit_distance_mm <= 0 || laser.source_mm < 0)
    return InvalidArgumentError("povray scene: the laser needs sources >= 1, a slit and its distance > 0");
  if (std::abs(laser.plane.SignedDistance(laser.origin)) > 1e-6)
    return InvalidArgumentError("povray scene: the laser's origin is not on its plane");
  for (const Surface& s : surfaces) {
    if (s.kind != Surface::Kind::kPlane && s.radius_mm <= 0)
      return InvalidArgumentError("povray scene: a sphere or cylinder needs a radius > 0");
  }
  return Status::Ok();
}

std::string SceneText(const PovScene& scene, Frame frame) {
  const geometry::CameraModel& cam = scene.rig.camera;
  const double w = cam.width, h = cam.height;
  std::ostringstream out;
  out.precision(12);
  out << "// Rotoscan: our rig in POV-Ray (host/tests/laser/povray_scene.h). Camera frame, y flipped.\n"
      << "#version 3.7;\n"
      << "global_settings { assumed_gamma 1.0 ambient_light rgb 1 max_trace_level 5 }\n"
      << "background { rgb 0 }\n"
      << "camera { perspective location <0, 0, 0>\n"
      << "  direction <" << (w / 2 - 0.5 - cam.cx) / cam.fx << ", " << (cam.cy + 0.5 - h / 2) / cam.fy << ", 1>\n"
      << "  right <" << w / cam.fx << ", 0, 0> up <0, " << h / cam.fy << ", 0> }\n";
  if (frame == Frame::kMarkers) {
    for (const Eigen::Vector3d& p : scene.markers) {
      out << "sphere { " << Vec(p) << ", " << scene.marker_radius_mm
          << " texture { pigment { rgb 1 } finish { ambient 0 diffuse 0 emission 1 } } }\n";
    }
    return out.str();
  }
  const Lamp& lamp = scene.lamp;
  out << "light_source { " << Vec(lamp.position) << " color rgb " << lamp.intensity << " }\n";
  for (const Surface& s : scene.surfaces) {
    switch (s.kind) {
      case Surface::Kind::kPlane: {
        // POV-Ray's plane { n, d } is n . X = d; ours n . X + offset = 0.
        const Eigen::Vector3d n = s.plane.normal;
        out << "plane { " << Vec(n) << ", " << -s.plane.offset << " " << Texture(s, lamp.ambient) << " }\n";
        break;
      }
      case Surface::Kind::kSphere:
        out << "sphere { " << Vec(s.centre) << ", " << s.radius_mm << " " << Texture(s, lamp.ambient) << " }\n";
        break;
      case Surface::Kind::kCylinder:
        out << "cylinder { " << Vec(s.centre - 2000.0 * s.axis) << ", " << Vec(s.centre + 2000.0 * s.axis)
            << ", " << s.radius_mm << " " << Texture(s, lamp.ambient) << " }\n";
        break;
    }
  }
  if (frame == Frame::kLaserOn) {
    const LaserSheet& l = scene.laser;
    const PlateFrame f = Plate(l);
    const int n = std::max(1, l.sources);
    // The area light's axis along the normal; a second axis of 1 light (POV-Ray needs two).
    out << "light_source { " << Vec(l.origin) << " color " << Rgb(l.power * l.rgb) << "\n"
        << "  area_light " << Vec(l.source_mm * f.n) << ", " << Vec(1e-3 * f.u) << ", " << n << ", 1";
    if (l.adaptive >= 0) out << " adaptive " << l.adaptive;
    out << " }\n";
    // The plate, two boxes either side of the slit, invisible to the camera and to reflections.
    const std::string plate = Matrix(f.u, f.n, f.m, l.origin + l.slit_distance_mm * f.m);
    for (int side : {-1, 1}) {
      const double a = side * l.slit_mm / 2, b = side * kPlateHalfHeight;
      out << "box { <" << -kPlateHalfLength << ", " << std::min(a, b) << ", 0>, <" << kPlateHalfLength << ", "
          << std::max(a, b) << ", " << kPlateThickness << "> " << plate
          << " pigment { rgb 0 } finish { ambient 0 diffuse 0 } no_image no_reflection no_radiosity }\n";
    }
  }
  return out.str();
}

bool PovrayAvailable() { return std::system("povray --version > /dev/null 2>&1") == 0; }

Result<cv::Mat> Render(const PovScene& scene, Frame frame, const fs::path& work_dir, const std::string& name) {
  ROTOSCAN_RETURN_IF_ERROR(scene.Check());
  if (!PovrayAvailable()) return NotFoundError("povray is not installed (apt-get install povray)");
  std::error_code ec;
  fs::create_directories(work_dir, ec);
  const fs::path pov = work_dir / (name + ".pov"), png = work_dir / (name + ".png"),
                 log = work_dir / (name + ".log");
  ROTOSCAN_RETURN_IF_ERROR(WriteFileAtomically(pov, SceneText(scene, frame)));
  std::ostringstream cmd;
  // Run in the work directory with relative names: POV-Ray's I/O security (restricted by default, Debian's
  // /etc/povray/3.7/povray.conf) always lets it read and write the current directory.
  cmd << "cd '" << fs::absolute(work_dir).string() << "' && povray -D -V +I'" << pov.filename().string() << "' +O'"
      << png.filename().string() << "' +W" << scene.rig.camera.width
      << " +H" << scene.rig.camera.height << " +FN8 File_Gamma=1.0 -J";
  if (scene.aa_method > 0) {
    // POV-Ray reads "+A0" as a malformed option: the threshold needs its decimal point.
    char aa[96];
    std::snprintf(aa, sizeof aa, " +A%.4f +AM%d +R%d", scene.aa_threshold, scene.aa_method, scene.aa_depth);
    cmd << aa;
  }
  cmd << " > '" << log.filename().string() << "' 2>&1";
  if (std::system(cmd.str().c_str()) != 0) {
    // The log's end says why (a parse error names the scene line); the work directory may be a scratch one.
    std::ifstream file(log);
    std::string text((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
    if (text.size() > 600) text = text.substr(text.size() - 600);
    return InternalError("povray failed (" + log.string() + "): " + text);
  }
  cv::Mat image = cv::imread(png.string(), cv::IMREAD_COLOR);
  if (image.empty() || image.cols != scene.rig.camera.width || image.rows != scene.rig.camera.height)
    return InternalError("povray wrote no readable frame of the rig's size: " + png.string());
  return image;
}

double SheetProfile(const LaserSheet& laser, const Eigen::Vector3d& point) {
  const PlateFrame f = Plate(laser);
  const std::vector<Eigen::Vector3d> lights = SubLights(laser);
  int through = 0;
  for (const Eigen::Vector3d& s : lights) {
    // Where the segment light -> point crosses the plate's plane m . (X - origin) = slit distance.
    const Eigen::Vector3d d = point - s;
    const double dm = f.m.dot(d);
    if (dm <= 0) continue;
    const double t = (laser.slit_distance_mm - f.m.dot(s - laser.origin)) / dm;
    if (t <= 0 || t >= 1) continue;
    const Eigen::Vector3d x = s + t * d - laser.origin;
    through += std::abs(f.n.dot(x)) < laser.slit_mm / 2 && std::abs(f.u.dot(x)) < kPlateHalfLength;
  }
  return static_cast<double>(through) / static_cast<double>(lights.size());
}

std::optional<Hit> FirstHit(const std::vector<Surface>& surfaces, const Eigen::Vector3d& origin,
                            const Eigen::Vector3d& dir, double min_t) {
  std::optional<Hit> best;
  for (size_t i = 0; i < surfaces.size(); ++i) {
    const std::optional<double> t = Intersect(surfaces[i], origin, dir, min_t);
    if (t && (!best || *t < best->t)) best = Hit{static_cast<int>(i), *t};
  }
  return best;
}

std::vector<bundle::LinePoint> AnalyticLineTruth(const PovScene& scene) {
  const geometry::CameraModel& cam = scene.rig.camera;
  const LaserSheet& laser = scene.laser;
  const PlateFrame plate = Plate(laser);
  const Eigen::Isometry3d world_from_cam = scene.rig.WorldFromCamAtAngle(0.0);
  std::vector<bundle::LinePoint> truth;
  // The laser plane's point on the ray of pixel (c, r) (eq. 2 inverted, no distortion), or nullopt.
  auto on_plane = [&](double c, int r) -> std::optional<Eigen::Vector3d> {
    const Eigen::Vector3d ray((c - cam.cx) / cam.fx, (r - cam.cy) / cam.fy, 1.0);
    const std::optional<double> t = laser.plane.IntersectRay(Eigen::Vector3d::Zero(), ray);
    if (!t || *t <= 0) return std::nullopt;
    return *t * ray;
  };
  constexpr double kStep = 0.25;
  const int samples = static_cast<int>(std::ceil(cam.width / kStep)) + 1;
  for (int r = 0; r < cam.height; ++r) {
    for (size_t si = 0; si < scene.surfaces.size(); ++si) {
      const Surface& s = scene.surfaces[si];
      double prev_c = 0, prev_f = 0;
      bool has_prev = false;
      for (int k = 0; k < samples; ++k) {
        const double c = std::min(-0.5 + k * kStep, cam.width - 0.5);
        const std::optional<Eigen::Vector3d> x = on_plane(c, r);
        if (!x) {
          has_prev = false;
          continue;
        }
        const double f = Implicit(s, *x);
        if (has_prev && ((prev_f <= 0) != (f <= 0))) {
          double lo = prev_c, hi = c, flo = prev_f;
          for (int it = 0; it < 60 && hi - lo > 1e-9; ++it) {
            const double mid = 0.5 * (lo + hi);
            const std::optional<Eigen::Vector3d> xm = on_plane(mid, r);
            if (!xm) break;
            const double fm = Implicit(s, *xm);
            if ((fm <= 0) == (flo <= 0)) {
              lo = mid;
              flo = fm;
            } else {
              hi = mid;
            }
          }
          const double column = 0.5 * (lo + hi);
          const std::optional<Eigen::Vector3d> p = on_plane(column, r);
          bool keep = p.has_value();
          if (keep) {
            // Seen: the camera's ray meets this surface first, here.
            const std::optional<Hit> seen = FirstHit(scene.surfaces, Eigen::Vector3d::Zero(), *p / p->norm());
            keep = seen && seen->surface == static_cast<int>(si) && std::abs(seen->t - p->norm()) < 1e-6 * p->norm() + 1e-7;
          }
          if (keep) {
            // Lit: past the plate, and nothing between the laser and the point.
            const Eigen::Vector3d to = *p - laser.origin;
            keep = plate.m.dot(to) > laser.slit_distance_mm + 1.0;
            const std::optional<Hit> lit = FirstHit(scene.surfaces, laser.origin, to / to.norm());
            keep = keep && lit && lit->surface == static_cast<int>(si) &&
                   std::abs(lit->t - to.norm()) < 1e-6 * to.norm() + 1e-7;
          }
          if (keep) {
            bundle::LinePoint point;
            point.row = r;
            point.column = column;
            point.point_in_cam = *p;
            point.point_in_world = world_from_cam * *p;
            point.object = s.object;
            truth.push_back(point);
          }
        }
        prev_c = c;
        prev_f = f;
        has_prev = true;
        if (c >= cam.width - 0.5) break;
      }
    }
  }
  std::sort(truth.begin(), truth.end(), [](const bundle::LinePoint& a, const bundle::LinePoint& b) {
    return a.row != b.row ? a.row < b.row : a.column < b.column;
  });
  return truth;
}

cv::Mat AddSensorNoise(const cv::Mat& frame, double read_dn, double shot_dn_per_dn, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  cv::Mat out = frame.clone();
  const int values = frame.cols * frame.channels();
  for (int y = 0; y < frame.rows; ++y) {
    const uint8_t* in = frame.ptr<uint8_t>(y);
    uint8_t* o = out.ptr<uint8_t>(y);
    for (int i = 0; i < values; ++i) {
      const double sigma = std::sqrt(read_dn * read_dn + shot_dn_per_dn * in[i]);
      o[i] = cv::saturate_cast<uint8_t>(std::lround(in[i] + sigma * normal(rng)));
    }
  }
  return out;
}

geometry::Rig WebcamRig(int width, int height) {
  Result<sim::Scene> scene = sim::SceneDefaults("webcam");
  geometry::Rig rig = scene->rig;
  rig.camera = geometry::CameraModel::FromFieldOfView(width, height, 50.0);
  return rig;
}

LaserSheet LeftLaser(const geometry::Rig& rig) {
  Result<sim::Scene> scene = sim::SceneDefaults("webcam");
  LaserSheet laser;
  laser.origin = scene->laser[0].origin_in_cam;
  laser.plane = rig.laser(geometry::LaserId::kLeft);
  const Eigen::Vector3d to_axis = rig.axis_point_in_cam - laser.origin;
  const Eigen::Vector3d n = laser.plane.normal;
  laser.fan_direction = (to_axis - n * n.dot(to_axis)).normalized();
  return laser;
}

}  // namespace rotoscan::testing::povray
