// The preview picture: a small z-buffer rasteriser of our own (a person's quick look after a scan; no
// OpenGL context is needed, so it works on a headless machine and in CI).
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rotoscan/core/file.h"
#include "rotoscan/mesh/mesh.h"

namespace rotoscan::mesh {
namespace {

constexpr double kPi = 3.14159265358979323846;
const cv::Vec3b kBackground(38, 32, 30);

// A look-at camera framing a sphere (centre, radius) from the options' direction.
struct ViewCamera {
  Eigen::Vector3d eye, right, down, forward;
  double focal, cx, cy;

  Eigen::Vector3d ToCamera(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d d = p - eye;
    return {d.dot(right), d.dot(down), d.dot(forward)};
  }
};

ViewCamera MakeCamera(const Eigen::Vector3d& centre, double radius, const PreviewOptions& options) {
  const Eigen::Vector3d up = options.up.normalized();
  Eigen::Vector3d e1 = up.unitOrthogonal();
  const Eigen::Vector3d e2 = up.cross(e1);
  const double az = options.azimuth_deg * kPi / 180.0, el = options.elevation_deg * kPi / 180.0;
  const Eigen::Vector3d towards_eye =
      std::cos(el) * (std::cos(az) * e1 + std::sin(az) * e2) + std::sin(el) * up;
  const double half_fov = 0.5 * options.fov_deg * kPi / 180.0;
  ViewCamera camera;
  camera.eye = centre + towards_eye * (radius / std::sin(half_fov) * 1.05);
  camera.forward = -towards_eye;
  camera.right = camera.forward.cross(up).normalized();
  camera.down = camera.forward.cross(camera.right);
  camera.focal = 0.5 * std::min(options.width, options.height) / std::tan(half_fov);
  camera.cx = 0.5 * options.width;
  camera.cy = 0.5 * options.height;
  return camera;
}

// Centre and radius of the points' bounding sphere (from the box).
void Bounds(const std::vector<Eigen::Vector3d>& points, Eigen::Vector3d* centre, double* radius) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::max());
  Eigen::Vector3d hi = -lo;
  for (const auto& p : points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  *centre = 0.5 * (lo + hi);
  *radius = std::max(1e-6, 0.5 * (hi - lo).norm());
}

cv::Vec3b Shade(const Eigen::Vector3d& rgb, double lambert) {
  const double light = 0.25 + 0.75 * std::clamp(lambert, 0.0, 1.0);
  auto channel = [&](double c) {
    return static_cast<uchar>(std::clamp(c * light * 255.0 + 0.5, 0.0, 255.0));
  };
  return {channel(rgb.z()), channel(rgb.y()), channel(rgb.x())};  // BGR
}

}  // namespace

Status PreviewOptions::Check() const {
  if (width < 16 || height < 16 || width > 8192 || height > 8192) {
    return InvalidArgumentError("preview size must be 16..8192 pixels a side");
  }
  if (!(fov_deg > 1 && fov_deg < 150)) return InvalidArgumentError("preview fov_deg must be in (1, 150)");
  if (!(up.norm() > 0)) return InvalidArgumentError("preview up vector must be non-zero");
  return Status::Ok();
}

Result<cv::Mat> RenderPreview(const TriangleMesh& mesh, const PreviewOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  if (mesh.vertices.empty() || mesh.triangles.empty())
    return InvalidArgumentError("cannot preview an empty mesh");
  const bool colored = mesh.vertex_colors.size() == mesh.vertices.size();
  Eigen::Vector3d centre;
  double radius;
  Bounds(mesh.vertices, &centre, &radius);
  const ViewCamera camera = MakeCamera(centre, radius, options);

  std::vector<Eigen::Vector3d> projected(mesh.vertices.size());  // u, v, depth
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Eigen::Vector3d c = camera.ToCamera(mesh.vertices[i]);
    projected[i] = {camera.focal * c.x() / c.z() + camera.cx, camera.focal * c.y() / c.z() + camera.cy,
                    c.z()};
  }
  cv::Mat image(options.height, options.width, CV_8UC3,
                cv::Scalar(kBackground[0], kBackground[1], kBackground[2]));
  std::vector<float> depth(static_cast<std::size_t>(options.width) * options.height,
                           std::numeric_limits<float>::max());
  const int n_vertices = static_cast<int>(mesh.vertices.size());
  for (const Eigen::Vector3i& t : mesh.triangles) {
    if ((t.array() < 0).any() || (t.array() >= n_vertices).any()) {
      return InvalidArgumentError("mesh triangle indexes a vertex that does not exist");
    }
    const Eigen::Vector3d &a = projected[t[0]], &b = projected[t[1]], &c = projected[t[2]];
    if (a.z() <= 0 || b.z() <= 0 || c.z() <= 0) continue;
    const double area = (b.x() - a.x()) * (c.y() - a.y()) - (c.x() - a.x()) * (b.y() - a.y());
    if (std::abs(area) < 1e-12) continue;
    const Eigen::Vector3d normal = (mesh.vertices[t[1]] - mesh.vertices[t[0]])
                                       .cross(mesh.vertices[t[2]] - mesh.vertices[t[0]])
                                       .normalized();
    const double lambert = std::abs(normal.dot(camera.forward));  // two-sided headlight
    const int x0 = std::max(0, static_cast<int>(std::floor(std::min({a.x(), b.x(), c.x()}))));
    const int x1 = std::min(options.width - 1, static_cast<int>(std::ceil(std::max({a.x(), b.x(), c.x()}))));
    const int y0 = std::max(0, static_cast<int>(std::floor(std::min({a.y(), b.y(), c.y()}))));
    const int y1 = std::min(options.height - 1, static_cast<int>(std::ceil(std::max({a.y(), b.y(), c.y()}))));
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        const double px = x + 0.5, py = y + 0.5;
        const double w0 = ((b.x() - px) * (c.y() - py) - (c.x() - px) * (b.y() - py)) / area;
        const double w1 = ((c.x() - px) * (a.y() - py) - (a.x() - px) * (c.y() - py)) / area;
        const double w2 = 1.0 - w0 - w1;
        if (w0 < 0 || w1 < 0 || w2 < 0) continue;
        const float z = static_cast<float>(w0 * a.z() + w1 * b.z() + w2 * c.z());
        float& stored = depth[static_cast<std::size_t>(y) * options.width + x];
        if (z >= stored) continue;
        stored = z;
        const Eigen::Vector3d rgb =
            colored ? Eigen::Vector3d(w0 * mesh.vertex_colors[t[0]] + w1 * mesh.vertex_colors[t[1]] +
                                      w2 * mesh.vertex_colors[t[2]])
                    : Eigen::Vector3d(0.8, 0.8, 0.8);
        image.at<cv::Vec3b>(y, x) = Shade(rgb, lambert);
      }
    }
  }
  return image;
}

