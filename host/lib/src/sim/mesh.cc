#include "mesh.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rotoscan/bundle/truth.h"
#include "rotoscan/calib/charuco.h"
#include "rotoscan/core/check.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/image_file.h"
#include "rotoscan/geometry/rigid.h"

namespace rotoscan::sim::internal {
namespace fs = std::filesystem;

namespace {

constexpr std::size_t kMaxObjBytes = std::size_t{1} << 30;
constexpr float kBlack = 0.05f, kWhite = 0.85f;
constexpr double kPi = 3.14159265358979323846;

Eigen::Isometry3d PoseFromSpec(const ObjectSpec& spec) {
  const Eigen::Vector3d r = spec.rotation_deg * kPi / 180.0;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.translate(spec.position_mm);
  pose.rotate(Eigen::AngleAxisd(r.z(), Eigen::Vector3d::UnitZ()) *
              Eigen::AngleAxisd(r.y(), Eigen::Vector3d::UnitY()) *
              Eigen::AngleAxisd(r.x(), Eigen::Vector3d::UnitX()));
  return pose;
}

void AddQuad(Mesh* m, const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
             const Eigen::Vector3d& d) {
  const int base = static_cast<int>(m->vertices.size());
  for (const Eigen::Vector3d* p : {&a, &b, &c, &d}) m->vertices.push_back(p->cast<float>());
  m->faces.emplace_back(base, base + 1, base + 2);
  m->faces.emplace_back(base, base + 2, base + 3);
}

// The square wave +1 on [0, s), -1 on [s, 2s), ... averaged over [x - w, x + w] (exact box filter through
// its integral, a triangle wave).
double FilteredSquareWave(double x, double w, double s) {
  auto integral = [s](double t) {
    double g = std::fmod(t / s, 2.0);
    if (g < 0) g += 2.0;
    return s * (g < 1.0 ? g : 2.0 - g);
  };
  if (w < 1e-6 * s) return std::fmod(std::floor(x / s), 2.0) == 0.0 ? 1.0 : -1.0;
  return (integral(x + w) - integral(x - w)) / (2.0 * w);
}

// Albedo of a checker of pitch s at (x, y), box-filtered over half-widths (wx, wy); white where the
// square indices i + j are odd. Separable: the filtered product is the product of filtered waves.
float Checker(double x, double y, double s, double wx = 0.0, double wy = 0.0) {
  const double c = -FilteredSquareWave(x, wx, s) * FilteredSquareWave(y, wy, s);
  return static_cast<float>(0.5 * (kWhite + kBlack) + 0.5 * (kWhite - kBlack) * c);
}

// The summed-area table `sum` ((H + 1) x (W + 1)) at a point (x, y) in texel units, clamped to the image:
// bilinear between the texel corners (exact for a piecewise-constant image).
double SumAt(const cv::Mat& sum, double x, double y) {
  const int w = sum.cols - 1, h = sum.rows - 1;
  x = std::clamp(x, 0.0, static_cast<double>(w));
  y = std::clamp(y, 0.0, static_cast<double>(h));
  const int x0 = std::min(static_cast<int>(x), w - 1), y0 = std::min(static_cast<int>(y), h - 1);
  const double fx = x - x0, fy = y - y0;
  const double* r0 = sum.ptr<double>(y0);
  const double* r1 = sum.ptr<double>(y0 + 1);
  return (1 - fy) * ((1 - fx) * r0[x0] + fx * r0[x0 + 1]) + fy * ((1 - fx) * r1[x0] + fx * r1[x0 + 1]);
}

// Mean of the image (0..255; white = 255 outside it) over [x - wx, x + wx] x [y - wy, y + wy] (texel units),
// from its summed-area table; a point sample when the box is empty.
double BoxFilteredImage(const cv::Mat& sum, double x, double y, double wx, double wy) {
  const int w = sum.cols - 1, h = sum.rows - 1;
  constexpr double kMin = 1e-6;
  if (!(wx < 1e9) || !(wy < 1e9)) wx = wy = 0.0;  // a grazing ray's footprint (inf, NaN): point sample
  if (wx < kMin && wy < kMin) {
    if (x < 0 || y < 0 || x >= w || y >= h) return 255.0;
    const int u = static_cast<int>(x), v = static_cast<int>(y);
    return sum.at<double>(v + 1, u + 1) - sum.at<double>(v, u + 1) - sum.at<double>(v + 1, u) +
           sum.at<double>(v, u);
  }
  wx = std::max(wx, kMin);
  wy = std::max(wy, kMin);
  const double x0 = x - wx, x1 = x + wx, y0 = y - wy, y1 = y + wy;
  const double inside = SumAt(sum, x1, y1) - SumAt(sum, x0, y1) - SumAt(sum, x1, y0) + SumAt(sum, x0, y0);
  const double inside_area = std::max(0.0, std::min(x1, static_cast<double>(w)) - std::max(x0, 0.0)) *
                             std::max(0.0, std::min(y1, static_cast<double>(h)) - std::max(y0, 0.0));
  const double area = (x1 - x0) * (y1 - y0);
  return (inside + 255.0 * (area - inside_area)) / area;
}

float Bilinear(const cv::Mat& tex, float x, float y, int channel) {
  x = std::clamp(x, 0.0f, static_cast<float>(tex.cols - 1));
  y = std::clamp(y, 0.0f, static_cast<float>(tex.rows - 1));
  const int x0 = std::min(static_cast<int>(x), tex.cols - 2 < 0 ? 0 : tex.cols - 2);
  const int y0 = std::min(static_cast<int>(y), tex.rows - 2 < 0 ? 0 : tex.rows - 2);
  const int x1 = std::min(x0 + 1, tex.cols - 1), y1 = std::min(y0 + 1, tex.rows - 1);
  const float fx = x - x0, fy = y - y0;
  auto at = [&](int yy, int xx) { return tex.at<cv::Vec3f>(yy, xx)[channel]; };
  return (1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x1)) +
         fy * ((1 - fx) * at(y1, x0) + fx * at(y1, x1));
}

Result<cv::Mat> LoadTexture(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return NotFoundError("texture " + path.string() + " not found");
  Result<cv::Mat> decoded = geometry::ReadImageFile(path, geometry::ImageRead::kColor);
  if (!decoded.ok()) return CorruptDataError("texture " + decoded.status().message());
  const cv::Mat image = std::move(*decoded);
  cv::Mat texture;
  image.convertTo(texture, CV_32FC3, 1.0 / 255.0);
  return texture;
}

// OBJ: v x y z [r g b], vt u v, f with v, v/vt, v//vn, v/vt/vn (negative indices allowed), polygons as
// fans; mtllib + map_Kd give the texture when the scene names none.
Result<Mesh> LoadObj(const fs::path& path, const fs::path& texture_override) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::string text, ReadFile(path, kMaxObjBytes));
  Mesh mesh;
  std::vector<Eigen::Vector2f> uvs;
  std::vector<std::array<int, 3>> face_uv;
  fs::path texture = texture_override;
  std::istringstream in(text);
  std::string line;
  std::size_t line_number = 0;
  auto bad = [&](const std::string& why) {
    return CorruptDataError(path.string() + ":" + std::to_string(line_number) + ": " + why);
  };
  while (std::getline(in, line)) {
    ++line_number;
    std::istringstream words(line);
    std::string tag;
    words >> tag;
    if (tag == "v") {
      double x, y, z;
      if (!(words >> x >> y >> z) || !std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) {
        return bad("bad vertex");
      }
      mesh.vertices.emplace_back(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
      double r, g, b;
      if (words >> r >> g >> b) {
        mesh.colors.resize(mesh.vertices.size() - 1, Eigen::Vector3f(0.8f, 0.8f, 0.8f));
        mesh.colors.emplace_back(static_cast<float>(r), static_cast<float>(g), static_cast<float>(b));
      }
    } else if (tag == "vt") {
      double u, v;
      if (!(words >> u >> v)) return bad("bad texture coordinate");
      uvs.emplace_back(static_cast<float>(u), static_cast<float>(v));
    } else if (tag == "f") {
      std::vector<int> vi, ti;
      std::string corner;
      while (words >> corner) {
        int v = 0, t = 0;
        const std::size_t slash = corner.find('/');
        try {
          v = std::stoi(corner.substr(0, slash));
          if (slash != std::string::npos && slash + 1 < corner.size() && corner[slash + 1] != '/') {
            t = std::stoi(corner.substr(slash + 1));
          }
        } catch (const std::exception&) {
          return bad("bad face corner '" + corner + "'");
        }
        const long nv = static_cast<long>(mesh.vertices.size()), nt = static_cast<long>(uvs.size());
        const long vv = v < 0 ? nv + v : v - 1, tt = t < 0 ? nt + t : t - 1;
        if (vv < 0 || vv >= nv) return bad("vertex index " + std::to_string(v) + " out of range");
        if (t != 0 && (tt < 0 || tt >= nt))
          return bad("texture index " + std::to_string(t) + " out of range");
        vi.push_back(static_cast<int>(vv));
        ti.push_back(t != 0 ? static_cast<int>(tt) : -1);
      }
      if (vi.size() < 3) return bad("face with fewer than 3 corners");
      for (std::size_t k = 1; k + 1 < vi.size(); ++k) {
        mesh.faces.emplace_back(vi[0], vi[k], vi[k + 1]);
        face_uv.push_back({ti[0], ti[k], ti[k + 1]});
      }
    } else if (tag == "mtllib" && texture.empty()) {
      std::string name;
      words >> name;
      std::ifstream mtl(path.parent_path() / name);
      std::string mtl_line;
      while (std::getline(mtl, mtl_line)) {
        std::istringstream mw(mtl_line);
        std::string key, value;
        mw >> key >> value;
        if (key == "map_Kd" && !value.empty()) texture = path.parent_path() / value;
      }
    }
    if (mesh.vertices.size() > bundle::kMaxTruthMeshVertices ||
        mesh.faces.size() > bundle::kMaxTruthMeshFaces) {
      return bad("mesh too large");
    }
  }
  if (!mesh.colors.empty()) mesh.colors.resize(mesh.vertices.size(), Eigen::Vector3f(0.8f, 0.8f, 0.8f));
  if (mesh.faces.empty()) return CorruptDataError(path.string() + ": no faces");
  if (!texture.empty()) {
    bool all_uv = true;
    for (const auto& f : face_uv) all_uv = all_uv && f[0] >= 0 && f[1] >= 0 && f[2] >= 0;
    if (!all_uv)
      return CorruptDataError(path.string() + ": a texture needs texture coordinates on every face");
    ROTOSCAN_ASSIGN_OR_RETURN(mesh.texture, LoadTexture(texture));
    mesh.uv.reserve(face_uv.size() * 3);
    for (const auto& f : face_uv) {
      for (int k = 0; k < 3; ++k) mesh.uv.push_back(uvs[f[k]]);
    }
  }
  return mesh;
}

