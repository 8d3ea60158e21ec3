// Issue 15, "scans without laser-off frames": some rigs capture laser-on frames in the dark only (FabScanPi
// by default). A rendered scan of a sphere in a dark room (no lamp, no ambient light: the laser frames hold
// the laser and the sensor's noise), processed with the true rig as captured (left, right, off, natural) and
// then with its laser-off frames removed from bundle.json and the disk: zero background, and a dark frame
// (one laser-off frame given as --dark-frame would give it). The distance to the true surface stays within
// kToleranceMm of the normal case's, and the summary warns. The same under the default lamp: the dark frame
// keeps that tolerance; a zero background does not (kLitZeroToleranceMm).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/core/file.h"
#include "rotoscan/pipeline/evaluate.h"
#include "rotoscan/pipeline/process.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"
#include "testing/testing.h"

namespace rotoscan::pipeline {
namespace {

// The distance to the surface may grow by this much without the laser-off frames (RMS, mm): the normal
// case is ~0.01 mm on this scene; the extraction then sees the same line over a background of sensor noise
// with a positive mean instead of a zero-mean difference.
constexpr double kToleranceMm = 0.005;
// Under the lamp a zero background takes its light for laser: a few stray points (measured: RMS 0.045 mm
// against 0.011 mm with the laser-off frames, p95 0.025 against 0.021); a dark frame (the lamp on, the
// lasers off) removes it again.
constexpr double kLitZeroToleranceMm = 0.05;

// A 320x240 crop of the default camera (same pixel footprint) and a sphere, in the dark; and the same
// lit by the default lamp (the laser frames then hold a few DN of lamp light, which a zero background
// takes for laser).
constexpr const char* kScene =
    "{\"seed\": 5, \"steps\": 6, \"camera\": {\"width\": 320, \"height\": 240, \"hfov_deg\": 4.97}, "
    "\"light\": {\"ambient\": 0, \"diffuse\": 0}, "
    "\"objects\": [{\"type\": \"sphere\", \"radius_mm\": 25}]}";
constexpr const char* kLitScene =
    "{\"seed\": 5, \"steps\": 6, \"camera\": {\"width\": 320, \"height\": 240, \"hfov_deg\": 4.97}, "
    "\"objects\": [{\"type\": \"sphere\", \"radius_mm\": 25}]}";

struct Measured {
  ProcessSummary summary;
  DistanceStats distance;
};

Measured ProcessAndEvaluate(const std::filesystem::path& bundle_dir, const ProcessOptions& options) {
  Measured out;
  Result<geometry::Rig> rig = geometry::ReadRigYaml(bundle::TruthRigPath(bundle_dir));
  EXPECT_TRUE(rig.ok()) << rig.status().ToString();
  if (!rig.ok()) return out;
  Result<ProcessResult> processed = ProcessBundle(bundle_dir, *rig, options);
  EXPECT_TRUE(processed.ok()) << processed.status().ToString();
  if (!processed.ok()) return out;
  out.summary = processed->summary;
  Result<TruthSurface> truth = LoadTruthSurface(bundle_dir);
  Result<EvaluationViews> views = LoadEvaluationViews(bundle_dir);
  EXPECT_TRUE(truth.ok() && views.ok());
  if (!truth.ok() || !views.ok()) return out;
  EvaluateOptions evaluate;
  evaluate.sample_spacing_mm = 1.0;  // the distance is exact; coverage is not looked at here
  Result<EvaluationReport> report = EvaluateCloud(processed->cloud, *truth, *views, evaluate);
  EXPECT_TRUE(report.ok()) << report.status().ToString();
  if (report.ok()) out.distance = report->distance;
  return out;
}

class NoOffFramesTest : public ::testing::TestWithParam<bool> {};  // lamp on

TEST_P(NoOffFramesTest, ScanWithoutLaserOffFramesIsProcessedWithAWarning) {
  const bool lit = GetParam();
  rotoscan::testing::ScratchDir dir;
  Result<sim::Scene> scene = sim::ParseScene(lit ? kLitScene : kScene, dir.path(), "sphere");
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  sim::SimulateOptions simulate;
  simulate.out = dir / "scan";
  ASSERT_TRUE(sim::Simulate(*scene, simulate, nullptr).ok());
  ProcessOptions options;
  options.merge = false;  // keep every point of both lasers
  const Measured normal = ProcessAndEvaluate(simulate.out, options);
  ASSERT_GT(normal.distance.points, 500u);
  EXPECT_EQ(normal.summary.background_steps, 0);

  // The same capture without its laser-off frames; one of them is kept aside as a dark frame.
  Result<bundle::Bundle> b = bundle::ReadBundle(simulate.out);
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  Result<cv::Mat> dark =
      bundle::ReadFrame(*b, static_cast<std::size_t>(b->FindFrame(0, bundle::LaserState::kOff)));
  ASSERT_TRUE(dark.ok()) << dark.status().ToString();
  std::vector<bundle::FrameRecord> kept;
  for (const bundle::FrameRecord& f : b->frames) {
    if (f.laser != bundle::LaserState::kOff) {
      kept.push_back(f);
    } else {
      std::filesystem::remove(b->FramePath(f));
    }
  }
  ASSERT_EQ(kept.size(), b->frames.size() * 3 / 4);
  ASSERT_TRUE(WriteFileAtomically(simulate.out / "bundle.json", bundle::BundleJson(b->header, kept)).ok());

  const Measured zero = ProcessAndEvaluate(simulate.out, options);
  ProcessOptions with_dark = options;
  with_dark.dark_frame = *dark;
  const Measured dark_frame = ProcessAndEvaluate(simulate.out, with_dark);
  std::printf(
      "sphere %s, distance to the true surface: with laser-off frames %zu points, RMS %.4f "
      "mm (p95 %.4f); without, zero background %zu points, RMS %.4f mm (p95 %.4f); dark frame %zu "
      "points, RMS %.4f mm (p95 %.4f)\n",
      lit ? "under the lamp" : "in the dark", normal.distance.points, normal.distance.rms_mm,
      normal.distance.p95_mm, zero.distance.points, zero.distance.rms_mm, zero.distance.p95_mm,
      dark_frame.distance.points, dark_frame.distance.rms_mm, dark_frame.distance.p95_mm);
  for (const Measured* m : {&zero, &dark_frame}) {
    EXPECT_EQ(m->summary.processed_steps, normal.summary.processed_steps);
    EXPECT_EQ(m->summary.skipped_steps, 0);
    EXPECT_EQ(m->summary.background_steps, normal.summary.processed_steps);
    ASSERT_FALSE(m->summary.warnings.empty());
    EXPECT_NE(m->summary.warnings[0].find("no laser-off frame"), std::string::npos) << m->summary.warnings[0];
    EXPECT_GT(m->distance.points, normal.distance.points * 95 / 100);
    EXPECT_LT(m->distance.rms_mm,
              normal.distance.rms_mm + (lit && m == &zero ? kLitZeroToleranceMm : kToleranceMm));
  }
  EXPECT_NE(zero.summary.warnings[0].find("zero background"), std::string::npos) << zero.summary.warnings[0];
  EXPECT_NE(dark_frame.summary.warnings[0].find("dark frame"), std::string::npos);

  // A dark frame of another size is refused, naming both sizes.
  ProcessOptions wrong = options;
  wrong.dark_frame = cv::Mat::zeros(10, 20, CV_8UC3);
  Result<geometry::Rig> rig = geometry::ReadRigYaml(bundle::TruthRigPath(simulate.out));
  ASSERT_TRUE(rig.ok());
  const Result<ProcessResult> refused = ProcessBundle(simulate.out, *rig, wrong);
  EXPECT_EQ(refused.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(refused.status().message().find("20x10"), std::string::npos) << refused.status().message();
}

INSTANTIATE_TEST_SUITE_P(DarkAndLit, NoOffFramesTest, ::testing::Bool());

}  // namespace
}  // namespace rotoscan::pipeline
