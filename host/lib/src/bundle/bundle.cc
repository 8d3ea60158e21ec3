#include "rotoscan/bundle/bundle.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <cmath>
#include <set>
#include <system_error>
#include <tuple>
#include <utility>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rotoscan/core/check.h"
#include "rotoscan/core/file.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/geometry/image_file.h"
#include "rotoscan/geometry/rigid.h"

namespace rotoscan::bundle {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

constexpr std::size_t kMaxJsonBytes = std::size_t{512} << 20;
constexpr std::size_t kMaxStringLength = 4096;

const char* const kKindNames[] = {"scan", "calibration"};
const char* const kLaserNames[] = {"left", "right", "off", "natural"};
const char* const kTargetNames[] = {"none", "calibration_object", "checkerboard", "table_checkerboard"};

template <typename Enum, std::size_t N>
Result<Enum> ParseName(const std::string& name, const char* const (&names)[N], const char* what) {
  for (std::size_t i = 0; i < N; ++i) {
    if (name == names[i]) return static_cast<Enum>(i);
  }
  std::string allowed;
  for (std::size_t i = 0; i < N; ++i) allowed += std::string(i ? ", " : "") + names[i];
  return InvalidArgumentError("unknown " + std::string(what) + " '" + name + "' (one of " + allowed + ")");
}

// Typed access to JSON fields with errors that name the field.
class Fields {
 public:
  Fields(const json& object, std::string path) : object_(object), path_(std::move(path)) {}

  Status Require() const {
    if (!object_.is_object()) return CorruptDataError("field '" + path_ + "' must be an object");
    return Status::Ok();
  }
  bool Has(const char* key) const { return object_.contains(key); }
  std::string Name(const char* key) const { return path_.empty() ? key : path_ + "." + key; }

  Status Number(const char* key, double* value, bool required = true) const {
    if (!object_.contains(key)) {
      return required ? CorruptDataError("missing field '" + Name(key) + "'") : Status::Ok();
    }
    const json& v = object_.at(key);
    if (!v.is_number() || !std::isfinite(v.get<double>())) {
      return CorruptDataError("field '" + Name(key) + "' must be a finite number");
    }
    *value = v.get<double>();
    return Status::Ok();
  }
  Status Integer(const char* key, int64_t lo, int64_t hi, int64_t* value, bool required = true) const {
    if (!object_.contains(key)) {
      return required ? CorruptDataError("missing field '" + Name(key) + "'") : Status::Ok();
    }
    const json& v = object_.at(key);
    if (!v.is_number_integer()) return CorruptDataError("field '" + Name(key) + "' must be an integer");
    const int64_t x =
        v.is_number_unsigned() && v.get<uint64_t>() > uint64_t(INT64_MAX) ? INT64_MAX : v.get<int64_t>();
    if (x < lo || x > hi) {
      return CorruptDataError("field '" + Name(key) + "' = " + std::to_string(x) + " is outside [" +
                              std::to_string(lo) + ", " + std::to_string(hi) + "]");
    }
    *value = x;
    return Status::Ok();
  }
  Status Int(const char* key, int lo, int hi, int* value, bool required = true) const {
    int64_t x = *value;
    ROTOSCAN_RETURN_IF_ERROR(Integer(key, lo, hi, &x, required));
    *value = static_cast<int>(x);
    return Status::Ok();
  }
  Status String(const char* key, std::string* value, bool required = true) const {
    if (!object_.contains(key)) {
      return required ? CorruptDataError("missing field '" + Name(key) + "'") : Status::Ok();
    }
    const json& v = object_.at(key);
    if (!v.is_string()) return CorruptDataError("field '" + Name(key) + "' must be a string");
    if (v.get_ref<const std::string&>().size() > kMaxStringLength) {
      return CorruptDataError("field '" + Name(key) + "' is too long");
    }
    *value = v.get<std::string>();
    return Status::Ok();
  }
  Status Bool(const char* key, bool* value) const {
    if (!object_.contains(key)) return Status::Ok();
    const json& v = object_.at(key);
    if (!v.is_boolean()) return CorruptDataError("field '" + Name(key) + "' must be true or false");
    *value = v.get<bool>();
    return Status::Ok();
  }
  Status Array(const char* key, std::size_t size, double* values) const {
    if (!object_.contains(key)) return CorruptDataError("missing field '" + Name(key) + "'");
    const json& v = object_.at(key);
    if (!v.is_array() || v.size() != size) {
      return CorruptDataError("field '" + Name(key) + "' must be an array of " + std::to_string(size) +
                              " numbers");
    }
    for (std::size_t i = 0; i < size; ++i) {
      if (!v[i].is_number() || !std::isfinite(v[i].get<double>())) {
        return CorruptDataError("field '" + Name(key) + "[" + std::to_string(i) +
                                "]' must be a finite number");
      }
      values[i] = v[i].get<double>();
    }
    return Status::Ok();
  }