Mesh MakeSphere(double radius, int segments) {
  Mesh m;
  const int rings = std::max(2, segments / 2);
  m.vertices.emplace_back(0.f, 0.f, static_cast<float>(-radius));
  for (int i = 1; i < rings; ++i) {
    const double theta = kPi * i / rings - kPi / 2;
    for (int j = 0; j < segments; ++j) {
      const double phi = 2 * kPi * j / segments;
      m.vertices.push_back((radius * Eigen::Vector3d(std::cos(theta) * std::cos(phi),
                                                     std::cos(theta) * std::sin(phi), std::sin(theta)))
                               .cast<float>());
    }
  }
  m.vertices.emplace_back(0.f, 0.f, static_cast<float>(radius));
  const int top = static_cast<int>(m.vertices.size()) - 1;
  auto idx = [&](int ring, int j) { return 1 + (ring - 1) * segments + (j % segments); };
  for (int j = 0; j < segments; ++j) m.faces.emplace_back(0, idx(1, j + 1), idx(1, j));
  for (int i = 1; i + 1 < rings; ++i) {
    for (int j = 0; j < segments; ++j) {
      m.faces.emplace_back(idx(i, j), idx(i, j + 1), idx(i + 1, j + 1));
      m.faces.emplace_back(idx(i, j), idx(i + 1, j + 1), idx(i + 1, j));
    }
  }
  for (int j = 0; j < segments; ++j) m.faces.emplace_back(top, idx(rings - 1, j), idx(rings - 1, j + 1));
  return m;
}

