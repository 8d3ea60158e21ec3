// The whole job with the installed librotoscan, public headers only: calibrate the rig from calibration
// bundles, process a scan bundle with that calibration, mesh the cloud, and print how far the mesh lies
// from the true surface (the scan must come from the virtual scanner, whose bundles carry truth/).
//   calibrate_and_scan SCAN_BUNDLE CALIBRATION_BUNDLE...
// Exits non-zero on any error (the install test runs it and checks the printed distance).
#include <cstdio>
#include <filesystem>
#include <vector>

#include <rotoscan/mesh/mesh.h>
#include <rotoscan/pipeline/calibrate.h>
#include <rotoscan/pipeline/evaluate.h>
#include <rotoscan/pipeline/process.h>

namespace {

int Fail(const char* what, const rotoscan::Status& status) {
  std::fprintf(stderr, "calibrate_and_scan: %s: %s\n", what, status.ToString().c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace rotoscan;
  if (argc < 3) {
    std::fprintf(stderr, "usage: calibrate_and_scan SCAN_BUNDLE CALIBRATION_BUNDLE...\n");
    return 2;
  }
  const std::filesystem::path scan = argv[1];
  const std::vector<std::filesystem::path> calibration_bundles(argv + 2, argv + argc);

  // 1. The rig (camera, both laser planes, table axis; mm, camera frame) from the calibration bundles.
  Result<pipeline::BundleCalibration> calibrated = pipeline::CalibrateFromBundles(calibration_bundles);
  if (!calibrated.ok()) return Fail("calibration", calibrated.status());
  const calib::RigCalibrationSummary& check = calibrated->calibration.summary;
  std::printf("calibration: %d views, reprojection %.3f px, predicted point error +-%.4f mm (%s)\n",
              check.target_views, check.rms_px, check.point_std_mm,
              check.passed ? "passed its checks" : "did not pass its checks");
  const geometry::Rig& rig = calibrated->calibration.estimate.rig;

  // 2. The scan processed with that rig: a colored point cloud in the table frame (mm).
  Result<pipeline::ProcessResult> processed = pipeline::ProcessBundle(scan, rig, pipeline::ProcessOptions{});
  if (!processed.ok()) return Fail("process", processed.status());
  std::printf("cloud: %zu points\n", processed->cloud.size());

  // 3. A surface by range-scan fusion.
  Result<mesh::TriangleMesh> surface =
      mesh::FuseSurface(mesh::ToColoredPoints(processed->cloud), mesh::FusionOptions{});
  if (!surface.ok()) return Fail("mesh", surface.status());
  std::printf("mesh: %zu vertices, %zu triangles\n", surface->vertices.size(), surface->triangles.size());

  // 4. The mesh's vertices against the true surface of the scanned object (truth/object.ply).
  Result<pipeline::TruthSurface> truth = pipeline::LoadTruthSurface(scan);
  if (!truth.ok()) return Fail("truth", truth.status());
  Result<pipeline::EvaluationViews> views = pipeline::LoadEvaluationViews(scan);
  if (!views.ok()) return Fail("truth", views.status());
  Result<pipeline::EvaluationReport> report =
      pipeline::EvaluateCloud(mesh::VerticesAsCloud(*surface), *truth, *views);
  if (!report.ok()) return Fail("evaluate", report.status());
  const pipeline::DistanceStats& d = report->distance;
  std::printf("distance to the truth: median %.4f mm, p95 %.4f mm, rms %.4f mm over %zu vertices\n",
              d.median_mm, d.p95_mm, d.rms_mm, d.points);
  return 0;
}