 private:
  const json& object_;
  std::string path_;
};

Status CheckRelativeFile(const std::string& file, const std::string& field) {
  if (file.empty()) return CorruptDataError("field '" + field + "' is empty");
  const fs::path p(file);
  if (p.is_absolute()) return CorruptDataError("field '" + field + "' must be a relative path: " + file);
  for (const auto& part : p) {
    if (part == "..") return CorruptDataError("field '" + field + "' must stay inside the bundle: " + file);
  }
  return Status::Ok();
}

Status ValidateHeader(const BundleHeader& header) {
  if (header.format_version < 1 || header.format_version > kMaxFormatVersion) {
    return InvalidArgumentError("format_version " + std::to_string(header.format_version) +
                                " is not supported (this build reads 1.." + std::to_string(kMaxFormatVersion) +
                                ")");
  }
  if (header.shared_off_frame && header.format_version < 2) {
    return InvalidArgumentError("a shared off frame needs format_version 2");
  }
  const CameraInfo& c = header.camera;
  ROTOSCAN_RETURN_IF_ERROR(c.model.Validate().WithContext("camera"));
  if (c.model.width > kMaxImageSide || c.model.height > kMaxImageSide) {
    return InvalidArgumentError("camera image size exceeds " + std::to_string(kMaxImageSide));
  }
  if (c.channels != 1 && c.channels != 3) return InvalidArgumentError("camera.channels must be 1 or 3");
  if (c.bit_depth < 1 || c.bit_depth > 16) return InvalidArgumentError("camera.bit_depth must be 1..16");
  if (c.bayer && c.channels != 1) return InvalidArgumentError("camera.bayer requires channels = 1");
  if (!(header.table_step_rad >= 0.0) || !std::isfinite(header.table_step_rad)) {
    return InvalidArgumentError("table_step_deg must be a finite number >= 0");
  }
  if (header.placement < 0 || header.placement > 255) return InvalidArgumentError("placement must be 0..255");
  return Status::Ok();
}

Status ValidateImage(const CameraInfo& camera, const cv::Mat& image, const std::string& name) {
  if (image.empty()) return InvalidArgumentError(name + ": empty image");
  if (image.cols != camera.model.width || image.rows != camera.model.height) {
    return InvalidArgumentError(name + ": image is " + std::to_string(image.cols) + "x" +
                                std::to_string(image.rows) + ", the bundle's camera is " +
                                std::to_string(camera.model.width) + "x" +
                                std::to_string(camera.model.height));
  }
  if (image.channels() != camera.channels) {
    return InvalidArgumentError(name + ": image has " + std::to_string(image.channels()) +
                                " channels, the bundle's camera " + std::to_string(camera.channels));
  }
  const int depth = image.depth();
  if (depth != CV_8U && depth != CV_16U) return InvalidArgumentError(name + ": image must be 8U or 16U");
  if ((camera.bit_depth > 8) != (depth == CV_16U)) {
    return InvalidArgumentError(name + ": image depth does not match camera.bit_depth " +
                                std::to_string(camera.bit_depth));
  }
  return Status::Ok();
}

json FrameJson(const FrameRecord& f) {
  return {{"file", f.file},
          {"step", f.step},
          {"table_angle_deg", geometry::RadToDeg(f.table_angle_rad)},
          {"laser", LaserStateName(f.laser)},
          {"trigger_seq", f.trigger_seq},
          {"device_time_us", f.device_time_us},
          {"exposure_us", f.exposure_us},
          {"pose", f.pose}};
}

int LaserOrder(LaserState s) {
  return static_cast<int>(s);
}

}  // namespace

const char* BundleKindName(BundleKind kind) {
  return kKindNames[static_cast<int>(kind)];
}
const char* LaserStateName(LaserState state) {
  return kLaserNames[static_cast<int>(state)];
}
const char* TargetKindName(TargetKind kind) {
  return kTargetNames[static_cast<int>(kind)];
}
Result<BundleKind> ParseBundleKind(const std::string& name) {
  return ParseName<BundleKind>(name, kKindNames, "bundle kind");
}
Result<LaserState> ParseLaserState(const std::string& name) {
  return ParseName<LaserState>(name, kLaserNames, "laser state");
}
Result<TargetKind> ParseTargetKind(const std::string& name) {
  return ParseName<TargetKind>(name, kTargetNames, "target kind");
}

