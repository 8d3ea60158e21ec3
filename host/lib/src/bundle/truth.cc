#include "rotoscan/bundle/truth.h"

#include <cmath>
#include <cstdio>
#include <cstring>
#include <sstream>

#include "rotoscan/core/file.h"

namespace rotoscan::bundle {
namespace fs = std::filesystem;

namespace {

constexpr std::size_t kMaxPlyBytes = std::size_t{4} << 30;
constexpr std::size_t kMaxCsvBytes = std::size_t{256} << 20;
constexpr std::size_t kMaxLinePoints = 1'000'000;
constexpr std::size_t kMaxPoses = 1'000'000;

template <typename T>
void Append(std::string* out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));  // little-endian host (x86-64, aarch64)
  out->append(bytes, sizeof(T));
}

// A bounds-checked cursor over binary PLY data.
class Cursor {
 public:
  Cursor(const std::string& data, std::size_t pos) : data_(data), pos_(pos) {}
  template <typename T>
  bool Read(T* value) {
    if (data_.size() - pos_ < sizeof(T)) return false;
    std::memcpy(value, data_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return true;
  }

 private:
  const std::string& data_;
  std::size_t pos_;
};

std::string FormatDouble(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.12g", v);
  return buffer;
}

// Splits a CSV line of numbers; false when a field is not a finite number or the count differs.
bool ParseNumbers(const std::string& line, std::size_t expected, double* values) {
  std::size_t count = 0;
  const char* p = line.c_str();
  while (*p != '\0') {
    if (count == expected) return false;
    char* end = nullptr;
    const double v = std::strtod(p, &end);
    if (end == p || !std::isfinite(v)) return false;
    values[count++] = v;
    p = end;
    while (*p == ' ' || *p == '\r') ++p;
    if (*p == ',') {
      ++p;
    } else if (*p != '\0') {
      return false;
    }
  }
  return count == expected;
}

Result<std::vector<std::string>> ReadLines(const fs::path& path, const char* magic) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::string text, ReadFile(path, kMaxCsvBytes));
  std::vector<std::string> lines;
  std::istringstream in(text);
  std::string line;
  bool first = true;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (first) {
      if (line.rfind(magic, 0) != 0) {
        return CorruptDataError(path.string() + ": first line must start with '" + magic + "'");
      }
      first = false;
      continue;
    }
    if (line.empty() || line[0] == '#' || std::isalpha(static_cast<unsigned char>(line[0]))) continue;
    lines.push_back(line);
  }
  if (first) return CorruptDataError(path.string() + ": empty file");
  return lines;
}

}  // namespace

Status WritePlyMesh(const fs::path& path, const TruthMesh& mesh) {
  if (!mesh.colors.empty() && mesh.colors.size() != mesh.vertices.size()) {
    return InvalidArgumentError("mesh colors must be empty or one per vertex");
  }
  const bool colored = !mesh.colors.empty();
  std::string out = "ply\nformat binary_little_endian 1.0\ncomment rotoscan truth mesh, table frame, mm\n";
  out += "element vertex " + std::to_string(mesh.vertices.size()) + "\n";
  out += "property float x\nproperty float y\nproperty float z\n";
  if (colored) out += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  out += "element face " + std::to_string(mesh.faces.size()) + "\n";
  out += "property list uchar int vertex_indices\nend_header\n";
  out.reserve(out.size() + mesh.vertices.size() * 15 + mesh.faces.size() * 13);
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    for (int k = 0; k < 3; ++k) Append(&out, mesh.vertices[i][k]);
    if (colored) out.append(reinterpret_cast<const char*>(mesh.colors[i].data()), 3);
  }
  for (const Eigen::Vector3i& f : mesh.faces) {
    for (int k = 0; k < 3; ++k) {
      if (f[k] < 0 || static_cast<std::size_t>(f[k]) >= mesh.vertices.size()) {
        return InvalidArgumentError("mesh face index out of range");
      }
    }
    Append(&out, uint8_t{3});
    for (int k = 0; k < 3; ++k) Append(&out, int32_t{f[k]});
  }
  return WriteFileAtomically(path, out);
}

