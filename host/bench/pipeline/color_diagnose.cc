// Where the color error of the views pass (pipeline/color.h) comes from, on a virtual-scanner bundle:
// the same cloud recolored with parts of the method replaced by the truth (the scene's mesh, lamp and
// rig), each variant evaluated against the true albedo (pipeline/evaluate.h: after one gain per
// channel). A diagnostic, not a benchmark: the truth it uses does not exist for a real scan.
//
//   color_diagnose BUNDLE CALIB.yaml SCENE.json [--pca]     (--pca: the PCA variants only)
//
// Variants (all with the scene's true lamp unless named "estimated"):
//   grid normals          the cloud's own normals (process's default), the depth-buffer occlusion test and
//                         the cast-shadow ratio test: what `process --lamp` gives;
//   true flat normals     each point's normal replaced by its closest true triangle's (a);
//   true smooth normals   by the true mesh's vertex normals interpolated there (a, for a smoothly shaded
//                         renderer);
//   + true visibility     occlusion and cast shadows from rays against the true mesh instead of the depth
//                         buffer and the ratio test (c);
//   PCA normals           the cloud's normals refit over a radius (pipeline/color.h, the default).
// What remains with true normals and true visibility is the combination across views and the sampling
// of the natural frame (d).
#include <embree3/rtcore.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include <open3d/core/Tensor.h>
#include <open3d/t/geometry/RaycastingScene.h>

#include "rotoscan/geometry/rig.h"
#include "rotoscan/pipeline/color.h"
#include "rotoscan/pipeline/evaluate.h"
#include "rotoscan/pipeline/process.h"
#include "rotoscan/sim/scene.h"

namespace {

using namespace rotoscan;
namespace o3c = open3d::core;

struct Truth {
  std::vector<Eigen::Vector3f> point, flat, smooth;  // per cloud point: closest true point and normals
};

// Closest true point of every cloud point, with the face's normal and the interpolated vertex normal
// (area-weighted), both turned to agree with the cloud's normal.
Truth ClosestTruth(const bundle::TruthMesh& mesh, const cloud::PointCloud& cloud) {
  std::vector<Eigen::Vector3f> vertex_normal(mesh.vertices.size(), Eigen::Vector3f::Zero());
  for (const Eigen::Vector3i& f : mesh.faces) {
    const Eigen::Vector3f n =
        (mesh.vertices[static_cast<size_t>(f[1])] - mesh.vertices[static_cast<size_t>(f[0])])
            .cross(mesh.vertices[static_cast<size_t>(f[2])] -
                   mesh.vertices[static_cast<size_t>(f[0])]);  // area-weighted
    for (int k = 0; k < 3; ++k) vertex_normal[static_cast<size_t>(f[k])] += n;
  }
  for (Eigen::Vector3f& n : vertex_normal) n.normalize();
  std::vector<float> vertices, queries;
  for (const Eigen::Vector3f& v : mesh.vertices) vertices.insert(vertices.end(), {v.x(), v.y(), v.z()});
  std::vector<uint32_t> faces;
  for (const Eigen::Vector3i& f : mesh.faces) {
    for (int k = 0; k < 3; ++k) faces.push_back(static_cast<uint32_t>(f[k]));
  }
  for (const cloud::CloudPoint& p : cloud.points) {
    queries.insert(queries.end(),
                   {p.position_in_table.x(), p.position_in_table.y(), p.position_in_table.z()});
  }
  open3d::t::geometry::RaycastingScene scene;
  scene.AddTriangles(o3c::Tensor(vertices, {static_cast<int64_t>(mesh.vertices.size()), 3}, o3c::Float32),
                     o3c::Tensor(faces, {static_cast<int64_t>(mesh.faces.size()), 3}, o3c::UInt32));
  auto result =
      scene.ComputeClosestPoints(o3c::Tensor(queries, {static_cast<int64_t>(cloud.size()), 3}, o3c::Float32));
  const o3c::Tensor points = result["points"].Contiguous(), ids = result["primitive_ids"].Contiguous(),
                    uvs = result["primitive_uvs"].Contiguous();
  const float* pp = points.GetDataPtr<float>();
  const uint32_t* id = ids.GetDataPtr<uint32_t>();
  const float* uv = uvs.GetDataPtr<float>();
  Truth truth;
  for (size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3i& f = mesh.faces[id[i]];
    const Eigen::Vector3f& a = mesh.vertices[static_cast<size_t>(f[0])];
    Eigen::Vector3f flat = (mesh.vertices[static_cast<size_t>(f[1])] - a)
                               .cross(mesh.vertices[static_cast<size_t>(f[2])] - a)
                               .normalized();
    const float u = uv[2 * i], v = uv[2 * i + 1];
    Eigen::Vector3f smooth =
        ((1 - u - v) * vertex_normal[static_cast<size_t>(f[0])] +
         u * vertex_normal[static_cast<size_t>(f[1])] + v * vertex_normal[static_cast<size_t>(f[2])])
            .normalized();
    const Eigen::Vector3f& own = cloud.points[i].normal;
    if (flat.dot(own) < 0) flat = -flat;
    if (smooth.dot(own) < 0) smooth = -smooth;
    truth.point.emplace_back(pp[3 * i], pp[3 * i + 1], pp[3 * i + 2]);
    truth.flat.push_back(flat);
    truth.smooth.push_back(smooth);
  }
  return truth;
}

class Occluder {
 public:
  explicit Occluder(const bundle::TruthMesh& mesh) {
    device_ = rtcNewDevice(nullptr);
    scene_ = rtcNewScene(device_);
    RTCGeometry g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                          3 * sizeof(float), mesh.vertices.size()));
    auto* f = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                             3 * sizeof(unsigned), mesh.faces.size()));
    for (size_t i = 0; i < mesh.vertices.size(); ++i) std::memcpy(v + 3 * i, mesh.vertices[i].data(), 12);
    for (size_t i = 0; i < mesh.faces.size(); ++i) {
      for (int k = 0; k < 3; ++k) f[3 * i + static_cast<size_t>(k)] = static_cast<unsigned>(mesh.faces[i][k]);
    }
    rtcCommitGeometry(g);
    rtcAttachGeometry(scene_, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(scene_);
  }
  ~Occluder() {
    rtcReleaseScene(scene_);
    rtcReleaseDevice(device_);
  }
  Occluder(const Occluder&) = delete;
  Occluder& operator=(const Occluder&) = delete;
  bool Blocked(const Eigen::Vector3f& from, const Eigen::Vector3f& direction, float far) const {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRay ray{};
    ray.org_x = from.x();
    ray.org_y = from.y();
    ray.org_z = from.z();
    ray.dir_x = direction.x();
    ray.dir_y = direction.y();
    ray.dir_z = direction.z();
    ray.tnear = 0.02f;
    ray.tfar = far;
    ray.mask = 0xFFFFFFFF;
    rtcOccluded1(scene_, &context, &ray);
    return ray.tfar < 0;
  }

 private:
  RTCDevice device_ = nullptr;
  RTCScene scene_ = nullptr;
};

