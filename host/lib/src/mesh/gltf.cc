// glTF 2.0 binary (.glb), written by hand from the Khronos specification: a 12-byte header ("glTF",
// version 2, total length), a JSON chunk (padded with spaces to 4 bytes) and a BIN chunk (padded with
// zeros). One mesh, one triangle primitive: POSITION (with the min/max the spec requires), NORMAL (unit,
// area-weighted from the faces), COLOR_0 (float RGB, linear as the spec defines it: our 8-bit sRGB-ish
// colors are written as they are, as scanners' viewers expect) and 32-bit indices. glTF is metres and +Y
// up; the table frame is millimetres and +Z up, so (x, y, z) mm becomes (x, z, -y) / 1000.
#include <algorithm>
#include <array>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "rotoscan/mesh/mesh.h"

namespace rotoscan::mesh {
namespace {

void PutU32(std::string* out, uint32_t v) {
  for (int i = 0; i < 4; ++i) out->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}

void PutFloat(std::string* out, float f) {
  uint32_t bits;
  std::memcpy(&bits, &f, 4);
  PutU32(out, bits);
}

Eigen::Vector3f ToGltf(const Eigen::Vector3d& v) {
  // + 0: no negative zero in the JSON's min/max.
  return Eigen::Vector3f(static_cast<float>(v.x()) + 0.0f, static_cast<float>(v.z()) + 0.0f,
                         static_cast<float>(-v.y()) + 0.0f);
}

}  // namespace

std::vector<Eigen::Vector3d> VertexNormals(const TriangleMesh& mesh) {
  std::vector<Eigen::Vector3d> normals(mesh.vertices.size(), Eigen::Vector3d::Zero());
  const int n = static_cast<int>(mesh.vertices.size());
  for (const Eigen::Vector3i& t : mesh.triangles) {
    if ((t.array() < 0).any() || (t.array() >= n).any()) continue;
    const Eigen::Vector3d face = (mesh.vertices[static_cast<std::size_t>(t[1])] - mesh.vertices[static_cast<std::size_t>(t[0])])
                                     .cross(mesh.vertices[static_cast<std::size_t>(t[2])] - mesh.vertices[static_cast<std::size_t>(t[0])]);
    for (int c = 0; c < 3; ++c) normals[static_cast<std::size_t>(t[c])] += face;  // area-weighted
  }
  for (Eigen::Vector3d& normal : normals) {
    const double norm = normal.norm();
    normal = norm > 0 ? Eigen::Vector3d(normal / norm) : Eigen::Vector3d::UnitZ();
  }
  return normals;
}

bool IsMeshFile(const std::filesystem::path& path) {
  const std::string ext = path.extension().string();
  if (ext == ".obj" || ext == ".stl" || ext == ".glb" || ext == ".gltf") return true;
  if (ext != ".ply") return false;
  std::ifstream in(path, std::ios::binary);
  std::string line;
  for (int i = 0; i < 200 && std::getline(in, line); ++i) {
    if (line.rfind("end_header", 0) == 0) break;
    std::istringstream words(line);
    std::string keyword, element;
    long long count = 0;
    if (words >> keyword >> element >> count && keyword == "element" && element == "face" && count > 0) return true;
  }
  return false;
}

cloud::PointCloud VerticesAsCloud(const TriangleMesh& mesh) {
  const std::vector<Eigen::Vector3d> normals = VertexNormals(mesh);
  const bool colored = mesh.vertex_colors.size() == mesh.vertices.size();
  cloud::PointCloud out;
  out.points.resize(mesh.vertices.size());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    cloud::CloudPoint& p = out.points[i];
    p.position_in_table = mesh.vertices[i].cast<float>();
    p.normal = normals[i].cast<float>();
    for (int c = 0; c < 3; ++c) {
      p.color[static_cast<std::size_t>(c)] = static_cast<uint8_t>(
          std::clamp(colored ? mesh.vertex_colors[i][c] * 255.0 + 0.5 : 200.0, 0.0, 255.0));
    }
    p.quality = 1.0f;
  }
  return out;
}