int Bundle::FindFrame(int step, LaserState laser, int pose) const {
  for (std::size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].step == step && frames[i].laser == laser && frames[i].pose == pose)
      return static_cast<int>(i);
  }
  return -1;
}

int Bundle::StepCount() const {
  int n = 0;
  for (const FrameRecord& f : frames) n = std::max(n, f.step + 1);
  return n;
}

std::string FrameFileName(int step, LaserState laser, int pose) {
  ROTOSCAN_CHECK(step >= 0);
  char buffer[64];
  if (pose >= 0) {
    std::snprintf(buffer, sizeof(buffer), "frames/p%02d_s%04d_%s.png", pose, step, LaserStateName(laser));
  } else {
    std::snprintf(buffer, sizeof(buffer), "frames/s%04d_%s.png", step, LaserStateName(laser));
  }
  return buffer;
}

std::string BundleJson(const BundleHeader& header, const std::vector<FrameRecord>& frames) {
  const CameraInfo& c = header.camera;
  json camera = {{"name", c.name},
                 {"width", c.model.width},
                 {"height", c.model.height},
                 {"channels", c.channels},
                 {"bit_depth", c.bit_depth},
                 {"bayer", c.bayer},
                 {"pixel_size_um", c.pixel_size_um},
                 {"K", {c.model.fx, 0.0, c.model.cx, 0.0, c.model.fy, c.model.cy, 0.0, 0.0, 1.0}},
                 {"distortion", c.model.distortion},
                 {"laser_exposure_us", c.laser_exposure_us},
                 {"natural_exposure_us", c.natural_exposure_us},
                 {"gain_db", c.gain_db}};
  json root = {{"format", "rotoscan-bundle"},
               {"format_version", header.format_version},
               {"kind", BundleKindName(header.kind)},
               {"created_by", header.created_by},
               {"camera", camera},
               {"table_step_deg", geometry::RadToDeg(header.table_step_rad)},
               {"placement", header.placement},
               {"device",
                {{"name", header.device.name},
                 {"serial", header.device.serial},
                 {"firmware_version", header.device.firmware_version}}}};
  if (header.shared_off_frame) root["shared_off_frame"] = true;
  if (header.kind == BundleKind::kCalibration) {
    root["target"] = {{"kind", TargetKindName(header.target.kind)},
                      {"cols", header.target.cols},
                      {"rows", header.target.rows},
                      {"square_mm", header.target.square_mm},
                      {"description", header.target.description}};
    if (std::isfinite(header.target.origin_height_mm))
      root["target"]["origin_height_mm"] = header.target.origin_height_mm;
  }
  json list = json::array();
  for (const FrameRecord& f : frames) list.push_back(FrameJson(f));
  root["frames"] = std::move(list);
  return root.dump(1) + "\n";
}