Mesh MakeCylinder(double radius, double height, int segments) {
  Mesh m;
  for (int level = 0; level < 2; ++level) {
    for (int j = 0; j < segments; ++j) {
      const double phi = 2 * kPi * j / segments;
      m.vertices.emplace_back(static_cast<float>(radius * std::cos(phi)),
                              static_cast<float>(radius * std::sin(phi)), static_cast<float>(level * height));
    }
  }
  const int bottom = static_cast<int>(m.vertices.size());
  m.vertices.emplace_back(0.f, 0.f, 0.f);
  m.vertices.emplace_back(0.f, 0.f, static_cast<float>(height));
  for (int j = 0; j < segments; ++j) {
    const int a = j, b = (j + 1) % segments;
    m.faces.emplace_back(a, b, b + segments);
    m.faces.emplace_back(a, b + segments, a + segments);
    m.faces.emplace_back(bottom, b, a);
    m.faces.emplace_back(bottom + 1, a + segments, b + segments);
  }
  return m;
}

Mesh MakeBox(const Eigen::Vector3d& size) {
  Mesh m;
  const double x = size.x() / 2, y = size.y() / 2, z = size.z();
  for (int i = 0; i < 8; ++i) {
    m.vertices.emplace_back(static_cast<float>((i & 1) ? x : -x), static_cast<float>((i & 2) ? y : -y),
                            static_cast<float>((i & 4) ? z : 0.0));
  }
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    m.faces.emplace_back(q[0], q[1], q[2]);
    m.faces.emplace_back(q[0], q[2], q[3]);
  }
  return m;
}

}  // namespace

