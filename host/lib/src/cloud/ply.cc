// PLY writer and hardened reader (see cloud/cloud.h). Values are encoded and decoded byte by byte in
// little endian, never by casting structs, so the file is the same on any host.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"

namespace rotoscan::cloud {
namespace {

constexpr double kPi = 3.14159265358979323846;

void PutU32(std::string* out, uint32_t v) {
  for (int i = 0; i < 4; ++i) out->push_back(static_cast<char>((v >> (8 * i)) & 0xFF));
}
void PutFloat(std::string* out, float f) {
  uint32_t bits;
  std::memcpy(&bits, &f, 4);
  PutU32(out, bits);
}

enum class Type { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

bool ParseType(const std::string& name, Type* type, int* bytes) {
  struct Entry {
    const char* name;
    Type type;
    int bytes;
  };
  static const Entry kTypes[] = {
      {"char", Type::kInt8, 1},      {"int8", Type::kInt8, 1},       {"uchar", Type::kUint8, 1},
      {"uint8", Type::kUint8, 1},    {"short", Type::kInt16, 2},     {"int16", Type::kInt16, 2},
      {"ushort", Type::kUint16, 2},  {"uint16", Type::kUint16, 2},   {"int", Type::kInt32, 4},
      {"int32", Type::kInt32, 4},    {"uint", Type::kUint32, 4},     {"uint32", Type::kUint32, 4},
      {"float", Type::kFloat32, 4},  {"float32", Type::kFloat32, 4}, {"double", Type::kFloat64, 8},
      {"float64", Type::kFloat64, 8}};
  for (const Entry& e : kTypes) {
    if (name == e.name) {
      *type = e.type;
      *bytes = e.bytes;
      return true;
    }
  }
  return false;
}

double DecodeBinary(const unsigned char* p, Type type) {
  uint64_t v = 0;
  auto load = [&](int n) {
    v = 0;
    for (int i = 0; i < n; ++i) v |= uint64_t{p[i]} << (8 * i);
  };
  switch (type) {
    case Type::kInt8: return static_cast<int8_t>(p[0]);
    case Type::kUint8: return p[0];
    case Type::kInt16: load(2); return static_cast<int16_t>(static_cast<uint16_t>(v));
    case Type::kUint16: load(2); return static_cast<uint16_t>(v);
    case Type::kInt32: load(4); return static_cast<int32_t>(static_cast<uint32_t>(v));
    case Type::kUint32: load(4); return static_cast<uint32_t>(v);
    case Type::kFloat32: {
      load(4);
      const uint32_t bits = static_cast<uint32_t>(v);
      float f;
      std::memcpy(&f, &bits, 4);
      return f;
    }
    case Type::kFloat64: {
      load(8);
      double d;
      std::memcpy(&d, &v, 8);
      return d;
    }
  }
  return 0;
}

// A decoded value as an integer field: non-finite values (a corrupt file) become 0 instead of undefined
// behaviour in the conversion.
double Finite(double v, double lo, double hi) {
  return std::isfinite(v) ? std::clamp(v, lo, hi) : 0.0;
}

struct Property {
  std::string name;
  Type type = Type::kFloat32;
  int bytes = 4;
  bool is_list = false;
};
struct Element {
  std::string name;
  uint64_t count = 0;
  std::vector<Property> properties;
};

}  // namespace

std::string EncodePly(const PointCloud& cloud) {
  std::string out;
  out.reserve(400 + cloud.size() * 36);
  out += "ply\nformat binary_little_endian 1.0\ncomment rotoscan cloud: x y z in mm, table frame\n";
  if (cloud.scan.known) {
    std::ostringstream scan;
    scan.precision(17);
    scan << "comment rotoscan camera_at_step0 " << cloud.scan.camera_at_step0.x() << " "
         << cloud.scan.camera_at_step0.y() << " " << cloud.scan.camera_at_step0.z() << "\n"
         << "comment rotoscan step_deg " << cloud.scan.step_rad * 180.0 / kPi << "\n";
    for (size_t k = 0; k < cloud.scan.placements.size() && k < 256; ++k) {
      const ScanGeometry::Placement& p = cloud.scan.placements[k];
      scan << "comment rotoscan placement " << k << " camera_at_step0 " << p.camera_at_step0.x() << " "
           << p.camera_at_step0.y() << " " << p.camera_at_step0.z() << " step_deg "
           << p.step_rad * 180.0 / kPi << " merged_from_table";
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c) scan << " " << p.merged_from_table.matrix()(r, c);
      scan << "\n";
    }
    out += scan.str();
  }
  out +=
      "element vertex " +
      std::to_string(cloud.size()) +
      "\nproperty float x\nproperty float y\nproperty float z\n"
      "property float nx\nproperty float ny\nproperty float nz\n"
      "property uchar red\nproperty uchar green\nproperty uchar blue\n"
      "property uchar laser\nproperty int step\nproperty float quality\n";
  // The placement (pipeline/placements.h) only in clouds that hold more than the first one.
  const bool placements = std::any_of(cloud.points.begin(), cloud.points.end(),
                                      [](const CloudPoint& p) { return p.placement != 0; });
  if (placements) out += "property uchar placement\n";
  out += "end_header\n";
  for (const CloudPoint& p : cloud.points) {
    for (int i = 0; i < 3; ++i) PutFloat(&out, p.position_in_table[i]);
    for (int i = 0; i < 3; ++i) PutFloat(&out, p.normal[i]);
    for (int i = 0; i < 3; ++i) out.push_back(static_cast<char>(p.color[static_cast<size_t>(i)]));
    out.push_back(static_cast<char>(p.laser));
    PutU32(&out, static_cast<uint32_t>(p.step));
    PutFloat(&out, p.quality);
    if (placements) out.push_back(static_cast<char>(p.placement));
  }
  return out;
}

Status WritePly(const std::filesystem::path& path, const PointCloud& cloud) {
  // Never write what ReadPly rejects.
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.points[i].position_in_table.allFinite()) {
      return InvalidArgumentError("refusing to write " + path.string() + ": point " + std::to_string(i) +
                                  " is not finite");
    }
  }
  return WriteFileAtomically(path, EncodePly(cloud)).WithContext("writing " + path.string());
}

