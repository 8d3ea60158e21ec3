// Placements of the scene's objects on the table (scene.h, PlaceScene): the whole set of objects turned as
// one rigid body, stood on the table top and centred on the axis, as a person lays the object on its side
// for a second scan.
#include <limits>

#include "mesh.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::sim {

Result<Scene> PlaceScene(const Scene& scene, int placement, Eigen::Isometry3d* table_from_reference) {
  const int count = scene.placements.empty() ? 1 : static_cast<int>(scene.placements.size());
  if (placement < 0 || placement >= count) {
    return InvalidArgumentError("placement " + std::to_string(placement) +
                                " is not defined by the scene (it has " + std::to_string(count) +
                                ": 'placements' in the scene JSON, sim/scene.h)");
  }
  Eigen::Isometry3d moved = Eigen::Isometry3d::Identity();
  Scene placed = scene;
  if (!scene.placements.empty()) {
    const Scene::Placement& p = scene.placements[static_cast<size_t>(placement)];
    const Eigen::Vector3d r = p.rotation_deg * (3.14159265358979323846 / 180.0);
    const Eigen::Matrix3d rotation = (Eigen::AngleAxisd(r.z(), Eigen::Vector3d::UnitZ()) *
                                      Eigen::AngleAxisd(r.y(), Eigen::Vector3d::UnitY()) *
                                      Eigen::AngleAxisd(r.x(), Eigen::Vector3d::UnitX()))
                                         .toRotationMatrix();
    // The objects as given, turned; their bounding box says where the table top and the axis are.
    std::vector<internal::Mesh> meshes;
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    for (const ObjectSpec& spec : scene.objects) {
      ROTOSCAN_ASSIGN_OR_RETURN(internal::Mesh mesh, internal::MakeObject(spec, scene));
      for (const Eigen::Vector3f& v : mesh.vertices) {
        const Eigen::Vector3d q = rotation * v.cast<double>();
        lo = lo.cwiseMin(q);
        hi = hi.cwiseMax(q);
      }
      meshes.push_back(std::move(mesh));
    }
    if (meshes.empty()) return InvalidArgumentError("the scene has no object to place");
    moved.linear() = rotation;
    moved.translation() =
        Eigen::Vector3d(-(lo.x() + hi.x()) / 2, -(lo.y() + hi.y()) / 2, -lo.z()) + p.position_mm;
    for (size_t i = 0; i < placed.objects.size(); ++i) {
      placed.objects[i].has_pose = true;
      placed.objects[i].table_from_object = moved * meshes[i].table_from_object;
    }
  }
  if (table_from_reference != nullptr) *table_from_reference = moved;
  return placed;
}

}  // namespace rotoscan::sim