Eigen::Vector3f Mesh::Albedo(unsigned face, float u, float v, const Eigen::Vector3d& point_in_table,
                             const Eigen::Vector3d& footprint_x, const Eigen::Vector3d& footprint_y) const {
  switch (pattern) {
    case Pattern::kChecker: {
      const Eigen::Vector3d p = object_from_table * point_in_table;
      const Eigen::Vector3d dx = object_from_table.linear() * footprint_x;
      const Eigen::Vector3d dy = object_from_table.linear() * footprint_y;
      const double s = square_mm;
      // Squares cover [-s, cols * s] x [-s, rows * s]; a white margin around them.
      if (p.x() < -s || p.x() > cols * s || p.y() < -s || p.y() > rows * s)
        return Eigen::Vector3f::Constant(kWhite);
      return Eigen::Vector3f::Constant(Checker(p.x(), p.y(), s, 0.5 * (std::abs(dx.x()) + std::abs(dy.x())),
                                               0.5 * (std::abs(dx.y()) + std::abs(dy.y()))));
    }
    case Pattern::kCalibrationObject: {
      const Eigen::Vector3d p = object_from_table * point_in_table;
      const Eigen::Vector3d dx = object_from_table.linear() * footprint_x;
      const Eigen::Vector3d dy = object_from_table.linear() * footprint_y;
      const bool on_x_plane = std::abs(p.y()) < std::abs(p.x());
      const double in_plane = on_x_plane ? p.x() : p.y();
      const double w_in =
          0.5 * (on_x_plane ? std::abs(dx.x()) + std::abs(dy.x()) : std::abs(dx.y()) + std::abs(dy.y()));
      const double w_z = 0.5 * (std::abs(dx.z()) + std::abs(dy.z()));
      return Eigen::Vector3f::Constant(Checker(in_plane, p.z(), square_mm, w_in, w_z));
    }
    case Pattern::kCharuco: {
      const Eigen::Vector3d p = object_from_table * point_in_table;
      const Eigen::Vector3d dx = object_from_table.linear() * footprint_x;
      const Eigen::Vector3d dy = object_from_table.linear() * footprint_y;
      const double k = pattern_texels_per_mm;
      const double grey = BoxFilteredImage(pattern_sum, (p.x() + square_mm) * k, (p.y() + square_mm) * k,
                                           0.5 * k * (std::abs(dx.x()) + std::abs(dy.x())),
                                           0.5 * k * (std::abs(dx.y()) + std::abs(dy.y())));
      return Eigen::Vector3f::Constant(static_cast<float>(kBlack + (kWhite - kBlack) * grey / 255.0));
    }
    case Pattern::kNone: break;
  }
  if (checker_mm > 0.0) {  // the solid checker: dark cells where the cell indices' sum is odd
    const Eigen::Vector3d p = object_from_table * point_in_table;
    // Cell boundaries a quarter cell off the object's axes: a flat face through its origin (a plane, a
    // box's middle) lies inside one layer of cells, not on a boundary that rounding would flip.
    const Eigen::Vector3d q = p / checker_mm + Eigen::Vector3d::Constant(0.25);
    const long sum = std::lround(std::floor(q.x()) + std::floor(q.y()) + std::floor(q.z()));
    if (sum % 2 != 0) return dark_albedo * PlainAlbedo(face, u, v);
  }
  return PlainAlbedo(face, u, v);
}

