// Issue 15: the extractor meets frames from a renderer we did not write. POV-Ray 3.7 (Debian's `povray`)
// renders our rig's camera, a line laser and a lamp over objects with analytic surfaces; the true line is
// computed here from the geometry alone (laser plane ∩ surface, projected with the rig, seen by the camera
// and lit by the laser), never by our renderer (sim/). The shading, shadows, highlights and anti-aliasing
// of the frames are POV-Ray's.
//
// Why C++ in the tests and not a script: the rig (geometry::Rig), the truth format (bundle/truth.h) and the
// extractor are C++; one code path writes the scene, the truth and the bundle from the same values.
//
// Conventions:
// - Camera. Ours: x right, y down, z forward (right-handed), pixel (0, 0) the centre of the top-left pixel
//   (geometry/camera.h, paper eq. 2). POV-Ray: left-handed, y up. A point (x, y, z) of our camera frame is
//   written as <x, -y, z>. POV-Ray's perspective camera shoots, for the image-plane coordinates (u, v) in
//   [-1/2, 1/2] (u to the right, v up), the ray direction + u right + v up, and pixel column i covers
//   u in [i/W - 1/2, (i+1)/W - 1/2]. So right = <W/fx, 0, 0>, up = <0, H/fy, 0> and direction =
//   <(W/2 - 1/2 - cx)/fx, (cy + 1/2 - H/2)/fy, 1> put pixel (c, r) on the ray ((c - cx)/fx, (r - cy)/fy, 1)
//   of eq. 2. POV-Ray has no lens distortion: the rig must have none (PovScene::Check).
// - Laser. A sheet of light: a linear area light of `sources` point lights spread over `source_mm` along
//   the laser plane's normal, centred on the laser's origin, behind an opaque plate (invisible to the
//   camera) at `slit_distance_mm` along the fan's central direction, with a slit of `slit_mm` centred on
//   the plane. Across the sheet each point light lights a band (the slit's shadow edges); their sum is
//   a trapezoid, a triangle when source_mm = slit_mm / (1 - k), k = slit distance / distance along the fan
//   (SheetProfile computes it exactly, point light by point light, as POV-Ray does). Symmetric about the
//   plane, so the line's centre in 3D is the plane's.
// - Lamp: a point light (POV-Ray's shadows) plus a uniform ambient level, in both frames.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "rotoscan/bundle/truth.h"
#include "rotoscan/core/status.h"
#include "rotoscan/geometry/plane.h"
#include "rotoscan/geometry/rig.h"

