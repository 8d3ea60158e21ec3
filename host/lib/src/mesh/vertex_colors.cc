// The mesh's vertex colors from the cloud's own colors (mesh.h, ColorVerticesFromPoints).
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <open3d/geometry/KDTreeFlann.h>

#include "rotoscan/mesh/mesh.h"

namespace rotoscan::mesh {

Status ColorVerticesFromPoints(const ColoredPoints& cloud, double radius_mm, TriangleMesh* mesh,
                               VertexColorSummary* summary) {
  if (mesh == nullptr) return InvalidArgumentError("vertex colors: no mesh");
  if (!(radius_mm > 0 && radius_mm < 100)) return InvalidArgumentError("vertex colors: radius_mm in (0, 100)");
  const std::size_t n = cloud.points.size(), nv = mesh->vertices.size();
  if (cloud.colors.size() != n || (!cloud.normals.empty() && cloud.normals.size() != n)) {
    return InvalidArgumentError("vertex colors: the cloud has " + std::to_string(cloud.colors.size()) +
                                " colors and " + std::to_string(cloud.normals.size()) + " normals for " +
                                std::to_string(n) + " points");
  }
  VertexColorSummary local;
  if (n == 0 || nv == 0) {
    if (summary != nullptr) *summary = local;
    return Status::Ok();
  }
  for (const Eigen::Vector3i& t : mesh->triangles) {
    if (t.minCoeff() < 0 || static_cast<std::size_t>(t.maxCoeff()) >= nv)
      return InvalidArgumentError("vertex colors: a triangle's index is out of range");
  }
  // Area-weighted vertex normals (triangles counter-clockwise seen from outside).
  std::vector<Eigen::Vector3d> normal(nv, Eigen::Vector3d::Zero());
  for (const Eigen::Vector3i& t : mesh->triangles) {
    const Eigen::Vector3d& a = mesh->vertices[static_cast<std::size_t>(t[0])];
    const Eigen::Vector3d f = (mesh->vertices[static_cast<std::size_t>(t[1])] - a)
                                  .cross(mesh->vertices[static_cast<std::size_t>(t[2])] - a);
    for (int c = 0; c < 3; ++c) normal[static_cast<std::size_t>(t[c])] += f;
  }
  // The tree maps this matrix (Open3D 0.16 keeps a view of the matrix it is given): it must outlive it.
  Eigen::MatrixXd positions(3, static_cast<Eigen::Index>(n));
  for (std::size_t i = 0; i < n; ++i) positions.col(static_cast<Eigen::Index>(i)) = cloud.points[i];
  open3d::geometry::KDTreeFlann tree;
  tree.SetMatrixData(positions);
  // A sharp fall-off (sigma = radius / 5): the texture's detail is finer than the vertex spacing, and a
  // blur over the radius costs more than a nearest point (on the demo's mesh: sigma = radius / 2 over 1 mm,
  // 8.8 levels; nearest point 7.95; this 7.65).
  const double sigma2 = 0.04 * radius_mm * radius_mm;
  std::vector<Eigen::Vector3d> color(nv, Eigen::Vector3d::Zero());
  std::vector<char> set(nv, 0);
  std::vector<int> found;
  std::vector<double> d2;
  for (std::size_t v = 0; v < nv; ++v) {
    const double length = normal[v].norm();
    const Eigen::Vector3d nv_unit = length > 0 ? Eigen::Vector3d(normal[v] / length) : Eigen::Vector3d::Zero();
    tree.SearchRadius(mesh->vertices[v], radius_mm, found, d2);
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    double weight = 0;
    for (std::size_t k = 0; k < found.size(); ++k) {
      const auto i = static_cast<std::size_t>(found[k]);
      double w = std::exp(-d2[k] / (2 * sigma2));
      if (!cloud.normals.empty() && length > 0 && cloud.normals[i].squaredNorm() > 0.25) {
        // Only the surface on the vertex's side: not the far side of a thin part (an ear, a leg).
        const double agree = nv_unit.dot(cloud.normals[i].normalized());
        if (agree < 0.3) continue;
        w *= agree;
      }
      sum += w * cloud.colors[i];
      weight += w;
    }
    if (weight > 0) {
      color[v] = sum / weight;
      set[v] = 1;
      ++local.from_points;
    }
  }
  // Vertices with no point near (surface that fusion made where the scan has a hole): from their
  // colored neighbours on the mesh, ring after ring.
  std::vector<std::vector<int>> neighbours(nv);
  for (const Eigen::Vector3i& t : mesh->triangles) {
    for (int c = 0; c < 3; ++c) {
      neighbours[static_cast<std::size_t>(t[c])].push_back(t[(c + 1) % 3]);
      neighbours[static_cast<std::size_t>(t[c])].push_back(t[(c + 2) % 3]);
    }
  }
  std::vector<std::size_t> ring;
  for (;;) {
    ring.clear();
    for (std::size_t v = 0; v < nv; ++v) {
      if (set[v]) continue;
      Eigen::Vector3d sum = Eigen::Vector3d::Zero();
      int count = 0;
      for (const int u : neighbours[v]) {
        if (!set[static_cast<std::size_t>(u)]) continue;
        sum += color[static_cast<std::size_t>(u)];
        ++count;
      }
      if (count == 0) continue;
      color[v] = sum / count;
      ring.push_back(v);
    }
    if (ring.empty()) break;
    for (const std::size_t v : ring) set[v] = 1;
    local.from_neighbours += ring.size();
    ++local.rings;
  }
  if (mesh->vertex_colors.size() != nv) mesh->vertex_colors.assign(nv, Eigen::Vector3d::Constant(0.8));
  for (std::size_t v = 0; v < nv; ++v) {
    if (set[v]) mesh->vertex_colors[v] = color[v].cwiseMax(0.0).cwiseMin(1.0);
  }
  if (summary != nullptr) *summary = local;
  return Status::Ok();
}

}  // namespace rotoscan::mesh
