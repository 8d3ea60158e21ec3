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

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <utility>
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
  std::vector<Eigen::Vector3f> albedo;                // and the true albedo there (0..255)
};

// Closest true point of every cloud point, with the face's normal and the interpolated vertex normal
// (area-weighted), both turned to agree with the cloud's normal.
Truth ClosestTruth(const pipeline::TruthSurface& surface, const cloud::PointCloud& cloud) {
  const bundle::TruthMesh& mesh = surface.mesh;
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
    truth.albedo.push_back(surface.albedo ? Eigen::Vector3f(255.0f * surface.albedo(static_cast<int>(id[i]), u, v,
                                                                                    truth.point.back().cast<double>()))
                                          : Eigen::Vector3f::Zero());
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
  const Truth t = ClosestTruth(*truth, base->cloud);
  const Occluder occluder(truth->mesh);
  std::printf("%zu points, true lamp (camera frame) %.3f %.3f %.3f\n", base->cloud.size(), true_lamp.x(),
              true_lamp.y(), true_lamp.z());

  // The truth's visibility of point i at a table angle: hidden from the camera, or the lamp blocked (cast
  // shadow, or the true surface facing away from the lamp).
  const std::vector<Eigen::Vector3f>* normals = &t.smooth;
  bool cast_only = false;
  std::vector<std::pair<std::string, double>> settings;  // --sweep's, for the next run  // the lamp blocked only by the object, not the surface facing away from it
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
    if ((!cast_only && (*normals)[i].dot(light) <= 0) || occluder.Blocked(from, light, 2000.0f))
      v |= pipeline::kLampBlocked;
    return v;
  };

  auto run = [&](const std::string& name, const std::vector<Eigen::Vector3f>* replace, bool true_visibility,
                 bool estimated_lamp, double shadow_ratio, double normal_radius_mm = -1,
                 double normal_radius_lines = 2, bool shadow_map = false, double shadow_margin = 2.0,
                 int truth_bits = pipeline::kHidden | pipeline::kLampBlocked) {
    cloud::PointCloud cloud = base->cloud;
    if (replace != nullptr) {
      for (size_t i = 0; i < cloud.size(); ++i) cloud.points[i].normal = (*replace)[i];
    }
    pipeline::ColorOptions color;
    if (!estimated_lamp) color.lamp_in_cam = true_lamp;
    color.use_calibrated_lamp = false;  // estimated: from the scan, not from calib.yaml's lamp
    color.truth_visibility_bits = truth_bits;
    color.shadow_ratio = shadow_ratio;
    color.normal_radius_mm = normal_radius_mm;
    color.normal_radius_lines = normal_radius_lines;
    color.shadow_map = shadow_map;
    color.shadow_margin_mm = shadow_margin;
    for (const auto& [key, value] : settings) {
      if (key == "occlusion") color.occlusion_mm = value;
      if (key == "splat") color.zbuffer_splat_cells = static_cast<int>(value);
      if (key == "cell") color.zbuffer_cell_px = static_cast<int>(value);
      if (key == "min_cos") color.min_cos_camera = value;
      if (key == "margin") color.shadow_margin_mm = value;
      if (key == "ratio") color.shadow_ratio = value;
      if (key == "shadowed_ambient") color.shadowed_ambient = value != 0;
    }
    if (true_visibility) {
      normals = replace != nullptr ? replace : &t.smooth;
      color.truth_visibility = visibility;
    }
    std::vector<int> seen(cloud.size(), 0), used(cloud.size(), 0);
    color.per_point = [&](size_t i, int a, int b) { seen[i] = a, used[i] = b; };
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
    if (std::getenv("CD_BREAKDOWN") != nullptr) {  // the error by views used and by the true normal's z
      auto bin_of_views = [](int u) { return u == 0 ? 0 : u <= 2 ? 1 : u <= 5 ? 2 : u <= 11 ? 3 : 4; };
      double sum[2][5] = {}, count[2][5] = {}, zsum[5] = {}, zcount[5] = {};
      for (size_t i = 0; i < cloud.size(); ++i) {
        if ((cloud.points[i].position_in_table - t.point[i]).norm() > 0.5f) continue;
        double e = 0;
        for (int ch = 0; ch < 3; ++ch) e += std::abs(c.gain[ch] * cloud.points[i].color[ch] - t.albedo[i][ch]) / 3;
        const int b = bin_of_views(used[i]);
        sum[0][b] += e, count[0][b] += 1;
        if (e > 10) sum[1][b] += 1;
        const int zb = std::clamp(static_cast<int>((t.smooth[i].z() + 1) * 2.5f), 0, 4);
        zsum[zb] += e, zcount[zb] += 1;
      }
      const char* names[5] = {"0 views", "1-2", "3-5", "6-11", "12+"};
      for (int b = 0; b < 5; ++b)
        std::printf("    used %-8s %7.0f points, mean %6.2f, over 10: %5.1f %%\n", names[b], count[0][b],
                    count[0][b] > 0 ? sum[0][b] / count[0][b] : 0, count[0][b] > 0 ? 100 * sum[1][b] / count[0][b] : 0);
      double e_seen0 = 0, n_seen0 = 0, e_shad = 0, n_shad = 0;
      for (size_t i = 0; i < cloud.size(); ++i) {
        if (used[i] > 0 || (cloud.points[i].position_in_table - t.point[i]).norm() > 0.5f) continue;
        double e = 0;
        for (int ch = 0; ch < 3; ++ch) e += std::abs(c.gain[ch] * cloud.points[i].color[ch] - t.albedo[i][ch]) / 3;
        if (seen[i] == 0) e_seen0 += e, n_seen0 += 1;
        else e_shad += e, n_shad += 1;
      }
      std::printf("    of those: seen in no view %.0f (mean %.2f), all views cast shadows %.0f (mean %.2f)\n", n_seen0,
                  n_seen0 > 0 ? e_seen0 / n_seen0 : 0, n_shad, n_shad > 0 ? e_shad / n_shad : 0);
      for (int b = 0; b < 5; ++b)
        std::printf("    normal z in [%4.1f, %4.1f) %7.0f points, mean %6.2f\n", -1 + 0.4 * b, -0.6 + 0.4 * b,
                    zcount[b], zcount[b] > 0 ? zsum[b] / zcount[b] : 0);
    }
    std::fflush(stdout);
    return 0;
  };
  int rc = 0;
  const bool pca_only = argc > 4 && std::string(argv[4]) == "--pca";
  if (argc > 4 && std::string(argv[4]) == "--sweep") {  // each further argument: key=value,key=value
    for (int a = 5; a < argc; ++a) {
      settings.clear();
      std::string item;
      std::istringstream list(argv[a]);
      while (std::getline(list, item, ',')) {
        const size_t eq = item.find('=');
        if (eq != std::string::npos) settings.emplace_back(item.substr(0, eq), std::atof(item.c_str() + eq + 1));
      }
      rc |= run(std::string("PCA 4, map 4 mm: ") + argv[a], nullptr, false, false, 0.6, 0, 4.0, true, 4.0);
    }
    return rc;
  }
  if (argc > 4 && std::string(argv[4]) == "--split") {  // which part of the visibility costs most
    rc |= run("PCA 4 x lines, shadow map 4 mm (process's default)", nullptr, false, false, 0.6, 0, 4.0, true,
              4.0);
    rc |= run("  + true hidden (own shadow tests)", nullptr, true, false, 0.6, 0, 4.0, true, 4.0,
              pipeline::kHidden);
    rc |= run("  + true lamp blocked (own occlusion test)", nullptr, true, false, 0.6, 0, 4.0, true, 4.0,
              pipeline::kLampBlocked);
    cast_only = true;
    rc |= run("  + true cast shadows only (own occlusion test)", nullptr, true, false, 0.6, 0, 4.0, true, 4.0,
              pipeline::kLampBlocked);
    rc |= run("  + true hidden and cast shadows only", nullptr, true, false, 0.6, 0, 4.0, true, 4.0);
    cast_only = false;
    rc |= run("  + true hidden and lamp blocked", nullptr, true, false, 0.6, 0, 4.0, true, 4.0);
    return rc;
  }
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