Result<Bundle> ParseBundleJson(const std::string& json_text, const std::string& source_name) {
  json root;
  try {
    root = json::parse(json_text);
  } catch (const json::exception& e) {
    return CorruptDataError(source_name + ": not valid JSON: " + e.what());
  }
  Bundle bundle;
  BundleHeader& h = bundle.header;
  auto fail = [&](const Status& s) { return s.WithContext(source_name); };
  const Fields top(root, "");
  if (Status s = top.Require(); !s.ok()) return fail(s);
  std::string format;
  if (Status s = top.String("format", &format); !s.ok()) return fail(s);
  if (format != "rotoscan-bundle")
    return fail(CorruptDataError("field 'format' must be \"rotoscan-bundle\""));
  if (Status s = top.Int("format_version", 1, 1000, &h.format_version); !s.ok()) return fail(s);
  if (h.format_version > kMaxFormatVersion) {
    return fail(CorruptDataError("field 'format_version' = " + std::to_string(h.format_version) +
                                 " is not supported (this build reads 1.." + std::to_string(kMaxFormatVersion) +
                                 ")"));
  }
  std::string kind;
  if (Status s = top.String("kind", &kind); !s.ok()) return fail(s);
  auto parsed_kind = ParseBundleKind(kind);
  if (!parsed_kind.ok()) return fail(CorruptDataError("field 'kind': " + parsed_kind.status().message()));
  h.kind = *parsed_kind;
  if (Status s = top.String("created_by", &h.created_by, false); !s.ok()) return fail(s);
  double step_deg = 0.0;
  if (Status s = top.Number("table_step_deg", &step_deg); !s.ok()) return fail(s);
  if (step_deg < 0.0 || step_deg > 360.0)
    return fail(CorruptDataError("field 'table_step_deg' must be in [0, 360]"));
  h.table_step_rad = geometry::DegToRad(step_deg);
  if (Status s = top.Int("placement", 0, 255, &h.placement, false); !s.ok()) return fail(s);
  if (Status s = top.Bool("shared_off_frame", &h.shared_off_frame); !s.ok()) return fail(s);
  if (h.shared_off_frame && h.format_version < 2) {
    return fail(CorruptDataError("field 'shared_off_frame' needs format_version 2"));
  }

  // camera
  if (!root.contains("camera")) return fail(CorruptDataError("missing field 'camera'"));
  const Fields cam(root["camera"], "camera");
  CameraInfo& c = h.camera;
  if (Status s = cam.Require(); !s.ok()) return fail(s);
  double k[9], dist[5];
  Status st = cam.String("name", &c.name, false);
  if (st.ok()) st = cam.Int("width", 1, kMaxImageSide, &c.model.width);
  if (st.ok()) st = cam.Int("height", 1, kMaxImageSide, &c.model.height);
  if (st.ok()) st = cam.Int("channels", 1, 3, &c.channels);
  if (st.ok()) st = cam.Int("bit_depth", 1, 16, &c.bit_depth);
  if (st.ok()) st = cam.Bool("bayer", &c.bayer);
  if (st.ok()) st = cam.Number("pixel_size_um", &c.pixel_size_um, false);
  if (st.ok()) st = cam.Array("K", 9, k);
  if (st.ok()) st = cam.Array("distortion", 5, dist);
  if (st.ok()) st = cam.Number("laser_exposure_us", &c.laser_exposure_us, false);
  if (st.ok()) st = cam.Number("natural_exposure_us", &c.natural_exposure_us, false);
  if (st.ok()) st = cam.Number("gain_db", &c.gain_db, false);
  if (!st.ok()) return fail(st);
  if (c.channels == 2) return fail(CorruptDataError("field 'camera.channels' must be 1 or 3"));
  c.model.fx = k[0];
  c.model.cx = k[2];
  c.model.fy = k[4];
  c.model.cy = k[5];
  std::copy(dist, dist + 5, c.model.distortion.begin());
  if (Status s = c.model.Validate(); !s.ok()) return fail(CorruptDataError("field 'camera': " + s.message()));
  if (c.bayer && c.channels != 1) return fail(CorruptDataError("field 'camera.bayer' requires channels = 1"));

  // device (optional)
  if (root.contains("device")) {
    const Fields dev(root["device"], "device");
    st = dev.Require();
    if (st.ok()) st = dev.String("name", &h.device.name, false);
    if (st.ok()) st = dev.String("serial", &h.device.serial, false);
    if (st.ok()) st = dev.String("firmware_version", &h.device.firmware_version, false);
    if (!st.ok()) return fail(st);
  }
  // target (calibration bundles)
  if (root.contains("target")) {
    const Fields tgt(root["target"], "target");
    std::string target_kind;
    st = tgt.Require();
    if (st.ok()) st = tgt.String("kind", &target_kind);
    if (st.ok()) st = tgt.Int("cols", 0, 1000, &h.target.cols, false);
    if (st.ok()) st = tgt.Int("rows", 0, 1000, &h.target.rows, false);
    if (st.ok()) st = tgt.Number("square_mm", &h.target.square_mm, false);
    if (st.ok()) st = tgt.String("description", &h.target.description, false);
    if (st.ok()) st = tgt.Number("origin_height_mm", &h.target.origin_height_mm, false);
    if (!st.ok()) return fail(st);
    if (!std::isnan(h.target.origin_height_mm) &&
        !(std::abs(h.target.origin_height_mm) <= 10000.0)) {
      return fail(CorruptDataError("field 'target.origin_height_mm' must be a height in mm (|h| <= 10 m)"));
    }
    auto tk = ParseTargetKind(target_kind);
    if (!tk.ok()) return fail(CorruptDataError("field 'target.kind': " + tk.status().message()));
    h.target.kind = *tk;
    if (h.target.square_mm < 0.0) return fail(CorruptDataError("field 'target.square_mm' must be >= 0"));
  }

  // frames
  if (!root.contains("frames") || !root["frames"].is_array()) {
    return fail(CorruptDataError("field 'frames' must be an array"));
  }
  const json& list = root["frames"];
  if (list.size() > kMaxFrames) {
    return fail(CorruptDataError("field 'frames' has " + std::to_string(list.size()) + " entries (limit " +
                                 std::to_string(kMaxFrames) + ")"));
  }
  bundle.frames.reserve(list.size());
  std::set<std::string> files;
  std::set<std::tuple<int, int, int>> keys;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string name = "frames[" + std::to_string(i) + "]";
    const Fields f(list[i], name);
    FrameRecord r;
    std::string laser;
    double angle_deg = 0.0;
    int64_t seq = 0, time_us = 0;
    st = f.Require();
    if (st.ok()) st = f.String("file", &r.file);
    if (st.ok()) st = CheckRelativeFile(r.file, name + ".file");
    if (st.ok()) st = f.Int("step", 0, 100'000'000, &r.step);
    if (st.ok()) st = f.Number("table_angle_deg", &angle_deg);
    if (st.ok()) st = f.String("laser", &laser);
    if (st.ok()) st = f.Integer("trigger_seq", 0, UINT32_MAX, &seq, false);
    if (st.ok()) st = f.Integer("device_time_us", 0, INT64_MAX, &time_us, false);
    if (st.ok()) st = f.Number("exposure_us", &r.exposure_us, false);
    if (st.ok()) st = f.Int("pose", -1, 100'000, &r.pose, false);
    if (!st.ok()) return fail(st);
    auto state = ParseLaserState(laser);
    if (!state.ok()) return fail(CorruptDataError("field '" + name + ".laser': " + state.status().message()));
    r.laser = *state;
    // A thousand turns is more than any scan: beyond, the value is corrupt (and loses all precision).
    if (std::abs(angle_deg) > 360.0 * 1000) {
      return fail(CorruptDataError("field '" + name + ".table_angle_deg' is " + std::to_string(angle_deg) +
                                   ": must be within +-360000"));
    }
    // Poses belong to calibration bundles; a scan's reader would drop such a frame without a word.
    if (r.pose >= 0 && h.kind == BundleKind::kScan) {
      return fail(CorruptDataError("field '" + name + ".pose': a scan bundle has no poses"));
    }
    r.table_angle_rad = geometry::DegToRad(angle_deg);
    r.trigger_seq = static_cast<uint32_t>(seq);
    r.device_time_us = static_cast<uint64_t>(time_us);
    if (!files.insert(r.file).second)
      return fail(CorruptDataError("field '" + name + ".file' repeats " + r.file));
    if (!keys.insert({r.pose, r.step, static_cast<int>(r.laser)}).second) {
      return fail(CorruptDataError(name + " repeats pose " + std::to_string(r.pose) + ", step " +
                                   std::to_string(r.step) + ", laser " + laser));
    }
    bundle.frames.push_back(std::move(r));
  }
  return bundle;
}