Eigen::Vector3f Mesh::PlainAlbedo(unsigned face, float u, float v) const {
  const float w = 1.0f - u - v;
  if (!texture.empty() && !uv.empty()) {
    const Eigen::Vector2f t = w * uv[3 * face] + u * uv[3 * face + 1] + v * uv[3 * face + 2];
    const float x = t.x() * (texture.cols - 1), y = (1.0f - t.y()) * (texture.rows - 1);
    return Eigen::Vector3f(Bilinear(texture, x, y, 2), Bilinear(texture, x, y, 1),
                           Bilinear(texture, x, y, 0));
  }
  if (!colors.empty()) {
    const Eigen::Vector3i& f = faces[face];
    return w * colors[f[0]] + u * colors[f[1]] + v * colors[f[2]];
  }
  return color;
}

Mesh MakeTableTop(double radius_mm, const Eigen::Vector3d& albedo) {
  Mesh m;
  const int segments = 96;
  m.vertices.emplace_back(0.f, 0.f, 0.f);
  for (int j = 0; j < segments; ++j) {
    const double phi = 2 * kPi * j / segments;
    m.vertices.emplace_back(static_cast<float>(radius_mm * std::cos(phi)),
                            static_cast<float>(radius_mm * std::sin(phi)), 0.f);
  }
  for (int j = 0; j < segments; ++j) m.faces.emplace_back(0, 1 + j, 1 + (j + 1) % segments);
  m.color = albedo.cast<float>();
  return m;
}