Result<TruthMesh> ReadPlyMesh(const fs::path& path) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::string data, ReadFile(path, kMaxPlyBytes));
  const std::string name = path.string();
  const std::size_t header_end = data.find("end_header\n");
  if (data.rfind("ply\n", 0) != 0 || header_end == std::string::npos || header_end > 65536) {
    return CorruptDataError(name + ": not a PLY file (no 'ply' ... 'end_header')");
  }
  std::istringstream header(data.substr(0, header_end));
  std::string line, format;
  // Vertex properties: name and type; only float/double xyz and uchar colors are supported.
  struct Property {
    std::string type, name;
  };
  std::vector<Property> vertex_props;
  std::string face_count_type, face_index_type;
  std::size_t vertex_count = 0, face_count = 0;
  int element = 0;  // 1 vertex, 2 face, 3 other
  while (std::getline(header, line)) {
    std::istringstream words(line);
    std::string word;
    words >> word;
    if (word == "format") {
      words >> format;
    } else if (word == "element") {
      std::string what;
      long long count = -1;
      words >> what >> count;
      if (count < 0) return CorruptDataError(name + ": bad element line '" + line + "'");
      if (what == "vertex") {
        if (static_cast<std::size_t>(count) > kMaxTruthMeshVertices) {
          return CorruptDataError(name + ": vertex count " + std::to_string(count) + " exceeds the limit");
        }
        vertex_count = static_cast<std::size_t>(count);
        element = 1;
      } else if (what == "face") {
        if (static_cast<std::size_t>(count) > kMaxTruthMeshFaces) {
          return CorruptDataError(name + ": face count " + std::to_string(count) + " exceeds the limit");
        }
        face_count = static_cast<std::size_t>(count);
        element = 2;
      } else {
        return CorruptDataError(name + ": unsupported element '" + what + "'");
      }
    } else if (word == "property") {
      std::string type;
      words >> type;
      if (element == 1) {
        Property p;
        p.type = type;
        words >> p.name;
        vertex_props.push_back(p);
      } else if (element == 2 && type == "list") {
        std::string prop_name;
        words >> face_count_type >> face_index_type >> prop_name;
      } else {
        return CorruptDataError(name + ": unsupported property line '" + line + "'");
      }
    }
  }
  const bool binary = format == "binary_little_endian";
  if (!binary && format != "ascii")
    return CorruptDataError(name + ": unsupported PLY format '" + format + "'");
  int xyz[3] = {-1, -1, -1}, rgb[3] = {-1, -1, -1};
  for (std::size_t i = 0; i < vertex_props.size(); ++i) {
    const Property& p = vertex_props[i];
    const char* axes[] = {"x", "y", "z"};
    const char* colors[] = {"red", "green", "blue"};
    for (int k = 0; k < 3; ++k) {
      if (p.name == axes[k]) {
        if (p.type != "float" && p.type != "float32") return CorruptDataError(name + ": x y z must be float");
        xyz[k] = static_cast<int>(i);
      }
      if (p.name == colors[k]) {
        if (p.type != "uchar" && p.type != "uint8") return CorruptDataError(name + ": colors must be uchar");
        rgb[k] = static_cast<int>(i);
      }
    }
    if (p.type != "float" && p.type != "float32" && p.type != "uchar" && p.type != "uint8") {
      return CorruptDataError(name + ": unsupported vertex property type '" + p.type + "'");
    }
  }
  if (xyz[0] < 0 || xyz[1] < 0 || xyz[2] < 0) return CorruptDataError(name + ": vertex x y z missing");
  const bool colored = rgb[0] >= 0 && rgb[1] >= 0 && rgb[2] >= 0;
  if (face_count > 0 && ((face_count_type != "uchar" && face_count_type != "uint8") ||
                         (face_index_type != "int" && face_index_type != "int32" &&
                          face_index_type != "uint" && face_index_type != "uint32"))) {
    return CorruptDataError(name + ": face list must be 'list uchar int'");
  }

  TruthMesh mesh;
  mesh.vertices.resize(vertex_count);
  if (colored) mesh.colors.resize(vertex_count);
  mesh.faces.reserve(face_count);
  const std::size_t body = header_end + std::strlen("end_header\n");
  std::vector<double> values(vertex_props.size());
  auto check_face = [&](const int32_t idx[3], std::size_t f) -> Status {
    for (int k = 0; k < 3; ++k) {
      if (idx[k] < 0 || static_cast<std::size_t>(idx[k]) >= vertex_count) {
        return CorruptDataError(name + ": face " + std::to_string(f) + " has an index out of range");
      }
    }
    return Status::Ok();
  };
  if (binary) {
    // The data size is checked before any per-element work (truncation -> kCorruptData).
    Cursor cursor(data, body);
    for (std::size_t v = 0; v < vertex_count; ++v) {
      for (std::size_t i = 0; i < vertex_props.size(); ++i) {
        bool ok;
        if (vertex_props[i].type[0] == 'f') {
          float x = 0;
          ok = cursor.Read(&x);
          values[i] = x;
        } else {
          uint8_t x = 0;
          ok = cursor.Read(&x);
          values[i] = x;
        }
        if (!ok) return CorruptDataError(name + ": truncated in vertex " + std::to_string(v));
      }
      for (int k = 0; k < 3; ++k) mesh.vertices[v][k] = static_cast<float>(values[xyz[k]]);
      if (colored) {
        for (int k = 0; k < 3; ++k) mesh.colors[v][k] = static_cast<uint8_t>(values[rgb[k]]);
      }
    }
    for (std::size_t f = 0; f < face_count; ++f) {
      uint8_t n = 0;
      int32_t idx[3];
      if (!cursor.Read(&n)) return CorruptDataError(name + ": truncated in face " + std::to_string(f));
      if (n != 3) return CorruptDataError(name + ": face " + std::to_string(f) + " is not a triangle");
      for (int k = 0; k < 3; ++k) {
        if (!cursor.Read(&idx[k])) return CorruptDataError(name + ": truncated in face " + std::to_string(f));
      }
      ROTOSCAN_RETURN_IF_ERROR(check_face(idx, f));
      mesh.faces.emplace_back(idx[0], idx[1], idx[2]);
    }
  } else {
    std::istringstream in(data.substr(body));
    for (std::size_t v = 0; v < vertex_count; ++v) {
      for (double& x : values) {
        if (!(in >> x)) return CorruptDataError(name + ": truncated in vertex " + std::to_string(v));
      }
      for (int k = 0; k < 3; ++k) mesh.vertices[v][k] = static_cast<float>(values[xyz[k]]);
      if (colored) {
        for (int k = 0; k < 3; ++k) mesh.colors[v][k] = static_cast<uint8_t>(values[rgb[k]]);
      }
    }
    for (std::size_t f = 0; f < face_count; ++f) {
      int n = 0;
      int32_t idx[3];
      if (!(in >> n >> idx[0] >> idx[1] >> idx[2]) || n != 3) {
        return CorruptDataError(name + ": bad or truncated face " + std::to_string(f));
      }
      ROTOSCAN_RETURN_IF_ERROR(check_face(idx, f));
      mesh.faces.emplace_back(idx[0], idx[1], idx[2]);
    }
  }
  for (const Eigen::Vector3f& v : mesh.vertices) {
    if (!v.allFinite()) return CorruptDataError(name + ": a vertex is not finite");
  }
  return mesh;
}

