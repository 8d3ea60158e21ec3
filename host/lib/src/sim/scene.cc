#include "rotoscan/sim/scene.h"

#include <cmath>

#include <nlohmann/json.hpp>

#include "rotoscan/calib/charuco.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rigid.h"

namespace rotoscan::sim {
namespace fs = std::filesystem;
using json = nlohmann::json;

double SensorModel::DnPerElectron() const {
  return MaxDn() / full_well_e * std::pow(10.0, gain_db / 20.0);
}

namespace {

// The laser plane through `origin` that contains the table axis.
geometry::Plane PlaneThroughAxis(const Eigen::Vector3d& origin, const geometry::Rig& rig) {
  const Eigen::Vector3d normal = (rig.axis_point_in_cam - origin).cross(rig.axis_direction_in_cam);
  return geometry::Plane::FromPointNormal(origin, normal);
}

// Reads fields with range checks; every error names the field.
class Reader {
 public:
  Reader(const json& object, std::string path) : object_(object), path_(std::move(path)) {}
  std::string Name(const char* key) const { return path_.empty() ? key : path_ + "." + key; }
  const json* Get(const char* key) const { return object_.contains(key) ? &object_.at(key) : nullptr; }

  Status Number(const char* key, double lo, double hi, double* value) const {
    const json* v = Get(key);
    if (v == nullptr) return Status::Ok();
    if (!v->is_number() || !std::isfinite(v->get<double>())) {
      return InvalidArgumentError("field '" + Name(key) + "' must be a number");
    }
    const double x = v->get<double>();
    if (x < lo || x > hi) {
      return InvalidArgumentError("field '" + Name(key) + "' = " + std::to_string(x) + " must be in [" +
                                  std::to_string(lo) + ", " + std::to_string(hi) + "]");
    }
    *value = x;
    return Status::Ok();
  }
  Status Int(const char* key, int lo, int hi, int* value) const {
    const json* v = Get(key);
    if (v == nullptr) return Status::Ok();
    if (!v->is_number_integer()) return InvalidArgumentError("field '" + Name(key) + "' must be an integer");
    const int64_t x = v->get<int64_t>();
    if (x < lo || x > hi) {
      return InvalidArgumentError("field '" + Name(key) + "' = " + std::to_string(x) + " must be in [" +
                                  std::to_string(lo) + ", " + std::to_string(hi) + "]");
    }
    *value = static_cast<int>(x);
    return Status::Ok();
  }
  Status Bool(const char* key, bool* value) const {
    const json* v = Get(key);
    if (v == nullptr) return Status::Ok();
    if (!v->is_boolean()) return InvalidArgumentError("field '" + Name(key) + "' must be true or false");
    *value = v->get<bool>();
    return Status::Ok();
  }
  Status String(const char* key, std::string* value) const {
    const json* v = Get(key);
    if (v == nullptr) return Status::Ok();
    if (!v->is_string()) return InvalidArgumentError("field '" + Name(key) + "' must be a string");
    *value = v->get<std::string>();
    return Status::Ok();
  }
  template <std::size_t N>
  Status Numbers(const char* key, double lo, double hi, double* values) const {
    const json* v = Get(key);
    if (v == nullptr) return Status::Ok();
    if (!v->is_array() || v->size() != N) {
      return InvalidArgumentError("field '" + Name(key) + "' must be an array of " + std::to_string(N) +
                                  " numbers");
    }
    for (std::size_t i = 0; i < N; ++i) {
      const json& e = (*v)[i];
      if (!e.is_number() || !std::isfinite(e.get<double>()) || e.get<double>() < lo || e.get<double>() > hi) {
        return InvalidArgumentError("field '" + Name(key) + "[" + std::to_string(i) +
                                    "]' must be a number in [" + std::to_string(lo) + ", " +
                                    std::to_string(hi) + "]");
      }
      values[i] = e.get<double>();
    }
    return Status::Ok();
  }
  Status Vector(const char* key, double lo, double hi, Eigen::Vector3d* value) const {
    double v[3] = {(*value)[0], (*value)[1], (*value)[2]};
    ROTOSCAN_RETURN_IF_ERROR(Numbers<3>(key, lo, hi, v));
    *value = Eigen::Vector3d(v[0], v[1], v[2]);
    return Status::Ok();
  }
  Status Object(const char* key, bool* present) const {
    const json* v = Get(key);
    *present = v != nullptr;
    if (v != nullptr && !v->is_object())
      return InvalidArgumentError("field '" + Name(key) + "' must be an object");
    return Status::Ok();
  }
  // Unknown keys are errors (a typo must not silently fall back to a default).
  Status OnlyKeys(std::initializer_list<const char*> keys) const {
    for (auto it = object_.begin(); it != object_.end(); ++it) {
      bool known = false;
      for (const char* k : keys) known = known || it.key() == k;
      if (!known) return InvalidArgumentError("unknown field '" + Name(it.key().c_str()) + "'");
    }
    return Status::Ok();
  }