Result<Mesh> MakeObject(const ObjectSpec& spec, const Scene& scene) {
  Mesh m;
  Eigen::Isometry3d pose = PoseFromSpec(spec);
  switch (spec.type) {
    case ObjectType::kMesh: {
      const std::string ext = spec.file.extension().string();
      if (ext == ".obj" || ext == ".OBJ") {
        ROTOSCAN_ASSIGN_OR_RETURN(m, LoadObj(spec.file, spec.texture));
      } else if (ext == ".ply" || ext == ".PLY") {
        ROTOSCAN_ASSIGN_OR_RETURN(bundle::TruthMesh ply, bundle::ReadPlyMesh(spec.file));
        m.vertices = ply.vertices;
        m.faces = ply.faces;
        for (const auto& c : ply.colors) m.colors.emplace_back(c[0] / 255.f, c[1] / 255.f, c[2] / 255.f);
        if (m.faces.empty()) return CorruptDataError(spec.file.string() + ": no faces");
      } else {
        return InvalidArgumentError("mesh file " + spec.file.string() + " must be .obj or .ply");
      }
      // Up axis to z, scale, then stand the mesh on the table centred on the axis.
      if (spec.up_axis == "y") {
        for (Eigen::Vector3f& v : m.vertices) v = Eigen::Vector3f(v.x(), -v.z(), v.y());
      }
      Eigen::Vector3f lo = m.vertices[0], hi = m.vertices[0];
      for (const Eigen::Vector3f& v : m.vertices) lo = lo.cwiseMin(v), hi = hi.cwiseMax(v);
      const double scale =
          spec.height_mm > 0 ? spec.height_mm / std::max(1e-12f, hi.z() - lo.z()) : spec.scale;
      const Eigen::Vector3f centre((lo.x() + hi.x()) / 2, (lo.y() + hi.y()) / 2, lo.z());
      for (Eigen::Vector3f& v : m.vertices) v = ((v - centre) * static_cast<float>(scale)).eval();
      break;
    }
    case ObjectType::kSphere:
      m = MakeSphere(spec.radius_mm, spec.segments);
      pose = pose * Eigen::Translation3d(0, 0, spec.radius_mm);
      break;
    case ObjectType::kCylinder: m = MakeCylinder(spec.radius_mm, spec.size_mm.z(), spec.segments); break;
    case ObjectType::kBox: m = MakeBox(spec.size_mm); break;
    case ObjectType::kPlane: {
      const double w = spec.size_mm.x() / 2, h = spec.size_mm.y() / 2;
      AddQuad(&m, {-w, -h, 0}, {w, -h, 0}, {w, h, 0}, {-w, h, 0});
      const Eigen::Isometry3d cam_from_object =
          Eigen::Translation3d(0, 0, spec.distance_mm) *
          Eigen::AngleAxisd(geometry::DegToRad(spec.angle_deg), Eigen::Vector3d::UnitY());
      pose = scene.rig.CamFromTable().inverse() * cam_from_object;
      break;
    }
    case ObjectType::kCheckerboard: {
      const double s = spec.square_mm;
      AddQuad(&m, {-2 * s, -2 * s, 0}, {(spec.cols + 1) * s, -2 * s, 0},
              {(spec.cols + 1) * s, (spec.rows + 1) * s, 0}, {-2 * s, (spec.rows + 1) * s, 0});
      m.pattern = Pattern::kChecker;
      m.cols = spec.cols;
      m.rows = spec.rows;
      m.square_mm = s;
      if (spec.marker_mm > 0) {
        // ChArUco: the board image drawn by OpenCV at a resolution where its marker cells fall on whole
        // texels (then the texture is the board's design exactly), box-filtered through its summed-area
        // table.
        calib::CharucoBoard board{spec.cols + 1, spec.rows + 1, s, spec.marker_mm, spec.dictionary};
        ROTOSCAN_RETURN_IF_ERROR(board.Check().WithContext("charuco object"));
        const int texels_per_square = board.CrispPixelsPerSquare(8, 400);
        cv::integral(board.Draw(texels_per_square), m.pattern_sum, CV_64F);
        m.pattern_texels_per_mm = texels_per_square / s;
        m.pattern = Pattern::kCharuco;
      }
      // Standing upright on the table facing the camera: target x along table x, y down, z away.
      Eigen::Matrix3d r;
      r << 1, 0, 0, 0, 0, 1, 0, -1, 0;
      Eigen::Isometry3d stand = Eigen::Isometry3d::Identity();
      stand.linear() = r;
      stand.translation() = Eigen::Vector3d(-(spec.cols - 1) * s / 2, 0, (spec.rows + 1) * s);
      pose = pose * stand;
      break;
    }
    case ObjectType::kCalibrationObject: {
      const double l = spec.size_mm.x();
      // Two orthogonal planes meeting on the target's z axis: y = 0 (x in [0, l]) and x = 0 (y in [0, l]),
      // z in [0, l]; turned so that the opening faces the camera (-y of the table).
      AddQuad(&m, {0, 0, 0}, {l, 0, 0}, {l, 0, l}, {0, 0, l});
      AddQuad(&m, {0, 0, 0}, {0, l, 0}, {0, l, l}, {0, 0, l});
      m.pattern = Pattern::kCalibrationObject;
      m.square_mm = spec.square_mm;
      pose = pose * Eigen::AngleAxisd(geometry::DegToRad(-135.0), Eigen::Vector3d::UnitZ());
      break;
    }
  }
  if (spec.has_pose) pose = spec.table_from_object;
  m.color = spec.color.cast<float>();
  m.specular = static_cast<float>(spec.specular);
  m.shininess = static_cast<float>(spec.shininess);
  m.checker_mm = spec.checker_mm;
  m.dark_albedo = static_cast<float>(spec.dark_albedo);
  m.table_from_object = pose;
  m.object_from_table = pose.inverse();
  for (Eigen::Vector3f& v : m.vertices) v = (pose * v.cast<double>()).cast<float>();
  // A mesh file stands for a smooth object (Spot's 1.5 mm facets are the file's sampling, not the object's
  // shape): shaded with interpolated normals, as a real surface would be lit.
  if (spec.type == ObjectType::kMesh) SmoothCornerNormals(&m, 60.0);
  return m;
}