int Fail(const Status& s) {
  std::fprintf(stderr, "color_diagnose: %s\n", s.ToString().c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: color_diagnose BUNDLE CALIB.yaml SCENE.json\n");
    return 2;
  }
  const std::filesystem::path bundle = argv[1], calib = argv[2], scene_path = argv[3];
  auto rig = geometry::ReadRigYaml(calib);
  if (!rig.ok()) return Fail(rig.status());
  auto scene = sim::LoadScene(scene_path);
  if (!scene.ok()) return Fail(scene.status());
  const Eigen::Vector3d true_lamp =
      scene->diffuse / scene->ambient * scene->light_direction_in_cam.normalized();
  auto truth = pipeline::LoadTruthSurface(bundle, scene_path);
  if (!truth.ok()) return Fail(truth.status());
  auto views = pipeline::LoadEvaluationViews(bundle);
  if (!views.ok()) return Fail(views.status());
  auto loaded = bundle::ReadBundle(bundle);
  if (!loaded.ok()) return Fail(loaded.status());
  pipeline::BundleStepSource source(std::move(*loaded));

  pipeline::ProcessOptions process;
  process.color.enabled = false;
  auto base = pipeline::ProcessBundle(bundle, *rig, process);
  if (!base.ok()) return Fail(base.status());
  const Truth t = ClosestTruth(truth->mesh, base->cloud);
  const Occluder occluder(truth->mesh);
  std::printf("%zu points, true lamp (camera frame) %.3f %.3f %.3f\n", base->cloud.size(), true_lamp.x(),
              true_lamp.y(), true_lamp.z());

  // The truth's visibility of point i at a table angle: hidden from the camera, or the lamp blocked (cast
  // shadow, or the true surface facing away from the lamp).
  const std::vector<Eigen::Vector3f>* normals = &t.smooth;
  auto visibility = [&](size_t i, double angle) {
    const Eigen::Isometry3d table_from_cam = rig->WorldFromCamAtAngle(angle);
    const Eigen::Vector3f camera = table_from_cam.translation().cast<float>();
    const Eigen::Vector3f light =
        (table_from_cam.linear() * scene->light_direction_in_cam).normalized().cast<float>();
    const Eigen::Vector3f from = t.point[i] + 0.01f * (*normals)[i];
    int v = pipeline::kVisibleLit;
    const Eigen::Vector3f to_camera = camera - from;
    const float range = to_camera.norm();
    if (occluder.Blocked(from, to_camera / range, range)) v |= pipeline::kHidden;
    if ((*normals)[i].dot(light) <= 0 || occluder.Blocked(from, light, 2000.0f)) v |= pipeline::kLampBlocked;
    return v;
  };

  auto run = [&](const std::string& name, const std::vector<Eigen::Vector3f>* replace, bool true_visibility,
                 bool estimated_lamp, double shadow_ratio, double normal_radius_mm = -1,
                 double normal_radius_lines = 2, bool shadow_map = false, double shadow_margin = 2.0) {
    cloud::PointCloud cloud = base->cloud;
    if (replace != nullptr) {
      for (size_t i = 0; i < cloud.size(); ++i) cloud.points[i].normal = (*replace)[i];
    }
    pipeline::ColorOptions color;
    if (!estimated_lamp) color.lamp_in_cam = true_lamp;
    color.shadow_ratio = shadow_ratio;
    color.normal_radius_mm = normal_radius_mm;
    color.normal_radius_lines = normal_radius_lines;
    color.shadow_map = shadow_map;
    color.shadow_margin_mm = shadow_margin;
    if (true_visibility) {
      normals = replace != nullptr ? replace : &t.smooth;
      color.truth_visibility = visibility;
    }
    pipeline::ColorSummary summary;
    Status s = pipeline::ColorFromViews(*rig, source, color, &cloud, &summary);
    if (!s.ok()) return Fail(s);
    pipeline::EvaluateOptions evaluate;
    evaluate.sample_spacing_mm = 1.0;
    auto report = pipeline::EvaluateCloud(cloud, *truth, *views, evaluate);
    if (!report.ok()) return Fail(report.status());
    const pipeline::ColorStats& c = report->color;
    std::printf(
        "%-52s mean %6.2f levels, within 10: %5.1f %%  (per-point gain %.2f; normals r %.2f mm; lamp %.2f "
        "%.2f %.2f)\n",
        name.c_str(), c.mean_abs_error_all, 100 * c.within_tolerance, c.mean_abs_error_per_point_gain,
        summary.normal_radius_mm, summary.lamp_in_cam.x(), summary.lamp_in_cam.y(), summary.lamp_in_cam.z());
    std::fflush(stdout);
    return 0;
  };
  int rc = 0;
  const bool pca_only = argc > 4 && std::string(argv[4]) == "--pca";
  for (const double lines : {3.0, 4.0, 5.0}) {
    rc |= run("PCA normals, radius " + std::to_string(lines).substr(0, 3) + " x line spacing", nullptr, false,
              false, 0.6, 0, lines);
  }
  rc |= run("PCA 4 x lines, lamp estimated", nullptr, false, true, 0.6, 0, 4.0);
  rc |= run("PCA 4 x lines + true visibility", nullptr, true, false, 0.6, 0, 4.0);
  for (const double margin : {1.0, 2.0, 3.0, 4.0, 5.0}) {
    rc |= run("PCA 4 x lines, shadow map " + std::to_string(margin).substr(0, 3) + " mm + ratio test",
              nullptr, false, false, 0.6, 0, 4.0, true, margin);
  }
  rc |= run("PCA 4 x lines, shadow map 2 mm, no ratio test", nullptr, false, false, 0.0, 0, 4.0, true, 2.0);
  rc |= run("PCA 4 x lines, shadow map 2 mm + ratio 0.5", nullptr, false, false, 0.5, 0, 4.0, true, 2.0);
  if (pca_only) return rc;
  rc |= run("grid normals (process --lamp TRUE)", nullptr, false, false, 0.6);
  rc |= run("grid normals, no shadow test", nullptr, false, false, 0.0);
  rc |= run("grid normals + true visibility", nullptr, true, false, 0.6);
  rc |= run("true flat normals", &t.flat, false, false, 0.6);
  rc |= run("true smooth normals", &t.smooth, false, false, 0.6);
  rc |= run("true flat normals + true visibility", &t.flat, true, false, 0.6);
  rc |= run("true smooth normals + true visibility", &t.smooth, true, false, 0.6);
  rc |= run("grid normals, lamp estimated", nullptr, false, true, 0.6);
  rc |= run("true smooth normals, lamp estimated", &t.smooth, false, true, 0.6);
  rc |= run("true flat normals, lamp estimated", &t.flat, false, true, 0.6);
  return rc;
}