Result<Bundle> ReadBundle(const fs::path& directory, const ReadOptions& options) {
  std::error_code ec;
  if (!fs::is_directory(directory, ec))
    return NotFoundError("bundle directory " + directory.string() + " not found");
  const fs::path json_path = directory / "bundle.json";
  auto text = ReadFile(json_path, kMaxJsonBytes);
  if (!text.ok()) return text.status();
  ROTOSCAN_ASSIGN_OR_RETURN(Bundle bundle, ParseBundleJson(*text, json_path.string()));
  bundle.directory = directory;
  bundle.has_truth = fs::is_directory(directory / "truth", ec);
  if (options.verify_frames) {
    for (const FrameRecord& f : bundle.frames) {
      if (!fs::is_regular_file(directory / f.file, ec)) {
        return NotFoundError(json_path.string() + ": frame file " + f.file + " is missing");
      }
    }
  }
  return bundle;
}

Result<cv::Mat> ReadFrame(const Bundle& bundle, const FrameRecord& frame) {
  const fs::path path = bundle.FramePath(frame);
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return NotFoundError("frame " + path.string() + " not found");
  Result<cv::Mat> decoded = geometry::ReadImageFile(path);
  if (!decoded.ok()) return CorruptDataError("frame " + decoded.status().message());
  cv::Mat image = std::move(*decoded);
  Status s = ValidateImage(bundle.header.camera, image, "frame " + path.string());
  if (!s.ok()) return CorruptDataError(s.message());
  return image;
}

Result<cv::Mat> ReadFrame(const Bundle& bundle, std::size_t index) {
  ROTOSCAN_CHECK(index < bundle.frames.size());
  return ReadFrame(bundle, bundle.frames[index]);
}

// ---------------------------------------------------------------------------------------------------------