namespace rotoscan::testing::povray {

// An analytic surface, camera frame, mm.
struct Surface {
  enum class Kind { kPlane, kSphere, kCylinder };
  Kind kind = Kind::kPlane;
  geometry::Plane plane;                            // kPlane (infinite)
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // kSphere centre, kCylinder a point on the axis
  Eigen::Vector3d axis = Eigen::Vector3d::UnitY();   // kCylinder axis (unit); rendered 4 m long
  double radius_mm = 0.0;
  int object = 0;  // truth's object index: 0 the background (the truth format's "table"), 1.. objects
  // Material (POV-Ray finish): albedo, a 3D checker of `checker_mm` (0: none) whose dark cells have
  // albedo * dark_albedo, and a Phong highlight (0: none) of `phong_size` (glints of the laser).
  Eigen::Vector3d albedo{0.8, 0.8, 0.8};
  double checker_mm = 0.0;
  double dark_albedo = 0.15;
  // The checker's frame (camera from checker): dark cells where floor(q.x) + floor(q.y) + floor(q.z) is
  // odd, q = (point in this frame) / checker_mm + 0.25, as our renderer's solid checker (sim/mesh.cc).
  Eigen::Isometry3d checker_frame = Eigen::Isometry3d::Identity();
  double phong = 0.0;
  double phong_size = 40.0;
};

struct LaserSheet {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  // camera frame, mm; on `plane`
  geometry::Plane plane;                              // camera frame
  Eigen::Vector3d fan_direction = Eigen::Vector3d::UnitZ();  // unit, in the plane: the fan's centre
  double slit_distance_mm = 40.0;
  double slit_mm = 0.2;
  double source_mm = 0.2;
  int sources = 33;
  // POV-Ray's adaptive area light (-1: off, every point light tested at every point). Exact here when
  // source_mm <= slit_mm (then the lit point lights are always a run that holds an end of the array or
  // all of it, so corners that agree speak for everything between them); it spares most shadow rays.
  int adaptive = 0;
  double power = 1.0;                             // radiance scale of the line centre (POV-Ray colour)
  Eigen::Vector3d rgb{1.0, 0.05, 0.05};           // red laser: what the sensor's channels see
};

struct Lamp {
  Eigen::Vector3d position{300.0, -1000.0, -1000.0};  // camera frame, mm
  double intensity = 0.3;
  double ambient = 0.12;  // ambient level (POV-Ray's ambient_light times each finish's ambient)
};

enum class Frame { kLaserOn, kLaserOff, kMarkers };

struct PovScene {
  geometry::Rig rig;  // camera (no distortion) and laser planes; laser.plane is one of them
  std::vector<Surface> surfaces;
  LaserSheet laser;
  Lamp lamp;
  // kMarkers: self-luminous spheres of marker_radius_mm at these points (camera frame) on black, nothing
  // else: checks the camera's projection.
  std::vector<Eigen::Vector3d> markers;
  double marker_radius_mm = 0.6;
  // Anti-aliasing (POV-Ray +A<threshold> +AM<method> +R<depth>, no jitter).
  double aa_threshold = 0.0;
  int aa_method = 1;
  int aa_depth = 3;

  Status Check() const;
};

// The POV-Ray scene text of one frame.
std::string SceneText(const PovScene& scene, Frame frame);

// True when `povray` runs (POV-Ray 3.7).
bool PovrayAvailable();

// Writes the scene under `work_dir`, runs povray (8-bit PNG, linear: File_Gamma 1.0) and reads the frame
// back (CV_8UC3, BGR). kNotFound when povray is missing, kInternal when it fails (its log is in work_dir).
Result<cv::Mat> Render(const PovScene& scene, Frame frame, const std::filesystem::path& work_dir,
                       const std::string& name);

// The relative intensity (0..1) of the sheet at `point` (camera frame): the share of the point lights
// that see the point through the slit. Shadows by objects and the incidence angle are not included.
double SheetProfile(const LaserSheet& laser, const Eigen::Vector3d& point);

// The first surface hit by the ray origin + t dir (t > min_t): its index and t, or nullopt.
struct Hit {
  int surface = -1;
  double t = 0.0;
};
std::optional<Hit> FirstHit(const std::vector<Surface>& surfaces, const Eigen::Vector3d& origin,
                            const Eigen::Vector3d& dir, double min_t = 1e-6);

// The true line (bundle/truth.h LinePoint, object = Surface::object), sorted by row then column: for every
// image row, each column where (laser plane ∩ a surface) crosses it, kept where the camera sees that
// point first along its ray and the laser lights it (nothing between it and the laser's origin, past the
// plate). Columns are found by bisection to 1e-9 px between samples 0.25 px apart; point_in_world is the
// world frame of the table at angle 0 (Rig::WorldFromCamAtAngle).
std::vector<bundle::LinePoint> AnalyticLineTruth(const PovScene& scene);

// Our sensor noise on a POV-Ray frame (POV-Ray renders without noise): Gaussian, sigma^2 =
// read_dn^2 + shot_dn_per_dn * DN, rounded and clipped, from `seed`.
cv::Mat AddSensorNoise(const cv::Mat& frame, double read_dn, double shot_dn_per_dn, uint64_t seed);

// The rig of the webcam preset (sim/scene.cc: 50° field of view, camera 10° down, lasers ±173 mm) at
// width x height with no distortion, and the left laser as a sheet aimed at the table axis.
geometry::Rig WebcamRig(int width, int height);
LaserSheet LeftLaser(const geometry::Rig& rig);

}  // namespace rotoscan::testing::povray