fs::path LineTruthPath(const fs::path& bundle_dir, const FrameRecord& frame) {
  return bundle_dir / "truth" / "lines" / (fs::path(frame.file).stem().string() + ".csv");
}

Status WriteLineTruth(const fs::path& path, const std::vector<LinePoint>& points) {
  std::string out = "# rotoscan line truth 1\nrow,column,x_cam,y_cam,z_cam,x_world,y_world,z_world,object\n";
  out.reserve(out.size() + points.size() * 120);
  for (const LinePoint& p : points) {
    out += std::to_string(p.row) + "," + FormatDouble(p.column);
    for (int k = 0; k < 3; ++k) out += "," + FormatDouble(p.point_in_cam[k]);
    for (int k = 0; k < 3; ++k) out += "," + FormatDouble(p.point_in_world[k]);
    out += "," + std::to_string(p.object) + "\n";
  }
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  return WriteFileAtomically(path, out);
}

Result<std::vector<LinePoint>> ReadLineTruth(const fs::path& path) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<std::string> lines, ReadLines(path, "# rotoscan line truth 1"));
  if (lines.size() > kMaxLinePoints) return CorruptDataError(path.string() + ": too many rows");
  std::vector<LinePoint> points;
  points.reserve(lines.size());
  for (std::size_t i = 0; i < lines.size(); ++i) {
    double v[9];
    if (!ParseNumbers(lines[i], 9, v)) {
      return CorruptDataError(
          path.string() + ": data line " + std::to_string(i + 1) +
          " must hold 9 numbers (row,column,x_cam,y_cam,z_cam,x_world,y_world,z_world,object)");
    }
    if (v[0] < 0 || v[0] > kMaxImageSide || v[0] != std::floor(v[0]) || v[8] < 0 || v[8] > 1e6) {
      return CorruptDataError(path.string() + ": data line " + std::to_string(i + 1) + ": bad row or object");
    }
    LinePoint p;
    p.row = static_cast<int>(v[0]);
    p.column = v[1];
    p.point_in_cam = Eigen::Vector3d(v[2], v[3], v[4]);
    p.point_in_world = Eigen::Vector3d(v[5], v[6], v[7]);
    p.object = static_cast<int>(v[8]);
    points.push_back(p);
  }
  return points;
}

