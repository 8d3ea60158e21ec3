// The virtual scanner's scene description: the rig (camera, two line lasers, table), the light and the
// objects, read from a JSON file whose every field has a documented default (SceneDefaults()).
//
// Default rig ("machine_vision" preset), matching the paper's rig (Ko & Yi 2018, §4): a 1288x964 color
// sensor of 3.75 µm pixels with a lens giving 20° horizontal field of view (fx = 644 / tan 10° = 3652 px),
// looking 10° down at the table axis, the middle of an 80 mm tall object on the table 315 mm away on the
// optical axis (the object fills the view, ±41 mm vertically there). Two 660 nm line lasers at the
// camera's height, 173.2 mm left and right of it (baseline = 300 mm * tan 30°), their planes containing
// the table axis (so they cross at 30° to the optical axis). Why 30°: the depth resolution per pixel is
// (pixel footprint at 300 mm = 0.082 mm) / tan 30° = 0.14 mm, occlusions between camera and laser stay
// moderate (the shadowed region grows with the angle) and the line stays thin on surfaces facing the
// camera; Ciclop/Horus-type scanners use the same angle. Table steps of 0.3°.
//
// Radiometry (arbitrary radiance units): a surface of albedo a under light L gives a * L * exposure_us *
// sensitivity electrons per pixel; the laser's `power` is the radiance of its line centre on a white
// surface facing it at 300 mm, falling off as cos(incidence) * 300 / range (a fan spreads in one
// dimension). Electrons saturate at the full well, get shot noise (Poisson, as a Gaussian of variance =
// mean) and read noise, then DN = e * (2^bits - 1) / full_well * 10^(gain_db / 20), rounded and clipped.
//
// JSON (all optional; "preset" first selects the defaults, then fields override):
//   { "preset": "machine_vision" | "webcam", "seed": 1, "steps": 1200,
//     "camera": { "width", "height", "hfov_deg" | ("fx","fy","cx","cy"), "distortion": [k1,k2,p1,p2,k3],
//                 "pixel_size_um", "full_well_e", "read_noise_e", "sensitivity_e_per_us", "gain_db",
//                 "bit_depth": 8|12, "bayer": false, "blur_sigma_px", "laser_exposure_us",
//                 "natural_exposure_us", "color_matrix": [9 numbers, row-major, applied to linear RGB],
//                 "noise": true, "supersampling": 1 },
//     "table": { "axis_point_mm": [x,y,z] (camera frame), "axis_direction": [x,y,z] (up, camera frame),
//                "step_deg": 0.3, "radius_mm": 100, "albedo": [r,g,b] },
//     "lasers": { "left": {...}, "right": {...} } each { "origin_mm": [x,y,z] (camera frame),
//                 "normal": [x,y,z] (optional; default: the plane through origin containing the axis),
//                 "sigma_mm": Gaussian half thickness, "power", "speckle_contrast", "speckle_size_px",
//                 "response": [r,g,b] (sensor response to 660 nm per channel) },
//     "light": { "ambient", "diffuse", "direction": [x,y,z] (towards the lamp, camera frame),
//                "shadows": true (the lamp's light is blocked by the object: cast and self shadows in the
//                natural image, as a real lamp beside the scanner gives), "interreflection": false (one
//                diffuse bounce of the laser lines: Scene::laser_interreflection) },
//     "objects": [ { "type": "mesh", "file": "x.obj|x.ply" (relative to the scene file),
//                    "texture": "x.png" (OBJ with UVs), "up_axis": "y"|"z", "height_mm": 80 (scale to it),
//                    "scale": 1 (when no height_mm) },
//                  { "type": "sphere", "radius_mm", "segments" }, { "type": "cylinder", "radius_mm",
//                    "height_mm", "segments" }, { "type": "box", "size_mm": [x,y,z] },
//                  { "type": "plane", "distance_mm", "angle_deg", "size_mm": [w,h] }   (camera frame:
//                    facing the camera at that distance on the optical axis, turned by angle about the
//                    camera's y axis; the paper's Table 1 accuracy test),
//                  { "type": "checkerboard", "cols", "rows", "square_mm" } (inner corners; target frame
//                    of OpenCV: origin at the first inner corner, z into the board),
//                  { "type": "charuco", "cols": 8, "rows": 6 (squares, as printed boards are counted),
//                    "square_mm": 8, "marker_mm": 6, "dictionary": "DICT_5X5_100" } (a ChArUco board,
//                    calib/charuco.h: a checkerboard of (cols - 1) x (rows - 1) inner corners whose white
//                    squares hold ArUco markers, in the checkerboard's target frame; it is a checkerboard
//                    object to the rest of the simulator: `simulate --kind checkerboard` or
//                    `table-checkerboard` render it at their poses, truth/poses.csv in that frame),
//                  { "type": "calibration_object", "square_mm": 10, "size_mm": 60 } ]
//     "placements": [ { "rotation_deg": [rx,ry,rz], "position_mm": [x,y,0], "comment": "..." }, ... ]
//       the object's poses on the table for `simulate --placement N` / `scan --placement N` (placement 0 is
//       entry 0, or the objects as given when there is no list): all objects together are turned by
//       rotation_deg about the table axes (applied x, y, z), stood on the table (lowest point at z = 0) and
//       centred on the axis, then moved by position_mm (PlaceScene).
//     each object also takes "position_mm": [x,y,z] (table frame; meshes and built-ins stand on the
//     table), "rotation_deg": [rx,ry,rz] (about the table axes, applied x, y, z) and "color": [r,g,b]
//     (albedo 0..1; default light grey) }
#pragma once

