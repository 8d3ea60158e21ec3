// Projects a few points through a camera with lens distortion and back, using the installed librotoscan.
// Exits non-zero if the round trip is off by more than 1e-6 px (so the install test can fail).
#include <cmath>
#include <cstdio>

#include <rotoscan/core/status.h>
#include <rotoscan/core/version.h>
#include <rotoscan/geometry/camera.h>

int main() {
  rotoscan::geometry::CameraModel camera = rotoscan::geometry::CameraModel::FromFieldOfView(1288, 964, 20.0);
  camera.distortion = {-0.08, 0.02, 0.0005, -0.0003, 0.0};
  if (rotoscan::Status status = camera.Validate(); !status.ok()) {
    std::fprintf(stderr, "%s\n", status.ToString().c_str());
    return 1;
  }
  std::printf("librotoscan %s, fx = %.2f px\n", ROTOSCAN_VERSION_STRING, camera.fx);
  double worst = 0.0;
  for (double x = -40; x <= 40; x += 20) {
    for (double y = -30; y <= 30; y += 15) {
      const Eigen::Vector3d point_in_cam(x, y, 300.0);
      const Eigen::Vector2d pixel = camera.Project(point_in_cam);
      const Eigen::Vector3d ray = camera.PixelToRay(pixel);
      const Eigen::Vector2d back = camera.Project(ray * 300.0);
      worst = std::fmax(worst, (back - pixel).norm());
    }
  }
  std::printf("worst round-trip error %.3g px\n", worst);
  return worst < 1e-6 ? 0 : 1;
}