// The partial directory holds, besides frames/ and truth/: header.json (the header the bundle was started
// with: a resume must not mix settings), journal.jsonl (one frame record per line, appended after the
// frame's PNG is safely on disk, so a record never names a missing or torn image; a torn last line from a
// crash is ignored), and .lock (flock: two processes never write the same bundle; the lock dies with its
// process, so a crashed writer does not block the resume).
namespace {

constexpr const char* kHeaderFile = "header.json";
constexpr const char* kJournalFile = "journal.jsonl";
constexpr const char* kLockFile = ".lock";
constexpr const char* kRunHashFile = "run-hash";
constexpr const char* kOverwriteFile = "overwrite";  // started with overwrite: Finish() replaces the old bundle

// Stray temporary files (a writer killed before its rename): never trusted, removed.
void RemoveStrayTemporaries(const fs::path& working) {
  std::error_code ec;
  std::vector<fs::path> stray;
  for (auto it = fs::recursive_directory_iterator(working, ec); !ec && it != fs::recursive_directory_iterator();
       it.increment(ec)) {
    if (it->path().filename().string().find(".tmp-") != std::string::npos) stray.push_back(it->path());
  }
  for (const fs::path& p : stray) {
    ROTOSCAN_LOG(kInfo) << "removing " << p.string() << " (left by an interrupted write)";
    fs::remove_all(p, ec);
  }
}

// True when the frame on disk decodes to an image (a 0-byte or torn file is rendered again).
bool FrameDecodes(const fs::path& path) {
  return geometry::ReadImageFile(path).ok();
}

// Locks `directory`/.lock; returns the descriptor, or an error when another process holds it.
Result<int> LockDirectory(const fs::path& directory, const fs::path& final_dir) {
  const fs::path lock_path = directory / kLockFile;
  const int fd = ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) return IoError("cannot open " + lock_path.string() + ": " + std::strerror(errno));
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    ::close(fd);
    return FailedPreconditionError("another process is writing " + final_dir.string() + " (" +
                                   directory.string() + " is locked)");
  }
  return fd;
}

// The frame records of an interrupted bundle whose files are on disk, validated by the bundle parser.
Result<std::vector<FrameRecord>> ReadJournal(const fs::path& working, const std::string& header_text) {
  std::vector<FrameRecord> frames;
  const fs::path journal_path = working / kJournalFile;
  std::error_code ec;
  if (!fs::exists(journal_path, ec)) return frames;
  ROTOSCAN_ASSIGN_OR_RETURN(std::string text, ReadFile(journal_path, kMaxJsonBytes));
  json root;
  try {
    root = json::parse(header_text);
  } catch (const json::exception& e) {
    return CorruptDataError((working / kHeaderFile).string() + ": not valid JSON: " + e.what());
  }
  json list = json::array();
  std::size_t begin = 0;
  while (begin < text.size()) {
    std::size_t end = text.find('\n', begin);
    if (end == std::string::npos) break;  // a torn last line: that frame is written again
    try {
      list.push_back(json::parse(text.substr(begin, end - begin)));
    } catch (const json::exception& e) {
      return CorruptDataError(journal_path.string() + ": line " + std::to_string(list.size() + 1) +
                              " is not valid JSON: " + e.what());
    }
    begin = end + 1;
  }
  root["frames"] = std::move(list);
  ROTOSCAN_ASSIGN_OR_RETURN(Bundle parsed, ParseBundleJson(root.dump(), journal_path.string()));
  for (FrameRecord& f : parsed.frames) {
    if (!fs::is_regular_file(working / f.file, ec)) continue;  // recorded, then lost: write it again
    if (!FrameDecodes(working / f.file)) {
      ROTOSCAN_LOG(kInfo) << (working / f.file).string() << " does not decode: it is rendered again";
      continue;
    }
    // A frame written twice (replaced on an earlier resume) keeps its last record.
    frames.erase(std::remove_if(frames.begin(), frames.end(),
                                [&](const FrameRecord& g) { return g.file == f.file; }),
                 frames.end());
    frames.push_back(std::move(f));
  }
  return frames;
}

}  // namespace

BundleWriter::BundleWriter(fs::path final_dir, fs::path working, BundleHeader header, Options options)
    : final_(std::move(final_dir)),
      working_(std::move(working)),
      header_(std::move(header)),
      options_(options) {}