 private:
  const json& object_;
  std::string path_;
};

#define RETURN_IF(expr) ROTOSCAN_RETURN_IF_ERROR(expr)

Status ParseCamera(const json& j, Scene* scene) {
  Reader r(j, "camera");
  RETURN_IF(r.OnlyKeys({"width",
                        "height",
                        "hfov_deg",
                        "fx",
                        "fy",
                        "cx",
                        "cy",
                        "distortion",
                        "pixel_size_um",
                        "full_well_e",
                        "read_noise_e",
                        "sensitivity_e_per_us",
                        "gain_db",
                        "bit_depth",
                        "bayer",
                        "blur_sigma_px",
                        "laser_exposure_us",
                        "natural_exposure_us",
                        "color_matrix",
                        "noise",
                        "supersampling",
                        "jpeg_quality",
                        "line_time_us"}));
  geometry::CameraModel& c = scene->rig.camera;
  SensorModel& s = scene->sensor;
  const int old_width = c.width;
  RETURN_IF(r.Int("width", 8, 8192, &c.width));
  RETURN_IF(r.Int("height", 8, 8192, &c.height));
  double hfov = 2.0 * geometry::RadToDeg(std::atan(c.width / 2.0 / c.fx));
  if (c.width != old_width || r.Get("hfov_deg") != nullptr) {
    RETURN_IF(r.Number("hfov_deg", 1.0, 170.0, &hfov));
    const auto d = c.distortion;
    c = geometry::CameraModel::FromFieldOfView(c.width, c.height, hfov);
    c.distortion = d;
  }
  RETURN_IF(r.Number("fx", 1.0, 1e6, &c.fx));
  RETURN_IF(r.Number("fy", 1.0, 1e6, &c.fy));
  RETURN_IF(r.Number("cx", -1e5, 1e5, &c.cx));
  RETURN_IF(r.Number("cy", -1e5, 1e5, &c.cy));
  RETURN_IF(r.Numbers<5>("distortion", -10.0, 10.0, c.distortion.data()));
  RETURN_IF(r.Number("pixel_size_um", 0.1, 100.0, &s.pixel_size_um));
  RETURN_IF(r.Number("full_well_e", 10.0, 1e7, &s.full_well_e));
  RETURN_IF(r.Number("read_noise_e", 0.0, 1e4, &s.read_noise_e));
  RETURN_IF(r.Number("sensitivity_e_per_us", 0.0, 1e6, &s.sensitivity_e_per_us));
  RETURN_IF(r.Number("gain_db", -20.0, 48.0, &s.gain_db));
  RETURN_IF(r.Int("bit_depth", 8, 12, &s.bit_depth));
  if (s.bit_depth != 8 && s.bit_depth != 12)
    return InvalidArgumentError("field 'camera.bit_depth' must be 8 or 12");
  RETURN_IF(r.Bool("bayer", &s.bayer));
  RETURN_IF(r.Number("blur_sigma_px", 0.0, 20.0, &s.blur_sigma_px));
  RETURN_IF(r.Number("laser_exposure_us", 1.0, 1e7, &s.laser_exposure_us));
  RETURN_IF(r.Number("natural_exposure_us", 1.0, 1e7, &s.natural_exposure_us));
  RETURN_IF(r.Numbers<9>("color_matrix", -10.0, 10.0, s.color_matrix.data()));
  RETURN_IF(r.Bool("noise", &s.noise));
  RETURN_IF(r.Int("supersampling", 1, 8, &s.supersampling));
  RETURN_IF(r.Int("jpeg_quality", 0, 100, &s.jpeg_quality));
  if (s.jpeg_quality > 0 && s.bit_depth != 8)
    return InvalidArgumentError("field 'camera.jpeg_quality' needs bit_depth 8 (JPEG frames are 8-bit)");
  RETURN_IF(r.Number("line_time_us", 0.0, 1e5, &s.line_time_us));
  RETURN_IF(c.Validate().WithContext("field 'camera'"));
  // A wide or off-centre view with the default distortion has no inverse at the border (NaN rays).
  return c.CheckInvertible().WithContext("field 'camera' (hfov_deg, cx, cy, distortion)");
}

Status ParseLaser(const json& j, const std::string& name, Scene* scene, int index, bool* explicit_normal) {
  Reader r(j, "lasers." + name);
  RETURN_IF(r.OnlyKeys(
      {"origin_mm", "normal", "sigma_mm", "power", "speckle_contrast", "speckle_size_px", "response",
       "f_number", "wavelength_nm"}));
  LaserModel& l = scene->laser[index];
  RETURN_IF(r.Vector("origin_mm", -1e4, 1e4, &l.origin_in_cam));
  RETURN_IF(r.Number("sigma_mm", 1e-3, 50.0, &l.sigma_mm));
  RETURN_IF(r.Number("power", 0.0, 1e6, &l.power));
  RETURN_IF(r.Number("speckle_contrast", 0.0, 1.0, &l.speckle_contrast));
  RETURN_IF(r.Number("speckle_size_px", 0.1, 100.0, &l.speckle_size_px));
  RETURN_IF(r.Vector("response", 0.0, 10.0, &l.response));
  RETURN_IF(r.Number("f_number", 0.0, 64.0, &l.f_number));  // 0: the older speckle model
  if (l.f_number > 0.0 && l.f_number < 0.5)
    return InvalidArgumentError("field 'lasers." + name + ".f_number' must be 0 (off) or in [0.5, 64]");
  RETURN_IF(r.Number("wavelength_nm", 200.0, 2000.0, &l.wavelength_nm));
  if (r.Get("normal") != nullptr) {
    Eigen::Vector3d n(0, 0, 0);
    RETURN_IF(r.Vector("normal", -1e6, 1e6, &n));
    if (n.norm() < 1e-9) return InvalidArgumentError("field 'lasers." + name + ".normal' must be non-zero");
    scene->rig.laser_plane[index] = geometry::Plane::FromPointNormal(l.origin_in_cam, n);
    *explicit_normal = true;
  }
  return Status::Ok();
}

Status ParseObject(const json& j, std::size_t index, const fs::path& base_dir, ObjectSpec* o) {
  const std::string path = "objects[" + std::to_string(index) + "]";
  if (!j.is_object()) return InvalidArgumentError("field '" + path + "' must be an object");
  Reader r(j, path);
  RETURN_IF(r.OnlyKeys({"type", "file", "texture", "up_axis", "height_mm", "scale", "radius_mm", "segments",
                        "size_mm", "distance_mm", "angle_deg", "cols", "rows", "square_mm", "marker_mm",
                        "dictionary", "position_mm", "rotation_deg", "color", "specular", "shininess",
                        "checker_mm", "dark_albedo"}));
  std::string type;
  if (r.Get("type") == nullptr) return InvalidArgumentError("missing field '" + path + ".type'");
  RETURN_IF(r.String("type", &type));
  const std::pair<const char*, ObjectType> types[] = {{"mesh", ObjectType::kMesh},
                                                      {"sphere", ObjectType::kSphere},
                                                      {"cylinder", ObjectType::kCylinder},
                                                      {"box", ObjectType::kBox},
                                                      {"plane", ObjectType::kPlane},
                                                      {"checkerboard", ObjectType::kCheckerboard},
                                                      {"charuco", ObjectType::kCheckerboard},
                                                      {"calibration_object", ObjectType::kCalibrationObject}};
  const bool charuco = type == "charuco";
  bool known = false;
  for (const auto& [n, t] : types) {
    if (type == n) {
      o->type = t;
      known = true;
    }
  }
  if (!known) {
    return InvalidArgumentError("field '" + path + ".type' = '" + type +
                                "' is not one of mesh, sphere, cylinder, box, plane, checkerboard, "
                                "charuco, calibration_object");
  }
  if (o->type == ObjectType::kCalibrationObject) o->square_mm = 10.0, o->size_mm = {60, 60, 60};
  if (charuco) o->cols = 8, o->rows = 6, o->square_mm = 8.0, o->marker_mm = 6.0;  // squares until below
  std::string file, texture;
  RETURN_IF(r.String("file", &file));
  RETURN_IF(r.String("texture", &texture));
  if (o->type == ObjectType::kMesh && file.empty())
    return InvalidArgumentError("missing field '" + path + ".file'");
  if (!file.empty()) o->file = fs::path(file).is_absolute() ? fs::path(file) : base_dir / file;
  if (!texture.empty()) o->texture = fs::path(texture).is_absolute() ? fs::path(texture) : base_dir / texture;
  RETURN_IF(r.String("up_axis", &o->up_axis));
  if (o->up_axis != "y" && o->up_axis != "z")
    return InvalidArgumentError("field '" + path + ".up_axis' must be y or z");
  RETURN_IF(r.Number("height_mm", 0.0, 1e4, &o->height_mm));
  RETURN_IF(r.Number("specular", 0.0, 100.0, &o->specular));
  RETURN_IF(r.Number("shininess", 1.0, 1e4, &o->shininess));
  RETURN_IF(r.Number("checker_mm", 0.0, 1e4, &o->checker_mm));
  RETURN_IF(r.Number("dark_albedo", 0.0, 1.0, &o->dark_albedo));
  RETURN_IF(r.Number("scale", 1e-6, 1e6, &o->scale));
  RETURN_IF(r.Number("radius_mm", 1e-3, 1e4, &o->radius_mm));
  RETURN_IF(r.Int("segments", 3, 4096, &o->segments));
  if (o->type == ObjectType::kPlane && r.Get("size_mm") != nullptr && r.Get("size_mm")->is_array() &&
      r.Get("size_mm")->size() == 2) {
    double wh[2];
    RETURN_IF(r.Numbers<2>("size_mm", 1e-3, 1e4, wh));
    o->size_mm = Eigen::Vector3d(wh[0], wh[1], 0.0);
  } else {
    RETURN_IF(r.Vector("size_mm", 1e-3, 1e4, &o->size_mm));
  }
  RETURN_IF(r.Number("distance_mm", 1.0, 1e5, &o->distance_mm));
  RETURN_IF(r.Number("angle_deg", -89.0, 89.0, &o->angle_deg));
  RETURN_IF(r.Int("cols", 2, 100, &o->cols));
  RETURN_IF(r.Int("rows", 2, 100, &o->rows));
  RETURN_IF(r.Number("square_mm", 0.1, 1e3, &o->square_mm));
  if (charuco) {
    RETURN_IF(r.Number("marker_mm", 0.01, 1e3, &o->marker_mm));
    RETURN_IF(r.String("dictionary", &o->dictionary));
    Result<calib::CharucoBoard> board = calib::ParseCharucoBoard(
        std::to_string(o->cols) + "x" + std::to_string(o->rows), o->square_mm, o->marker_mm, o->dictionary);
    if (!board.ok())
      return InvalidArgumentError("field '" + path + "' (charuco): " + board.status().message());
    o->dictionary = board->dictionary;
    o->cols -= 1;  // squares -> inner corners (the checkerboard's convention)
    o->rows -= 1;
  } else if (r.Get("marker_mm") != nullptr || r.Get("dictionary") != nullptr) {
    return InvalidArgumentError("fields '" + path + ".marker_mm' and '.dictionary' belong to a charuco only");
  }
  RETURN_IF(r.Vector("position_mm", -1e4, 1e4, &o->position_mm));
  RETURN_IF(r.Vector("rotation_deg", -360.0, 360.0, &o->rotation_deg));
  RETURN_IF(r.Vector("color", 0.0, 1.0, &o->color));
  return Status::Ok();
}

}  // namespace

Result<Scene> SceneDefaults(const std::string& preset) {
  Scene scene;
  scene.preset = preset;
  geometry::Rig& rig = scene.rig;
  rig.camera = geometry::CameraModel::FromFieldOfView(1288, 964, 20.0);
  rig.camera.distortion = {-0.08, 0.12, 0.0002, -0.0001, 0.0};
  // Camera 10° down: the table's up axis in the camera frame, and the table centre 40 mm below the
  // point of the optical axis at 300 mm (an 80 mm object is centred in the view).
  const double pitch = geometry::DegToRad(10.0);
  rig.axis_direction_in_cam = Eigen::Vector3d(0.0, -std::cos(pitch), -std::sin(pitch));
  rig.axis_point_in_cam = Eigen::Vector3d(0, 0, 315) - 40.0 * rig.axis_direction_in_cam;
  rig.step_angle_rad = geometry::DegToRad(0.3);
  const double baseline = 300.0 * std::tan(geometry::DegToRad(30.0));
  scene.laser[0].origin_in_cam = Eigen::Vector3d(-baseline, 0, 0);
  scene.laser[1].origin_in_cam = Eigen::Vector3d(baseline, 0, 0);
  if (preset == "webcam") {
    // A Logitech C270-like webcam (DESIGN.md "What real laser frames look like"): wide saturated lines,
    // Bayer demosaicing and a color matrix whose negative terms make green drop under the red line.
    rig.camera = geometry::CameraModel::FromFieldOfView(1280, 960, 50.0);
    rig.camera.distortion = {0.05, -0.15, 0.0, 0.0, 0.0};
    SensorModel& s = scene.sensor;
    s.pixel_size_um = 2.8;
    // Tuned to DESIGN.md's real C270 figures (RealCameraTest.WebcamPresetMatchesRealFrameStatistics: a
    // white sphere gives 77 % of line rows saturated, peak difference 172 DN, off red 82 DN, 12 px wide,
    // green drop 57 DN, background noise 1.5 DN against 75 %, 160, 80, 12, 50, 1.4). The full well is more
    // than a 2.8 um pixel holds: it stands in for the webcam's noise reduction, which is not modelled
    // (with 4,000 e the difference's noise was 3.6 DN).
    s.full_well_e = 16000.0;
    s.read_noise_e = 10.0;
    s.sensitivity_e_per_us = 0.4;
    s.bayer = true;
    s.blur_sigma_px = 1.2;
    s.laser_exposure_us = 8000.0;
    s.natural_exposure_us = 33000.0;
    s.color_matrix = {1.5, -0.3, -0.2, -0.45, 1.6, -0.15, -0.1, -0.4, 1.5};
    for (LaserModel& l : scene.laser) {
      l.sigma_mm = 0.7;
      l.power = 7.0;
      l.speckle_contrast = 0.25;
      l.speckle_size_px = 3.0;
      l.response = {1.0, 0.05, 0.05};
      l.f_number = 4.0;  // fully developed speckle through an f/4 pupil (renderer.h)
    }
    // An MJPEG stream (the C270 sends 1280x960 only as MJPEG; its quality is not published: 85 is
    // typical of UVC encoders, and blocks and ringing show at it) read out by a rolling shutter at
    // 15 frames/s (1 / 15 s over 960 rows), under a lamp that flickers a little and an ambient level that
    // changes between frames (0.5 % and 0.3 %: with more, the difference's background noise exceeds the
    // real 1.4 DN; the JPEG quality changes none of DESIGN's figures: 75 gives the same).
    s.jpeg_quality = 85;
    s.line_time_us = 69.0;
    scene.ambient_change = 0.003;
    scene.ambient_flicker = 0.005;
    scene.laser_interreflection = true;  // a second, weaker line in concavities (renderer.h)
    rig.axis_point_in_cam = Eigen::Vector3d(0, 0, 280) - 40.0 * rig.axis_direction_in_cam;
    scene.ambient = 1.8;  // the off frame's red about 80 DN on white (DESIGN.md)
  } else if (preset != "machine_vision") {
    return InvalidArgumentError("field 'preset' = '" + preset + "' must be machine_vision or webcam");
  }
  for (int i = 0; i < 2; ++i) rig.laser_plane[i] = PlaneThroughAxis(scene.laser[i].origin_in_cam, rig);
  return scene;
}

Result<Scene> ParseScene(const std::string& json_text, const fs::path& base_dir,
                         const std::string& source_name) {
  auto parse = [&]() -> Result<Scene> {
    json root;
    try {
      root = json::parse(json_text);
    } catch (const json::exception& e) {
      return InvalidArgumentError(std::string("not valid JSON: ") + e.what());
    }
    if (!root.is_object()) return InvalidArgumentError("the scene must be a JSON object");
    Reader top(root, "");
    RETURN_IF(top.OnlyKeys(
        {"preset", "seed", "steps", "camera", "table", "lasers", "light", "objects", "placements", "comment"}));
    std::string preset = "machine_vision";
    RETURN_IF(top.String("preset", &preset));
    ROTOSCAN_ASSIGN_OR_RETURN(Scene scene, SceneDefaults(preset));
    scene.base_dir = base_dir;
    scene.source = root.dump();
    double seed = 1;
    RETURN_IF(top.Number("seed", 0, 9007199254740992.0, &seed));
    scene.seed = static_cast<uint64_t>(seed);
    RETURN_IF(top.Int("steps", 1, 1'000'000, &scene.steps));
    bool present = false;
    RETURN_IF(top.Object("camera", &present));
    if (present) RETURN_IF(ParseCamera(root["camera"], &scene));

    RETURN_IF(top.Object("table", &present));
    if (present) {
      Reader r(root["table"], "table");
      RETURN_IF(r.OnlyKeys({"axis_point_mm", "axis_direction", "step_deg", "radius_mm", "albedo"}));
      RETURN_IF(r.Vector("axis_point_mm", -1e4, 1e4, &scene.rig.axis_point_in_cam));
      RETURN_IF(r.Vector("axis_direction", -1e6, 1e6, &scene.rig.axis_direction_in_cam));
      if (scene.rig.axis_direction_in_cam.norm() < 1e-9) {
        return InvalidArgumentError("field 'table.axis_direction' must be non-zero");
      }
      scene.rig.axis_direction_in_cam.normalize();
      double step_deg = geometry::RadToDeg(scene.rig.step_angle_rad);
      RETURN_IF(r.Number("step_deg", 1e-4, 360.0, &step_deg));
      scene.rig.step_angle_rad = geometry::DegToRad(step_deg);
      RETURN_IF(r.Number("radius_mm", 1.0, 1e4, &scene.table_radius_mm));
      RETURN_IF(r.Vector("albedo", 0.0, 1.0, &scene.table_albedo));
    }
    bool explicit_normal[2] = {false, false};
    RETURN_IF(top.Object("lasers", &present));
    if (present) {
      Reader r(root["lasers"], "lasers");
      RETURN_IF(r.OnlyKeys({"left", "right"}));
      const char* names[2] = {"left", "right"};
      for (int i = 0; i < 2; ++i) {
        RETURN_IF(r.Object(names[i], &present));
        if (present)
          RETURN_IF(ParseLaser(root["lasers"][names[i]], names[i], &scene, i, &explicit_normal[i]));
      }
    }
    for (int i = 0; i < 2; ++i) {
      if (!explicit_normal[i]) {
        const Eigen::Vector3d n = (scene.rig.axis_point_in_cam - scene.laser[i].origin_in_cam)
                                      .cross(scene.rig.axis_direction_in_cam);
        if (n.norm() < 1e-9) {
          return InvalidArgumentError(std::string("field 'lasers.") + (i ? "right" : "left") +
                                      ".origin_mm' lies on the table axis: give a normal");
        }
        scene.rig.laser_plane[i] = PlaneThroughAxis(scene.laser[i].origin_in_cam, scene.rig);
      }
    }
    RETURN_IF(top.Object("light", &present));
    if (present) {
      Reader r(root["light"], "light");
      RETURN_IF(r.OnlyKeys(
          {"ambient", "diffuse", "direction", "shadows", "ambient_change", "ambient_flicker", "flicker_hz",
           "interreflection"}));
      RETURN_IF(r.Bool("interreflection", &scene.laser_interreflection));
      RETURN_IF(r.Number("ambient_change", 0.0, 0.5, &scene.ambient_change));
      RETURN_IF(r.Number("ambient_flicker", 0.0, 1.0, &scene.ambient_flicker));
      RETURN_IF(r.Number("flicker_hz", 0.0, 1e4, &scene.flicker_hz));
      RETURN_IF(r.Bool("shadows", &scene.lamp_shadows));
      RETURN_IF(r.Number("ambient", 0.0, 1e4, &scene.ambient));
      RETURN_IF(r.Number("diffuse", 0.0, 1e4, &scene.diffuse));
      RETURN_IF(r.Vector("direction", -1e6, 1e6, &scene.light_direction_in_cam));
      if (scene.light_direction_in_cam.norm() < 1e-9) {
        return InvalidArgumentError("field 'light.direction' must be non-zero");
      }
      scene.light_direction_in_cam.normalize();
    }
    if (const json* objects = top.Get("objects")) {
      if (!objects->is_array()) return InvalidArgumentError("field 'objects' must be an array");
      if (objects->size() > 1000) return InvalidArgumentError("field 'objects' has more than 1000 entries");
      for (std::size_t i = 0; i < objects->size(); ++i) {
        ObjectSpec o;
        RETURN_IF(ParseObject((*objects)[i], i, base_dir, &o));
        scene.objects.push_back(o);
      }
    }
    if (const json* placements = top.Get("placements")) {
      if (!placements->is_array() || placements->empty() || placements->size() > 256) {
        return InvalidArgumentError("field 'placements' must be an array of 1 to 256 objects");
      }
      for (std::size_t i = 0; i < placements->size(); ++i) {
        const json& entry = (*placements)[i];
        const std::string name = "placements[" + std::to_string(i) + "]";
        if (!entry.is_object()) return InvalidArgumentError("field '" + name + "' must be an object");
        Reader r(entry, name);
        RETURN_IF(r.OnlyKeys({"rotation_deg", "position_mm", "comment"}));
        Scene::Placement placement;
        RETURN_IF(r.Vector("rotation_deg", -360.0, 360.0, &placement.rotation_deg));
        RETURN_IF(r.Vector("position_mm", -1e3, 1e3, &placement.position_mm));
        scene.placements.push_back(placement);
      }
    }
    RETURN_IF(scene.rig.Validate().WithContext("rig"));
    return scene;
  };
  Result<Scene> result = parse();
  if (!result.ok()) return result.status().WithContext(source_name);
  return result;
}

Result<Scene> LoadScene(const fs::path& path) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::string text, ReadFile(path, std::size_t{16} << 20));
  return ParseScene(text, path.parent_path(), path.string());
}

std::vector<Eigen::Vector3d> BoardCornersInTarget(const ObjectSpec& board) {
  std::vector<Eigen::Vector3d> corners;
  for (int r = 0; r < board.rows; ++r) {
    for (int c = 0; c < board.cols; ++c) corners.emplace_back(c * board.square_mm, r * board.square_mm, 0.0);
  }
  return corners;
}

}  // namespace rotoscan::sim