Result<cv::Mat> RenderPointPreview(const ColoredPoints& cloud, const PreviewOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  if (cloud.points.empty()) return InvalidArgumentError("cannot preview an empty point cloud");
  const bool colored = cloud.colors.size() == cloud.points.size();
  const bool has_normals = cloud.normals.size() == cloud.points.size();
  Eigen::Vector3d centre;
  double radius;
  Bounds(cloud.points, &centre, &radius);
  const ViewCamera camera = MakeCamera(centre, radius, options);
  cv::Mat image(options.height, options.width, CV_8UC3,
                cv::Scalar(kBackground[0], kBackground[1], kBackground[2]));
  std::vector<float> depth(static_cast<std::size_t>(options.width) * options.height,
                           std::numeric_limits<float>::max());
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    const Eigen::Vector3d c = camera.ToCamera(cloud.points[i]);
    if (c.z() <= 0) continue;
    const int x = static_cast<int>(std::floor(camera.focal * c.x() / c.z() + camera.cx));
    const int y = static_cast<int>(std::floor(camera.focal * c.y() / c.z() + camera.cy));
    if (x < 0 || y < 0 || x >= options.width || y >= options.height) continue;
    float& stored = depth[static_cast<std::size_t>(y) * options.width + x];
    if (static_cast<float>(c.z()) >= stored) continue;
    stored = static_cast<float>(c.z());
    const double lambert = has_normals ? std::abs(cloud.normals[i].dot(camera.forward)) : 1.0;
    image.at<cv::Vec3b>(y, x) = Shade(colored ? cloud.colors[i] : Eigen::Vector3d(0.8, 0.8, 0.8), lambert);
  }
  return image;
}

namespace {

template <typename Render>
Result<cv::Mat> Sheet(const PreviewOptions& options, Render render) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  struct View {
    const char* name;
    double azimuth, elevation;
  };
  const View views[4] = {{"front", options.azimuth_deg, options.elevation_deg},
                         {"side", options.azimuth_deg + 90, options.elevation_deg},
                         {"back", options.azimuth_deg + 180, options.elevation_deg},
                         {"top", options.azimuth_deg, 89.0}};
  cv::Mat sheet(2 * options.height, 2 * options.width, CV_8UC3);
  for (int i = 0; i < 4; ++i) {
    PreviewOptions one = options;
    one.azimuth_deg = views[i].azimuth;
    one.elevation_deg = views[i].elevation;
    Result<cv::Mat> image = render(one);
    if (!image.ok()) return image.status();
    cv::putText(*image, views[i].name, cv::Point(8, 24), cv::FONT_HERSHEY_SIMPLEX, 0.7, cv::Scalar(220, 220, 220),
                1, cv::LINE_AA);
    image->copyTo(sheet(cv::Rect((i % 2) * options.width, (i / 2) * options.height, options.width, options.height)));
  }
  return sheet;
}

}  // namespace

Result<cv::Mat> RenderPreviewSheet(const TriangleMesh& mesh, const PreviewOptions& options) {
  return Sheet(options, [&](const PreviewOptions& one) { return RenderPreview(mesh, one); });
}

Result<cv::Mat> RenderPointPreviewSheet(const ColoredPoints& cloud, const PreviewOptions& options) {
  return Sheet(options, [&](const PreviewOptions& one) { return RenderPointPreview(cloud, one); });
}

Result<std::string> EncodePng(const cv::Mat& image, const std::string& name) {
  if (image.empty()) return InvalidArgumentError("refusing to write an empty image to " + name);
  std::vector<uchar> bytes;
  try {
    if (!cv::imencode(".png", image, bytes)) return InternalError("PNG encoding failed");
  } catch (const cv::Exception& e) {
    return InvalidArgumentError("cannot encode " + name + " as PNG: " + e.msg);
  }
  return std::string(bytes.begin(), bytes.end());
}

Result<PendingFile> PngFile(const std::filesystem::path& path, const cv::Mat& image) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::string bytes, EncodePng(image, path.string()));
  return FileWithContent(path, std::move(bytes));
}

Status WritePng(const std::filesystem::path& path, const cv::Mat& image) {
  ROTOSCAN_ASSIGN_OR_RETURN(PendingFile file, PngFile(path, image));
  return WriteFilesTogether({file});
}

}  // namespace rotoscan::mesh