#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "rotoscan/core/status.h"
#include "rotoscan/geometry/rig.h"

namespace rotoscan::sim {

struct SensorModel {
  double pixel_size_um = 3.75;
  double full_well_e = 10000.0;
  double read_noise_e = 6.0;
  double sensitivity_e_per_us = 0.35;  // electrons per µs for unit radiance
  double gain_db = 0.0;
  int bit_depth = 8;                   // 8 or 12 (12-bit frames are stored in 16-bit PNG)
  bool bayer = false;                  // RGGB mosaic, then OpenCV demosaicing
  double blur_sigma_px = 0.5;          // optical blur (Gaussian), 0 = none
  double laser_exposure_us = 2000.0;
  double natural_exposure_us = 20000.0;
  std::array<double, 9> color_matrix{1, 0, 0, 0, 1, 0, 0, 0, 1};  // row-major, linear RGB
  bool noise = true;
  int supersampling = 1;               // S x S rays per pixel
  // Webcam effects (all off by default; the "webcam" preset turns them on, renderer.h says how each is
  // made). JPEG quality of an MJPEG stream (each frame through OpenCV's JPEG encoder and decoder; 0 =
  // lossless frames); rolling-shutter readout time per row (µs; 0 = global shutter): rows are exposed one
  // after the other, so a flickering lamp (Scene::ambient_flicker) paints bands across the frame.
  int jpeg_quality = 0;
  double line_time_us = 0.0;

