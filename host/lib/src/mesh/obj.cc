// Wavefront OBJ with a texture atlas baked from the vertex colors (mesh.h, ObjWithAtlas).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "rotoscan/mesh/mesh.h"

namespace rotoscan::mesh {
namespace {

constexpr int kMaxAtlasSide = 8192;

void Append(std::string* out, const char* format, double a, double b, double c) {
  char line[160];
  const int n = std::snprintf(line, sizeof(line), format, a, b, c);
  out->append(line, static_cast<std::size_t>(std::max(0, n)));
}

}  // namespace

Result<ObjWithAtlas> EncodeObjWithAtlas(const TriangleMesh& mesh, const std::string& mtl_name,
                                        const std::string& texture_name) {
  const std::size_t nv = mesh.vertices.size(), nt = mesh.triangles.size();
  if (nv == 0 || nt == 0) return InvalidArgumentError("refusing to write an empty mesh");
  const bool colored = !mesh.vertex_colors.empty();
  if (colored && mesh.vertex_colors.size() != nv)
    return InvalidArgumentError("the mesh has " + std::to_string(mesh.vertex_colors.size()) + " colors for " +
                                std::to_string(nv) + " vertices");
  for (const Eigen::Vector3i& t : mesh.triangles) {
    if (t.minCoeff() < 0 || static_cast<std::size_t>(t.maxCoeff()) >= nv)
      return InvalidArgumentError("a triangle indexes a vertex that does not exist");
  }
  for (const Eigen::Vector3d& v : mesh.vertices) {
    if (!v.allFinite()) return InvalidArgumentError("the mesh has a non-finite vertex");
  }
  // The atlas: cells of 2 x 2 texels, `columns` per row.
  const auto columns = static_cast<std::size_t>(std::ceil(std::sqrt(static_cast<double>(nt))));
  const std::size_t rows = (nt + columns - 1) / columns;
  if (colored && (2 * columns > kMaxAtlasSide || 2 * rows > kMaxAtlasSide)) {
    return InvalidArgumentError("the mesh has " + std::to_string(nt) + " triangles: too many for a " +
                                std::to_string(kMaxAtlasSide) + "-texel texture atlas (write .ply or .glb)");
  }
  ObjWithAtlas out;
  std::string& obj = out.obj;
  obj.reserve(nv * 64 + nt * (colored ? 120 : 30));
  obj += "# rotoscan mesh: millimetres, table frame (+Z up)\n";
  if (colored) obj += "mtllib " + mtl_name + "\nusemtl scan\n";
  for (std::size_t i = 0; i < nv; ++i) {
    const Eigen::Vector3d& v = mesh.vertices[i];
    if (colored) {
      Append(&obj, "v %.5f %.5f %.5f", v.x(), v.y(), v.z());
      const Eigen::Vector3d c = mesh.vertex_colors[i].cwiseMax(0.0).cwiseMin(1.0);
      Append(&obj, " %.4f %.4f %.4f\n", c.x(), c.y(), c.z());
    } else {
      Append(&obj, "v %.5f %.5f %.5f\n", v.x(), v.y(), v.z());
    }
  }
  if (!colored) {
    for (const Eigen::Vector3i& t : mesh.triangles) {
      char line[64];
      const int n = std::snprintf(line, sizeof(line), "f %d %d %d\n", t[0] + 1, t[1] + 1, t[2] + 1);
      obj.append(line, static_cast<std::size_t>(n));
    }
    return out;
  }
  const int width = static_cast<int>(2 * columns), height = static_cast<int>(2 * rows);
  out.texture = cv::Mat(height, width, CV_8UC3, cv::Scalar(0, 0, 0));
  auto texel = [](const Eigen::Vector3d& rgb) {
    const Eigen::Vector3d c = (255.0 * rgb).array().round().cwiseMax(0.0).cwiseMin(255.0);
    return cv::Vec3b(static_cast<uchar>(c.z()), static_cast<uchar>(c.y()), static_cast<uchar>(c.x()));
  };
  // UVs: u across, v up from the image's bottom row (OBJ's convention).
  for (std::size_t t = 0; t < nt; ++t) {
    const int x0 = static_cast<int>(2 * (t % columns)), y0 = static_cast<int>(2 * (t / columns));
    const Eigen::Vector3i& tri = mesh.triangles[t];
    const Eigen::Vector3d c0 = mesh.vertex_colors[static_cast<std::size_t>(tri[0])];
    const Eigen::Vector3d c1 = mesh.vertex_colors[static_cast<std::size_t>(tri[1])];
    const Eigen::Vector3d c2 = mesh.vertex_colors[static_cast<std::size_t>(tri[2])];
    out.texture.at<cv::Vec3b>(y0, x0) = texel(c0);
    out.texture.at<cv::Vec3b>(y0, x0 + 1) = texel(c1);
    out.texture.at<cv::Vec3b>(y0 + 1, x0) = texel(c2);
    out.texture.at<cv::Vec3b>(y0 + 1, x0 + 1) = texel(c1 + c2 - c0);
    const double corners[3][2] = {{x0 + 0.5, y0 + 0.5}, {x0 + 1.5, y0 + 0.5}, {x0 + 0.5, y0 + 1.5}};
    for (const auto& corner : corners) {
      char line[80];
      const int n =
          std::snprintf(line, sizeof(line), "vt %.8f %.8f\n", corner[0] / width, 1.0 - corner[1] / height);
      obj.append(line, static_cast<std::size_t>(n));
    }
  }
  for (std::size_t t = 0; t < nt; ++t) {
    const Eigen::Vector3i& tri = mesh.triangles[t];
    char line[120];
    const unsigned long long uv = 3 * t + 1;
    const int n = std::snprintf(line, sizeof(line), "f %d/%llu %d/%llu %d/%llu\n", tri[0] + 1, uv, tri[1] + 1,
                                uv + 1, tri[2] + 1, uv + 2);
    obj.append(line, static_cast<std::size_t>(n));
  }
  out.mtl =
      "# rotoscan: the scan's colors as a texture\nnewmtl scan\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum "
      "1\nmap_Kd " +
      texture_name + "\n";
  return out;
}

}  // namespace rotoscan::mesh