Result<std::vector<LinePoint>> ReadLineTruth(const Bundle& bundle, const FrameRecord& frame) {
  return ReadLineTruth(LineTruthPath(bundle.directory, frame));
}

Status WriteTargetPoses(const fs::path& path, const std::vector<TargetPose>& poses) {
  std::string out =
      "# rotoscan target poses 1 (cam_from_target, mm)\npose,step,r00,r01,r02,r10,r11,r12,r20,r21,r22,"
      "tx,ty,tz\n";
  for (const TargetPose& p : poses) {
    out += std::to_string(p.pose) + "," + std::to_string(p.step);
    const Eigen::Matrix3d r = p.cam_from_target.linear();
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) out += "," + FormatDouble(r(i, j));
    }
    for (int k = 0; k < 3; ++k) out += "," + FormatDouble(p.cam_from_target.translation()[k]);
    out += "\n";
  }
  return WriteFileAtomically(path, out);
}

Result<std::vector<TargetPose>> ReadTargetPoses(const fs::path& path) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<std::string> lines, ReadLines(path, "# rotoscan target poses 1"));
  if (lines.size() > kMaxPoses) return CorruptDataError(path.string() + ": too many poses");
  std::vector<TargetPose> poses;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    double v[14];
    if (!ParseNumbers(lines[i], 14, v) || v[0] < 0 || v[1] < 0 || v[0] > 1e6 || v[1] > 1e8) {
      return CorruptDataError(path.string() + ": data line " + std::to_string(i + 1) +
                              " must hold 14 numbers (pose,step,r00..r22,tx,ty,tz)");
    }
    TargetPose p;
    p.pose = static_cast<int>(v[0]);
    p.step = static_cast<int>(v[1]);
    Eigen::Matrix3d r;
    r << v[2], v[3], v[4], v[5], v[6], v[7], v[8], v[9], v[10];
    if ((r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-6) {
      return CorruptDataError(path.string() + ": data line " + std::to_string(i + 1) + ": not a rotation");
    }
    p.cam_from_target.linear() = r;
    p.cam_from_target.translation() = Eigen::Vector3d(v[11], v[12], v[13]);
    poses.push_back(p);
  }
  return poses;
}