Result<std::unique_ptr<BundleWriter>> BundleWriter::Create(const fs::path& directory,
                                                           const BundleHeader& header,
                                                           const Options& options,
                                                           const std::string& run_hash_now) {
  ROTOSCAN_RETURN_IF_ERROR(ValidateHeader(header));
  std::error_code ec;
  fs::path final_dir = directory;
  if (final_dir.filename().empty()) final_dir = final_dir.parent_path();  // "out/" -> "out"
  const fs::path working = PartialDirectory(final_dir);
  // An interrupted overwrite is resumed as one: it replaces the old bundle when it finishes.
  Options effective = options;
  if (options.resume && fs::exists(working / kOverwriteFile, ec)) effective.overwrite = true;
  if (fs::exists(final_dir, ec) && !effective.overwrite) {
    return FailedPreconditionError(final_dir.string() + " exists already (overwrite it explicitly)");
  }
  const std::string header_text = BundleJson(header, {});
  std::unique_ptr<BundleWriter> writer(new BundleWriter(final_dir, working, header, effective));
  if (fs::is_directory(working, ec)) {
    ROTOSCAN_ASSIGN_OR_RETURN(writer->lock_fd_, LockDirectory(working, final_dir));
    if (options.resume) {
      auto started_with = ReadFile(working / kHeaderFile, kMaxJsonBytes);
      if (!started_with.ok() || *started_with != header_text) {
        return FailedPreconditionError("the interrupted bundle in " + working.string() +
                                       " was started with other settings: it cannot be resumed with these "
                                       "(start again with overwrite, or use the same settings)");
      }
      auto run_hash = ReadFile(working / kRunHashFile, kMaxJsonBytes);
      if (!run_hash.ok() || *run_hash != run_hash_now) {
        return FailedPreconditionError("the interrupted bundle in " + working.string() +
                                       " was started with another scene or other options (run hash " +
                                       (run_hash.ok() ? *run_hash : std::string("missing")) + ", now " +
                                       run_hash_now + "): it cannot be resumed with these");
      }
      RemoveStrayTemporaries(working);
      ROTOSCAN_ASSIGN_OR_RETURN(writer->frames_, ReadJournal(working, header_text));
      // The journal is rewritten with the records kept, so that a torn last line is not continued.
      std::string journal;
      for (const FrameRecord& f : writer->frames_) {
        writer->resumed_.insert(f.file);
        journal += FrameJson(f).dump() + "\n";
      }
      ROTOSCAN_RETURN_IF_ERROR(WriteFileAtomically(working / kJournalFile, journal));
    } else if (options.overwrite) {
      for (const fs::directory_entry& entry : fs::directory_iterator(working, ec)) {
        if (entry.path().filename() != kLockFile) fs::remove_all(entry.path(), ec);
      }
      writer->started_ = true;
    } else {
      return FailedPreconditionError("an interrupted bundle is in " + working.string() +
                                     ": resume it (--resume), or start again (--overwrite)");
    }
  } else {
    fs::create_directories(working, ec);
    if (ec) return IoError("cannot create " + working.string() + ": " + ec.message());
    ROTOSCAN_ASSIGN_OR_RETURN(writer->lock_fd_, LockDirectory(working, final_dir));
    writer->started_ = true;
  }
  fs::create_directories(working / "frames", ec);
  if (!ec) fs::create_directories(working / "truth", ec);
  if (ec) return IoError("cannot create " + working.string() + ": " + ec.message());
  ROTOSCAN_RETURN_IF_ERROR(WriteFileAtomically(working / kHeaderFile, header_text));
  if (writer->started_) {
    ROTOSCAN_RETURN_IF_ERROR(WriteFileAtomically(working / kRunHashFile, run_hash_now));
    if (options.overwrite) ROTOSCAN_RETURN_IF_ERROR(WriteFileAtomically(working / kOverwriteFile, ""));
  }
  const fs::path journal_path = working / kJournalFile;
  writer->journal_ = std::fopen(journal_path.c_str(), "ae");
  if (writer->journal_ == nullptr) {
    return IoError("cannot open " + journal_path.string() + ": " + std::strerror(errno));
  }
  return writer;
}

fs::path BundleWriter::PartialDirectory(const fs::path& directory) {
  fs::path final_dir = directory;
  if (final_dir.filename().empty()) final_dir = final_dir.parent_path();
  return final_dir.string() + ".partial";
}

bool BundleWriter::HasFrame(const std::string& file) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return resumed_.count(file) > 0;
}

std::size_t BundleWriter::resumed_frame_count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return resumed_.size();
}

std::size_t BundleWriter::frame_count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return frames_.size();
}

void BundleWriter::Discard() {
  ROTOSCAN_CHECK(!finished_);
  std::lock_guard<std::mutex> lock(mutex_);
  frames_.clear();
  resumed_.clear();
  started_ = true;  // the destructor removes the partial directory
}