Result<PointCloud> ReadPly(const std::filesystem::path& path, const PlyReadOptions& options) {
  auto bytes = ReadFile(path, options.max_file_bytes);
  if (!bytes.ok()) return bytes.status().WithContext("reading " + path.string());
  return DecodePly(*bytes, path.string(), options);
}

Result<PointCloud> DecodePly(const std::string& bytes, const std::string& name,
                             const PlyReadOptions& options) {
  auto corrupt = [&](const std::string& why) { return CorruptDataError(name + ": " + why); };
  // Header: text lines up to "end_header\n", bounded.
  // "end_header" as a whole line: a comment may contain the word.
  size_t header_end = std::string::npos;
  for (size_t at = bytes.find("\nend_header"); at != std::string::npos && at < (1 << 20);
       at = bytes.find("\nend_header", at + 1)) {
    const size_t after = at + 11;
    if (after == bytes.size() || bytes[after] == '\n' || bytes[after] == '\r' || bytes[after] == ' ') {
      header_end = at + 1;
      break;
    }
  }
  if (bytes.compare(0, 4, "ply\n") != 0 && bytes.compare(0, 5, "ply\r\n") != 0) {
    return corrupt("not a PLY file (no 'ply' magic)");
  }
  if (header_end == std::string::npos || header_end > (1 << 20)) return corrupt("no end_header");
  size_t data_start = bytes.find('\n', header_end);
  if (data_start == std::string::npos) return corrupt("header not terminated");
  ++data_start;
  std::istringstream header(bytes.substr(0, header_end));
  std::string line;
  bool binary = false, have_format = false;
  std::vector<Element> elements;
  ScanGeometry scan;
  bool have_camera = false, have_step = false, placements_broken = false;
  std::vector<ScanGeometry::Placement> placements;
  while (std::getline(header, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    if (keyword == "comment") {
      std::string tag, key;
      words >> tag >> key;
      if (tag == "rotoscan" && key == "camera_at_step0") {
        Eigen::Vector3d c;
        have_camera = static_cast<bool>(words >> c.x() >> c.y() >> c.z()) && c.allFinite() && c.cwiseAbs().maxCoeff() < 1e9;
        if (have_camera) scan.camera_at_step0 = c;
      } else if (tag == "rotoscan" && key == "placement") {
        // One placement's camera path (header comment above); anything malformed drops every path.
        size_t index = 0;
        std::string k1, k2, k3;
        ScanGeometry::Placement p;
        double deg = 0;
        Eigen::Matrix<double, 3, 4> m;
        bool ok = static_cast<bool>(words >> index >> k1 >> p.camera_at_step0.x() >> p.camera_at_step0.y() >>
                                    p.camera_at_step0.z() >> k2 >> deg >> k3);
        for (int r = 0; ok && r < 3; ++r)
          for (int c = 0; ok && c < 4; ++c) ok = static_cast<bool>(words >> m(r, c));
        ok = ok && k1 == "camera_at_step0" && k2 == "step_deg" && k3 == "merged_from_table" && index < 256 &&
             index == placements.size() && p.camera_at_step0.allFinite() &&
             p.camera_at_step0.cwiseAbs().maxCoeff() < 1e9 && std::isfinite(deg) && std::abs(deg) <= 360.0 &&
             m.allFinite() && m.rightCols<1>().cwiseAbs().maxCoeff() < 1e9 &&
             (m.leftCols<3>() * m.leftCols<3>().transpose() - Eigen::Matrix3d::Identity())
                     .cwiseAbs()
                     .maxCoeff() < 1e-6 &&
             m.leftCols<3>().determinant() > 0;
        if (ok) {
          p.step_rad = deg * kPi / 180.0;
          p.merged_from_table.linear() = m.leftCols<3>();
          p.merged_from_table.translation() = m.rightCols<1>();
          placements.push_back(p);
        } else {
          placements_broken = true;
        }
      } else if (tag == "rotoscan" && key == "step_deg") {
        double deg = 0;
        have_step = static_cast<bool>(words >> deg) && std::isfinite(deg) && std::abs(deg) <= 360.0;
        if (have_step) scan.step_rad = deg * kPi / 180.0;
      }
    } else if (keyword == "format") {
      std::string format, version;
      words >> format >> version;
      if (format == "binary_little_endian") {
        binary = true;
      } else if (format != "ascii") {
        return corrupt("unsupported format '" + format + "' (binary_little_endian and ascii are read)");
      }
      have_format = true;
    } else if (keyword == "element") {
      Element e;
      std::string count;
      words >> e.name >> count;
      if (count.empty() || count.find_first_not_of("0123456789") != std::string::npos || count.size() > 19) {
        return corrupt("bad count in '" + line + "'");
      }
      e.count = std::stoull(count);
      elements.push_back(e);
    } else if (keyword == "property") {
      if (elements.empty()) return corrupt("property before any element");
      Property p;
      std::string type;
      words >> type;
      if (type == "list") {
        std::string count_type, item_type;
        words >> count_type >> item_type >> p.name;
        p.is_list = true;
      } else {
        if (!ParseType(type, &p.type, &p.bytes)) return corrupt("unknown property type '" + type + "'");
        words >> p.name;
      }
      elements.back().properties.push_back(p);
    }
  }
  if (!have_format) return corrupt("no format line");
  // Find the vertex element; everything before it must be skippable.
  size_t offset = data_start;
  const Element* vertex = nullptr;
  std::istringstream ascii(binary ? std::string() : bytes.substr(data_start));
  for (const Element& e : elements) {
    if (e.name == "vertex") {
      vertex = &e;
      break;
    }
    for (const Property& p : e.properties) {
      if (p.is_list) return corrupt("list property in element '" + e.name + "' before the vertices");
    }
    if (binary) {
      uint64_t stride = 0;
      for (const Property& p : e.properties) stride += static_cast<uint64_t>(p.bytes);
      if (stride != 0 && e.count > (bytes.size() - offset) / stride)
        return corrupt("truncated element " + e.name);
      offset += static_cast<size_t>(e.count * stride);
    } else {
      for (uint64_t i = 0; i < e.count; ++i) {
        if (!std::getline(ascii, line)) return corrupt("truncated element " + e.name);
      }
    }
  }
  if (vertex == nullptr) return corrupt("no vertex element");
  int index[13];
  const char* names[13] = {"x",   "y",     "z",    "nx",    "ny",   "nz",     "red",
                           "green", "blue", "laser", "step", "quality", "placement"};
  for (int k = 0; k < 13; ++k) index[k] = -1;
  uint64_t stride = 0;
  for (size_t i = 0; i < vertex->properties.size(); ++i) {
    const Property& p = vertex->properties[i];
    if (p.is_list) return corrupt("list property '" + p.name + "' in the vertex element is not supported");
    stride += static_cast<uint64_t>(p.bytes);
    for (int k = 0; k < 13; ++k) {
      if (p.name == names[k]) index[k] = static_cast<int>(i);
    }
  }
  if (index[0] < 0 || index[1] < 0 || index[2] < 0) return corrupt("vertex element lacks x, y or z");
  if (vertex->count > options.max_points) {
    return corrupt("claims " + std::to_string(vertex->count) + " vertices, more than the limit " +
                   std::to_string(options.max_points));
  }
  if (binary && vertex->count > (bytes.size() - offset) / stride) {
    return corrupt("truncated: " + std::to_string(vertex->count) + " vertices of " + std::to_string(stride) +
                   " bytes announced, " + std::to_string(bytes.size() - offset) + " bytes present");
  }
  if (!binary && vertex->count > bytes.size() - data_start) return corrupt("truncated vertex data");
  PointCloud cloud;
  cloud.points.resize(static_cast<size_t>(vertex->count));
  std::vector<double> values(vertex->properties.size());
  const auto* data = reinterpret_cast<const unsigned char*>(bytes.data());
  for (uint64_t v = 0; v < vertex->count; ++v) {
    if (binary) {
      size_t at = offset + static_cast<size_t>(v * stride);
      for (size_t i = 0; i < values.size(); ++i) {
        values[i] = DecodeBinary(data + at, vertex->properties[i].type);
        at += static_cast<size_t>(vertex->properties[i].bytes);
      }
    } else {
      if (!std::getline(ascii, line)) return corrupt("truncated at vertex " + std::to_string(v));
      std::istringstream words(line);
      for (double& value : values) {
        if (!(words >> value)) return corrupt("bad vertex line " + std::to_string(v));
      }
    }
    CloudPoint& p = cloud.points[static_cast<size_t>(v)];
    auto get = [&](int k, double fallback) {
      return index[k] >= 0 ? values[static_cast<size_t>(index[k])] : fallback;
    };
    for (int k = 0; k < 3; ++k) {
      const double x = get(k, 0);
      if (!std::isfinite(x) || std::abs(x) > 1e30)
        return corrupt("non-finite coordinate at vertex " + std::to_string(v));
      p.position_in_table[k] = static_cast<float>(x);
      p.normal[k] = static_cast<float>(Finite(get(3 + k, 0), -1e30, 1e30));
      p.color[static_cast<size_t>(k)] = static_cast<uint8_t>(Finite(get(6 + k, 0), 0.0, 255.0));
    }
    p.laser = static_cast<uint8_t>(Finite(get(9, 0), 0.0, 255.0));
    p.step = static_cast<int32_t>(Finite(get(10, 0), -2147483648.0, 2147483647.0));
    p.quality = static_cast<float>(Finite(get(11, 0), -1e30, 1e30));
    p.placement = static_cast<uint8_t>(Finite(get(12, 0), 0.0, 255.0));
  }
  if (have_camera && have_step && !placements_broken) {
    scan.known = true;
    scan.placements = std::move(placements);
    for (const CloudPoint& p : cloud.points) {
      // A merged cloud's path must name every placement of its points.
      if (p.placement != 0 && p.placement >= scan.placements.size()) scan.known = false;
    }
    if (!scan.known) scan.placements.clear();
    if (scan.known) cloud.scan = scan;
  }
  return cloud;
}

Eigen::Vector3d ScanGeometry::CameraAt(int placement, int step) const {
  if (placement < 0 || static_cast<size_t>(placement) >= placements.size()) return CameraAtStep(step);
  const Placement& p = placements[static_cast<size_t>(placement)];
  const double angle = p.step_rad * step;
  const double c = std::cos(angle), s = std::sin(angle);
  const Eigen::Vector3d own(c * p.camera_at_step0.x() - s * p.camera_at_step0.y(),
                            s * p.camera_at_step0.x() + c * p.camera_at_step0.y(), p.camera_at_step0.z());
  return p.merged_from_table * own;
}

Eigen::Vector3d ScanGeometry::CameraAtStep(int step) const {
  const double angle = step_rad * step;
  const double c = std::cos(angle), s = std::sin(angle);
  return {c * camera_at_step0.x() - s * camera_at_step0.y(), s * camera_at_step0.x() + c * camera_at_step0.y(),
          camera_at_step0.z()};
}

}  // namespace rotoscan::cloud