  // Multiplier from electrons to DN.
  double DnPerElectron() const;
  int MaxDn() const { return (1 << bit_depth) - 1; }
};

struct LaserModel {
  Eigen::Vector3d origin_in_cam = Eigen::Vector3d::Zero();
  double sigma_mm = 0.15;            // Gaussian thickness (standard deviation) of the sheet
  double power = 8.0;                // line-centre radiance on white at 300 mm, normal incidence
  double speckle_contrast = 0.15;    // std of the multiplicative speckle factor
  double speckle_size_px = 1.5;      // correlation length of the speckle in the image
  Eigen::Vector3d response{1.0, 0.06, 0.02};  // R G B response to the laser wavelength
  // Speckle from physics instead of speckle_contrast/speckle_size_px: when f_number > 0 the laser image
  // is multiplied by fully developed speckle formed through a circular pupil of this f-number at
  // wavelength_nm (renderer.h, "Speckle"): grain radius 1.22 * wavelength * f_number in the image plane,
  // exponential intensity statistics, contrast 1 before integration over the pixel.
  double f_number = 0.0;
  double wavelength_nm = 660.0;
};

enum class ObjectType { kMesh, kSphere, kCylinder, kBox, kPlane, kCheckerboard, kCalibrationObject };

struct ObjectSpec {
  ObjectType type = ObjectType::kSphere;
  std::filesystem::path file, texture;
  std::string up_axis = "y";
  double height_mm = 0.0, scale = 1.0;
  double radius_mm = 30.0;
  int segments = 128;
  Eigen::Vector3d size_mm{40, 40, 40};
  double distance_mm = 300.0, angle_deg = 0.0;
  int cols = 9, rows = 6;  // checkerboards (ChArUco included): inner corners
  double square_mm = 7.0;
  // ChArUco (JSON type "charuco", read as a kCheckerboard): ArUco markers of this side in the white
  // squares; 0 = a plain checkerboard.
  double marker_mm = 0.0;
  std::string dictionary = "DICT_5X5_100";
  Eigen::Vector3d position_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d rotation_deg = Eigen::Vector3d::Zero();
  Eigen::Vector3d color{0.8, 0.8, 0.8};
  // Glossy material: a Blinn-Phong specular lobe of this strength (white, added to the diffuse albedo's
  // reflection) and exponent, for the lasers and the lamp: glints of the laser, highlights of the lamp.
  double specular = 0.0;
  double shininess = 60.0;
  // Dark-and-white texture: a 3D checker of this pitch (mm, object frame; 0 = none) whose dark cells have
  // albedo `color` * dark_albedo (a solid texture: no UVs needed, on any shape).
  double checker_mm = 0.0;
  double dark_albedo = 0.1;
  // Set by code (not JSON): place the object by this pose instead of position/rotation (and for the
  // plane, instead of distance/angle).
  bool has_pose = false;
  Eigen::Isometry3d table_from_object = Eigen::Isometry3d::Identity();
};

struct Scene {
  std::string preset = "machine_vision";
  std::filesystem::path base_dir;  // directory of the scene file (relative paths)
  std::string source;              // the JSON it was parsed from, normalised (what --resume compares)
  uint64_t seed = 1;
  int steps = 1200;
  geometry::Rig rig;  // camera model, laser planes, axis, step angle: the truth
  SensorModel sensor;
  LaserModel laser[2];
  double table_radius_mm = 100.0;
  Eigen::Vector3d table_albedo{0.08, 0.08, 0.08};
  double ambient = 0.3;
  double diffuse = 1.0;
  Eigen::Vector3d light_direction_in_cam = Eigen::Vector3d(0.3, -1.0, -1.0).normalized();
  bool lamp_shadows = true;
  // Ambient light that changes between frames: each frame's ambient level is multiplied by 1 +
  // ambient_change * (a standard normal deviate of that frame), and by 1 + ambient_flicker * sin(2 pi
  // flicker_hz t) with t the exposure time of the row (mains-powered lamps flicker at twice the mains
  // frequency; with a rolling shutter, SensorModel::line_time_us, the flicker varies along the frame).
  double ambient_change = 0.0;
  double ambient_flicker = 0.0;
  double flicker_hz = 100.0;
  // Laser light scattered into concavities (JSON light.interreflection; the webcam preset turns it on):
  // one diffuse bounce of each laser's lit line onto the visible surface, the second, weaker line of an
  // inside corner (renderer.h, "Interreflection").
  bool laser_interreflection = false;
  std::vector<ObjectSpec> objects;
  // The object's placements on the table (JSON "placements"; empty: one, the objects as given).
  struct Placement {
    Eigen::Vector3d rotation_deg = Eigen::Vector3d::Zero();
    Eigen::Vector3d position_mm = Eigen::Vector3d::Zero();
  };
  std::vector<Placement> placements;
};

// The defaults of a preset ("machine_vision" or "webcam"); kInvalidArgument for another name.
Result<Scene> SceneDefaults(const std::string& preset);

// Parses scene JSON; errors are kInvalidArgument naming the field ("scene.json: camera.width must be ...").
Result<Scene> ParseScene(const std::string& json_text, const std::filesystem::path& base_dir,
                         const std::string& source_name);
Result<Scene> LoadScene(const std::filesystem::path& path);

// The scene with its objects put in placement `placement` (Scene::placements): every object gets an
// explicit pose (ObjectSpec::has_pose). `table_from_reference` (may be null) receives the rigid transform
// from the reference frame (the table frame of the objects as given) to this placement's table frame: the
// truth that aligning the scans of several placements must find (bundle/truth.h, truth/placement.csv).
// Placement 0 of a scene without a list is the scene itself (identity). kInvalidArgument for a placement
// the scene does not define; mesh files' errors as the renderer's.
Result<Scene> PlaceScene(const Scene& scene, int placement, Eigen::Isometry3d* table_from_reference);

// The inner corners of a checkerboard object (ChArUco included) in its target frame, row by row: the
// index is OpenCV's ChArUco corner id. The truth that board detections are compared with.
std::vector<Eigen::Vector3d> BoardCornersInTarget(const ObjectSpec& board);

}  // namespace rotoscan::sim