BundleWriter::~BundleWriter() {
  if (journal_ != nullptr) std::fclose(journal_);
  std::error_code ec;
  if (!finished_ && lock_fd_ >= 0) {
    // Frames on disk make it resumable: keep it. Started here and nothing written: nothing to keep.
    if (frames_.empty() && started_) {
      fs::remove_all(working_, ec);
    } else if (!frames_.empty()) {
      ROTOSCAN_LOG(kInfo) << "the unfinished bundle stays in " << working_.string() << " (" << frames_.size()
                << " frames): it can be resumed";
    }
  }
  if (lock_fd_ >= 0) ::close(lock_fd_);
}

Status BundleWriter::AddFrame(FrameRecord record, const cv::Mat& image) {
  ROTOSCAN_CHECK(!finished_);
  if (record.file.empty()) record.file = FrameFileName(record.step, record.laser, record.pose);
  ROTOSCAN_RETURN_IF_ERROR(CheckRelativeFile(record.file, "file"));
  if (record.step < 0) return InvalidArgumentError("frame step must be >= 0");
  ROTOSCAN_RETURN_IF_ERROR(ValidateImage(header_.camera, image, record.file));
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (resumed_.erase(record.file) > 0) {
      // Written before an interruption and written again now: the new one replaces it.
      frames_.erase(std::remove_if(frames_.begin(), frames_.end(),
                                   [&](const FrameRecord& f) { return f.file == record.file; }),
                    frames_.end());
    }
    for (const FrameRecord& f : frames_) {
      if (f.file == record.file) return InvalidArgumentError("frame " + record.file + " added twice");
    }
    frames_.push_back(record);  // reserve the name
  }
  const fs::path path = working_ / record.file;
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  std::vector<uchar> png;
  bool encoded = false;
  try {
    encoded = cv::imencode(".png", image, png, {cv::IMWRITE_PNG_COMPRESSION, 1});
  } catch (const cv::Exception& e) {
    encoded = false;
  }
  Status s = encoded ? WriteFileAtomically(path, std::string(png.begin(), png.end()))
                     : IoError("cannot encode " + record.file + " as PNG");
  if (s.ok()) {
    // The record goes to the journal only once its image is complete on disk.
    std::lock_guard<std::mutex> lock(mutex_);
    const std::string line = FrameJson(record).dump() + "\n";
    if (std::fwrite(line.data(), 1, line.size(), journal_) != line.size() || std::fflush(journal_) != 0) {
      s = IoError("cannot append to " + (working_ / kJournalFile).string() + ": " + std::strerror(errno));
    }
  }
  if (!s.ok()) {
    std::lock_guard<std::mutex> lock(mutex_);
    frames_.erase(std::remove_if(frames_.begin(), frames_.end(),
                                 [&](const FrameRecord& f) { return f.file == record.file; }),
                  frames_.end());
  }
  return s;
}

Status BundleWriter::Finish() {
  ROTOSCAN_CHECK(!finished_);
  std::vector<FrameRecord> frames;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    frames = frames_;
  }
  std::sort(frames.begin(), frames.end(), [](const FrameRecord& a, const FrameRecord& b) {
    return std::make_tuple(a.pose, a.step, LaserOrder(a.laser), a.file) <
           std::make_tuple(b.pose, b.step, LaserOrder(b.laser), b.file);
  });
  ROTOSCAN_RETURN_IF_ERROR(WriteFileAtomically(working_ / "bundle.json", BundleJson(header_, frames)));
  std::error_code ec;
  // An empty truth/ means no truth: remove it so that readers see has_truth = false.
  if (fs::is_directory(working_ / "truth", ec) && fs::is_empty(working_ / "truth", ec)) {
    fs::remove(working_ / "truth", ec);
  }
  if (fs::exists(final_, ec)) {
    if (!options_.overwrite) return FailedPreconditionError(final_.string() + " appeared while writing");
  }
  // The bookkeeping of the partial directory is not part of the bundle. The lock is held until the
  // rename (the descriptor stays open; only the name goes).
  std::fclose(journal_);
  journal_ = nullptr;
  fs::remove(working_ / kJournalFile, ec);
  fs::remove(working_ / kHeaderFile, ec);
  fs::remove(working_ / kLockFile, ec);
  fs::remove(working_ / kRunHashFile, ec);
  fs::remove(working_ / kOverwriteFile, ec);
  Status s = WriteAtomically(final_, [&](const fs::path& temporary) -> Status {
    std::error_code rename_error;
    fs::rename(working_, temporary, rename_error);
    if (rename_error) {
      return IoError("cannot rename " + working_.string() + ": " + rename_error.message());
    }
    return Status::Ok();
  });
  if (s.ok()) finished_ = true;
  return s;
}

}  // namespace rotoscan::bundle