Status WriteTableAngles(const fs::path& path, const std::vector<TableAngle>& angles) {
  std::string out = "# rotoscan table angles 1 (degrees)\npose,step,commanded_deg,true_deg\n";
  for (const TableAngle& a : angles) {
    out += std::to_string(a.pose) + "," + std::to_string(a.step) + "," +
           FormatDouble(a.commanded_rad * 180.0 / M_PI) + "," + FormatDouble(a.true_rad * 180.0 / M_PI) +
           "\n";
  }
  return WriteFileAtomically(path, out);
}

Result<std::vector<TableAngle>> ReadTableAngles(const fs::path& path) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<std::string> lines, ReadLines(path, "# rotoscan table angles 1"));
  if (lines.size() > kMaxPoses) return CorruptDataError(path.string() + ": too many angles");
  std::vector<TableAngle> angles;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    double v[4];
    if (!ParseNumbers(lines[i], 4, v) || v[0] < -1 || v[1] < 0 || v[0] > 1e6 || v[1] > 1e8 ||
        v[0] != std::floor(v[0]) || v[1] != std::floor(v[1]) || std::abs(v[2]) > 1e6 ||
        std::abs(v[3]) > 1e6) {
      return CorruptDataError(path.string() + ": data line " + std::to_string(i + 1) +
                              " must hold pose (>= -1), step (>= 0) and two angles in degrees");
    }
    angles.push_back(
        {static_cast<int>(v[0]), static_cast<int>(v[1]), v[2] * M_PI / 180.0, v[3] * M_PI / 180.0});
  }
  return angles;
}

Status WritePlacementTruth(const fs::path& path, const PlacementTruth& placement) {
  std::string out =
      "# rotoscan placement 1 (table_from_reference, mm)\nplacement,r00,r01,r02,r10,r11,r12,r20,r21,r22,tx,ty,"
      "tz\n" +
      std::to_string(placement.placement);
  const Eigen::Matrix3d r = placement.table_from_reference.linear();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) out += "," + FormatDouble(r(i, j));
  }
  for (int k = 0; k < 3; ++k) out += "," + FormatDouble(placement.table_from_reference.translation()[k]);
  out += "\n";
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  return WriteFileAtomically(path, out);
}

Result<PlacementTruth> ReadPlacementTruth(const fs::path& path) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<std::string> lines, ReadLines(path, "# rotoscan placement 1"));
  double v[13];
  if (lines.size() != 1 || !ParseNumbers(lines[0], 13, v) || v[0] < 0 || v[0] > 255 || v[0] != std::floor(v[0]) ||
      std::abs(v[10]) > 1e6 || std::abs(v[11]) > 1e6 || std::abs(v[12]) > 1e6) {
    return CorruptDataError(path.string() + ": must hold one line of 13 numbers (placement,r00..r22,tx,ty,tz)");
  }
  Eigen::Matrix3d r;
  r << v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8], v[9];
  if ((r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-6 || r.determinant() < 0) {
    return CorruptDataError(path.string() + ": not a rotation");
  }
  PlacementTruth p;
  p.placement = static_cast<int>(v[0]);
  p.table_from_reference.linear() = r;
  p.table_from_reference.translation() = Eigen::Vector3d(v[10], v[11], v[12]);
  return p;
}

}  // namespace rotoscan::bundle