void SmoothCornerNormals(Mesh* m, double crease_deg) {
  ROTOSCAN_CHECK(m != nullptr);
  const size_t nf = m->faces.size();
  // Vertices at the same position (texture seams) welded into one.
  std::map<std::array<float, 3>, int> weld;
  std::vector<int> welded(m->vertices.size());
  for (size_t i = 0; i < m->vertices.size(); ++i) {
    const Eigen::Vector3f& v = m->vertices[i];
    welded[i] =
        weld.emplace(std::array<float, 3>{v.x(), v.y(), v.z()}, static_cast<int>(weld.size())).first->second;
  }
  std::vector<Eigen::Vector3f> area_normal(nf);
  std::vector<std::vector<uint32_t>> around(weld.size());
  for (size_t f = 0; f < nf; ++f) {
    const Eigen::Vector3i& t = m->faces[f];
    const Eigen::Vector3f& a = m->vertices[static_cast<size_t>(t[0])];
    area_normal[f] =
        (m->vertices[static_cast<size_t>(t[1])] - a).cross(m->vertices[static_cast<size_t>(t[2])] - a);
    for (int k = 0; k < 3; ++k)
      around[static_cast<size_t>(welded[static_cast<size_t>(t[k])])].push_back(static_cast<uint32_t>(f));
  }
  const float min_cos = static_cast<float>(std::cos(crease_deg * kPi / 180.0));
  m->corner_normals.assign(3 * nf, Eigen::Vector3f::Zero());
  for (size_t f = 0; f < nf; ++f) {
    const Eigen::Vector3f own = area_normal[f].normalized();
    for (int k = 0; k < 3; ++k) {
      Eigen::Vector3f sum = Eigen::Vector3f::Zero();
      for (const uint32_t g : around[static_cast<size_t>(welded[static_cast<size_t>(m->faces[f][k])])]) {
        if (area_normal[g].normalized().dot(own) >= min_cos) sum += area_normal[g];
      }
      m->corner_normals[3 * f + static_cast<size_t>(k)] = sum.squaredNorm() > 0 ? sum.normalized() : own;
    }
  }
}

}  // namespace rotoscan::sim::internal