Result<std::string> EncodeGlb(const TriangleMesh& mesh) {
  const std::size_t nv = mesh.vertices.size(), nt = mesh.triangles.size();
  if (nv == 0 || nt == 0) return InvalidArgumentError("refusing to write an empty mesh");
  if (nv > std::numeric_limits<uint32_t>::max() / 64 || nt > std::numeric_limits<uint32_t>::max() / 64)
    return InvalidArgumentError("mesh too large for one glTF buffer");
  const bool colored = mesh.vertex_colors.size() == nv;
  for (const Eigen::Vector3i& t : mesh.triangles) {
    if ((t.array() < 0).any() || (t.array() >= static_cast<int>(nv)).any())
      return InvalidArgumentError("mesh triangle indexes a vertex that does not exist");
  }
  const std::vector<Eigen::Vector3d> normals = VertexNormals(mesh);
  std::string bin;
  const std::size_t vec3_bytes = nv * 12;
  bin.reserve(vec3_bytes * (colored ? 3 : 2) + nt * 12);
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max()), hi = -lo;
  for (const Eigen::Vector3d& v : mesh.vertices) {
    if (!v.allFinite()) return InvalidArgumentError("mesh holds a non-finite vertex");
    const Eigen::Vector3f p = ToGltf(v / 1000.0);
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
    for (int i = 0; i < 3; ++i) PutFloat(&bin, p[i]);
  }
  for (const Eigen::Vector3d& n : normals) {
    const Eigen::Vector3f g = ToGltf(n);
    for (int i = 0; i < 3; ++i) PutFloat(&bin, g[i]);
  }
  if (colored) {
    for (const Eigen::Vector3d& c : mesh.vertex_colors) {
      for (int i = 0; i < 3; ++i) PutFloat(&bin, static_cast<float>(std::clamp(c[i], 0.0, 1.0)));
    }
  }
  const std::size_t index_offset = bin.size();
  for (const Eigen::Vector3i& t : mesh.triangles) {
    for (int c = 0; c < 3; ++c) PutU32(&bin, static_cast<uint32_t>(t[c]));
  }
  while (bin.size() % 4 != 0) bin.push_back('\0');

  std::ostringstream json;
  json.precision(9);
  auto view = [&](std::size_t offset, std::size_t length, int target) {
    json << "{\"buffer\":0,\"byteOffset\":" << offset << ",\"byteLength\":" << length << ",\"target\":" << target
         << "}";
  };
  json << "{\"asset\":{\"version\":\"2.0\",\"generator\":\"rotoscan\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
       << "\"nodes\":[{\"mesh\":0,\"name\":\"scan\"}],\"meshes\":[{\"primitives\":[{\"attributes\":{"
       << "\"POSITION\":0,\"NORMAL\":1" << (colored ? ",\"COLOR_0\":2" : "") << "},\"indices\":"
       << (colored ? 3 : 2) << ",\"mode\":4}]}],\"buffers\":[{\"byteLength\":" << bin.size() << "}],"
       << "\"bufferViews\":[";
  view(0, vec3_bytes, 34962);
  json << ",";
  view(vec3_bytes, vec3_bytes, 34962);
  if (colored) {
    json << ",";
    view(2 * vec3_bytes, vec3_bytes, 34962);
  }
  json << ",";
  view(index_offset, nt * 12, 34963);
  json << "],\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":" << nv
       << ",\"type\":\"VEC3\",\"min\":[" << lo.x() << "," << lo.y() << "," << lo.z() << "],\"max\":[" << hi.x()
       << "," << hi.y() << "," << hi.z() << "]},{\"bufferView\":1,\"componentType\":5126,\"count\":" << nv
       << ",\"type\":\"VEC3\"}";
  if (colored) json << ",{\"bufferView\":2,\"componentType\":5126,\"count\":" << nv << ",\"type\":\"VEC3\"}";
  json << ",{\"bufferView\":" << (colored ? 3 : 2) << ",\"componentType\":5125,\"count\":" << nt * 3
       << ",\"type\":\"SCALAR\"}]}";
  std::string text = json.str();
  while (text.size() % 4 != 0) text.push_back(' ');

  std::string out;
  out.reserve(28 + text.size() + bin.size());
  out += "glTF";
  PutU32(&out, 2);
  PutU32(&out, static_cast<uint32_t>(12 + 8 + text.size() + 8 + bin.size()));
  PutU32(&out, static_cast<uint32_t>(text.size()));
  PutU32(&out, 0x4E4F534Au);  // "JSON"
  out += text;
  PutU32(&out, static_cast<uint32_t>(bin.size()));
  PutU32(&out, 0x004E4942u);  // "BIN\0"
  out += bin;
  return out;
}

}  // namespace rotoscan::mesh
