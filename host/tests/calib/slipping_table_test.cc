// Issue 15, "calibration on real captures": a real sweep (JPEG frames) was calibrated well but its report
// failed it, reprojection 1.05 px with 15 views over 1 px, where the real table had stepped 2.9 or 4.05
// degrees for a commanded 3.6. Here the virtual scanner renders the demo's three table-checkerboard
// placements (data/scenes/calibration*.json) on a table that slips (every true angle up to +-kSlipDeg
// off the commanded one, uniform; bundle.json keeps the commanded angle, truth/table_angles.csv the true
// one), every frame goes through JPEG at a webcam's quality (encoded and decoded here, before detection),
// and `rotoscan calibrate`'s observations are calibrated twice: with each view's table angle refined
// (commanded angles as priors; the default) and with the commanded angles held fixed (the old behaviour).
// Shown against the truth: the refined angles, the calibration within DESIGN.md's targets, the pixel
// figures within the report's limits and the predicted error of a scanned point consistent with the true
// errors (the report still asks for more views: see below); the fixed-angle calibration measurably worse.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/calib/rig_calibration.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/pipeline/calibrate.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"
#include "rig_errors.h"
#include "testing/testing.h"

namespace rotoscan::pipeline {
namespace {

using rotoscan::testing::DataPath;
using rotoscan::testing::ScratchDir;

// Table angles per placement (over 120 degrees). With 10 (26 views found) the rig was as close to the truth
// (axis 0.007 mm), with the axis position's standard deviation 0.083 mm and a scanned point's predicted
// error 0.108 mm; the demo's capture has 24.
constexpr int kSteps = 16;
constexpr double kSlipDeg = 0.5;  // largest deviation of a true table angle from the commanded one
constexpr int kJpegQuality = 80;  // a webcam's MJPEG (the C270 streams 1280x960 as MJPEG only)

using rotoscan::testing::AxisAngleDeg;
using rotoscan::testing::AxisDistanceMm;
using rotoscan::testing::NormalErrorDeg;
using rotoscan::testing::OffsetErrorMm;

// Every frame of the bundle through JPEG and back, written over the PNG (lossless storage of a lossy
// frame, as a capture of an MJPEG camera stores it).
void JpegRoundTrip(const std::filesystem::path& directory) {
  Result<bundle::Bundle> b = bundle::ReadBundle(directory);
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  for (const bundle::FrameRecord& frame : b->frames) {
    const std::string path = b->FramePath(frame).string();
    const cv::Mat image = cv::imread(path, cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(image.empty()) << path;
    ASSERT_EQ(image.depth(), CV_8U) << path;
    std::vector<uchar> jpeg;
    ASSERT_TRUE(cv::imencode(".jpg", image, jpeg, {cv::IMWRITE_JPEG_QUALITY, kJpegQuality}));
    const cv::Mat decoded = cv::imdecode(jpeg, cv::IMREAD_UNCHANGED);
    ASSERT_EQ(decoded.size(), image.size());
    ASSERT_TRUE(cv::imwrite(path, decoded)) << path;
  }
}

struct Errors {
  double fx_percent, normal_deg[2], offset_mm[2], axis_mm, axis_deg;
};
Errors ErrorsOf(const geometry::Rig& rig, const geometry::Rig& truth) {
  Errors e{};
  e.fx_percent = 100.0 * std::abs(rig.camera.fx / truth.camera.fx - 1.0);
  for (int l = 0; l < 2; ++l) {
    e.normal_deg[l] = NormalErrorDeg(rig.laser_plane[l], truth.laser_plane[l]);
    e.offset_mm[l] = OffsetErrorMm(rig.laser_plane[l], truth.laser_plane[l]);
  }
  e.axis_mm = AxisDistanceMm(rig, truth);
  e.axis_deg = AxisAngleDeg(rig, truth);
  return e;
}
// Renders the demo's three board placements on a table that slips by up to kSlipDeg (in `mode`), every frame
// through JPEG; appends each bundle and its true table angles.
void RenderSlippingTable(const ScratchDir& dir, int steps, sim::SlipMode mode,
                         std::vector<std::filesystem::path>* bundles,
                         std::vector<std::vector<bundle::TableAngle>>* angles) {
  for (const char* name : {"calibration.json", "calibration-2.json", "calibration-3.json"}) {
    Result<sim::Scene> scene = sim::LoadScene(DataPath(std::string("scenes/") + name));
    ASSERT_TRUE(scene.ok()) << scene.status().ToString();
    sim::SimulateOptions options;
    options.out = dir / name;
    options.kind = sim::SimulateKind::kTableCheckerboard;
    options.steps = steps;
    options.table_slip_deg = kSlipDeg;
    options.table_slip_mode = mode;
    const Status simulated = sim::Simulate(*scene, options, nullptr);
    ASSERT_TRUE(simulated.ok()) << simulated.ToString();
    ASSERT_NO_FATAL_FAILURE(JpegRoundTrip(options.out));
    Result<std::vector<bundle::TableAngle>> truth =
        bundle::ReadTableAngles(bundle::TruthTableAnglesPath(options.out));
    ASSERT_TRUE(truth.ok()) << truth.status().ToString();
    angles->push_back(*truth);
    bundles->push_back(options.out);
  }
}

// The refined table angles against the true ones, in degrees. Each placement's pose takes up the mean of
// its slips (the views fix the angles only relative to the placement's pose at angle 0), so both are
// compared after removing their mean per placement. Also checks that bundle.json gave the commanded angles.
struct AngleErrors {
  double worst_deg = 0.0;
  double rms_deg = 0.0;
};
void RefinedAnglesAgainstTruth(const calib::CalibrationData& data, const calib::RigEstimate& estimate,
                               const std::vector<std::vector<bundle::TableAngle>>& angles, AngleErrors* out) {
  double sum_sq = 0.0;
  int count = 0;
  for (int p = 0; p < static_cast<int>(angles.size()); ++p) {
    std::vector<double> est, tru;
    for (const calib::TargetView& view : data.target_views) {
      if (view.placement != p) continue;
      const auto it = std::find_if(angles[p].begin(), angles[p].end(),
                                   [&](const bundle::TableAngle& a) { return a.step == view.step; });
      ASSERT_NE(it, angles[p].end()) << view.name;
      ASSERT_NEAR(it->commanded_rad, view.table_angle_rad, 1e-9) << view.name;  // bundle.json: commanded
      est.push_back(estimate.TableAngle(p, view.step, view.table_angle_rad));
      tru.push_back(it->true_rad);
    }
    ASSERT_GE(est.size(), 3u) << "placement " << p;
    double est_mean = 0.0, tru_mean = 0.0;
    for (std::size_t i = 0; i < est.size(); ++i) {
      est_mean += est[i] / static_cast<double>(est.size());
      tru_mean += tru[i] / static_cast<double>(tru.size());
    }
    for (std::size_t i = 0; i < est.size(); ++i) {
      const double error_deg = geometry::RadToDeg(std::abs((est[i] - est_mean) - (tru[i] - tru_mean)));
      out->worst_deg = std::max(out->worst_deg, error_deg);
      sum_sq += error_deg * error_deg;
      ++count;
    }
  }
  out->rms_deg = std::sqrt(sum_sq / count);
}

void Print(const char* what, const calib::RigCalibrationSummary& s, const Errors& e) {
  std::printf(
      "%s: reprojection %.3f px, views over 1 px %d, predicted point error %.4f mm (max %.4f) at "
      "%.0f mm, %s; vs truth: fx %.4f %%, normals %.4f / %.4f deg, offsets %.4f / %.4f mm, axis "
      "%.4f mm %.4f deg\n",
      what, s.rms_px,
      static_cast<int>(std::count_if(s.per_view.begin(), s.per_view.end(),
                                     [](const calib::ViewResidual& v) { return v.rms_px > 1.0; })),
      s.point_std_mm, s.point_std_max_mm, s.working_distance_mm, s.passed ? "passed" : "failed", e.fx_percent,
      e.normal_deg[0], e.normal_deg[1], e.offset_mm[0], e.offset_mm[1], e.axis_mm, e.axis_deg);
  for (const auto& f : s.failures) std::printf("  failure: %s\n", f.c_str());
  for (const auto& n : s.notes) {
    if (n.rfind("view ", 0) != 0) std::printf("  note: %s\n", n.c_str());
  }
}

// One test (rendering is most of its time, and ctest runs each test in its own process).
// Opt-in: about 2 minutes on 2 busy cores (rendering 192 frames at 1288x964 is most of it); the synthetic
// variant (calib_test, RigCalibrationTest.RefinedTableAnglesRecoverASlippingTable) runs by default.
TEST(SlippingTableTest, RefinedTableAnglesRecoverTheSlipAndTheReportJudgesTheScannedPointError) {
  if (std::getenv("ROTOSCAN_CALIB_RENDERED") == nullptr)
    GTEST_SKIP() << "set ROTOSCAN_CALIB_RENDERED=1 to run";
  ScratchDir dir;
  std::vector<std::filesystem::path> bundles;
  std::vector<std::vector<bundle::TableAngle>> angles;
  ASSERT_NO_FATAL_FAILURE(RenderSlippingTable(dir, kSteps, sim::SlipMode::kIndependent, &bundles, &angles));
  Result<geometry::Rig> truth_rig = geometry::ReadRigYaml(bundle::TruthRigPath(bundles[0]));
  ASSERT_TRUE(truth_rig.ok()) << truth_rig.status().ToString();
  const geometry::Rig& truth = *truth_rig;
  Result<calib::CalibrationData> observed = ObservationsFromBundles(bundles, nullptr);
  ASSERT_TRUE(observed.ok()) << observed.status().ToString();
  const calib::CalibrationData& data = *observed;
  ASSERT_GE(data.target_views.size(), 3u * kSteps - 10u);
  // Every placement was seen (so placement p is bundle p), and the table did slip.
  std::set<int> placements;
  for (const auto& v : data.target_views) placements.insert(v.placement);
  ASSERT_EQ(placements.size(), 3u);
  double largest_slip = 0.0;
  for (const auto& list : angles) {
    for (const auto& a : list) largest_slip = std::max(largest_slip, std::abs(a.true_rad - a.commanded_rad));
  }
  EXPECT_GT(geometry::RadToDeg(largest_slip), 0.6 * kSlipDeg);

  const calib::RigCalibrationOptions refined_options;  // table angles refined (the default)
  ASSERT_TRUE(refined_options.refine_table_angles);
  calib::RigCalibrationOptions fixed_options;
  fixed_options.refine_table_angles = false;
  const auto initial = calib::CalibrateThreeStep(data, refined_options);
  ASSERT_TRUE(initial.ok()) << initial.status().ToString();
  const auto refined = calib::RefineRig(data, *initial, refined_options);
  ASSERT_TRUE(refined.ok()) << refined.status().ToString();
  const auto fixed = calib::RefineRig(data, *initial, fixed_options);
  ASSERT_TRUE(fixed.ok()) << fixed.status().ToString();
  const calib::RigCalibrationSummary& s = refined->summary;
  const calib::RigCalibrationSummary& f = fixed->summary;
  const Errors er = ErrorsOf(refined->estimate.rig, truth), ef = ErrorsOf(fixed->estimate.rig, truth);
  Print("angles refined", s, er);
  Print("angles fixed  ", f, ef);

  AngleErrors angle_errors;
  ASSERT_NO_FATAL_FAILURE(RefinedAnglesAgainstTruth(data, refined->estimate, angles, &angle_errors));
  std::printf("refined table angles vs truth: RMS %.4f deg, worst %.4f deg (slips up to %.3f deg)\n",
              angle_errors.rms_deg, angle_errors.worst_deg, geometry::RadToDeg(largest_slip));
  EXPECT_LT(angle_errors.worst_deg, 0.02);  // measured 0.004 (16 angles) and 0.011 (10)

  // The calibration within DESIGN.md's targets, its pixel figures within the report's limits (as on the
  // real sweep once its slips are modelled). The report itself does not pass this capture: JPEG doubles
  // the corner noise (0.106 px RMS against 0.053 px for the same capture from PNG without slip,
  // rendered_calibration_test, whose axis position has a standard deviation of 0.032 mm with the angles
  // refined as here), so the axis position is known to 0.056 mm and a scanned point's predicted error is
  // 0.073 mm against the 0.05 mm limit: the report asks for more views. Bound it so that a regression
  // shows, and check that it is the honest figure: the true error of the axis within 2 of its standard
  // deviations.
  EXPECT_TRUE(s.converged) << s.termination;
  EXPECT_TRUE(s.table_angles_refined);
  EXPECT_LT(s.point_std_mm, 0.1);
  EXPECT_LT(er.axis_mm, 2.0 * s.std_devs.axis_point_mm);
  EXPECT_LT(s.rms_px, refined_options.max_rms_px);
  for (const auto& v : s.per_view) EXPECT_LT(v.rms_px, refined_options.max_view_rms_px) << v.name;
  EXPECT_LT(er.fx_percent, 0.1);
  for (int l = 0; l < 2; ++l) {
    EXPECT_LT(er.normal_deg[l], 0.05) << l;
    EXPECT_LT(er.offset_mm[l], 0.05) << l;
  }
  EXPECT_LT(er.axis_mm, 0.05);
  EXPECT_LT(er.axis_deg, 0.05);

  // The old behaviour (commanded angles as truths) is measurably worse: the slips stay in the residuals
  // (views over 1 px, as on the real sweep), the covariance scaled by them fails the report, and the rig
  // is further from the truth.
  EXPECT_GT(f.rms_px, 3.0 * s.rms_px);
  EXPECT_FALSE(f.passed);
  EXPECT_GT(f.point_std_mm, 4.0 * s.point_std_mm);
  EXPECT_GT(ef.axis_mm, 4.0 * er.axis_mm);
  EXPECT_GT(ef.axis_mm + ef.offset_mm[0] + ef.offset_mm[1], er.axis_mm + er.offset_mm[0] + er.offset_mm[1]);
}

// A table whose lost steps accumulate (`simulate --table-slip-mode cumulative`: each move off by up to
// 0.5 degree, the true angle drifting from the commanded one without coming back), JPEG frames, calibrated
// with the prior on each move (TableAnglePrior::kIncrements). By default a short set (3 placements x 7
// angles over 120 degrees, ~20 s); ROTOSCAN_CALIB_RENDERED=1 renders 16 angles per placement.
TEST(SlippingTableTest, CumulativeSlipRefinedWithAPriorOnEachMove) {
  const bool full = std::getenv("ROTOSCAN_CALIB_RENDERED") != nullptr;
  const int steps = full ? kSteps : 7;
  ScratchDir dir;
  std::vector<std::filesystem::path> bundles;
  std::vector<std::vector<bundle::TableAngle>> angles;
  ASSERT_NO_FATAL_FAILURE(RenderSlippingTable(dir, steps, sim::SlipMode::kCumulative, &bundles, &angles));
  Result<geometry::Rig> truth_rig = geometry::ReadRigYaml(bundle::TruthRigPath(bundles[0]));
  ASSERT_TRUE(truth_rig.ok()) << truth_rig.status().ToString();
  Result<calib::CalibrationData> observed = ObservationsFromBundles(bundles, nullptr);
  ASSERT_TRUE(observed.ok()) << observed.status().ToString();
  const calib::CalibrationData& data = *observed;
  // The truth is a drift: consecutive deviations differ by at most one move's slip, and the largest
  // deviation is beyond it.
  double largest = 0.0;
  for (const auto& list : angles) {
    for (std::size_t i = 0; i < list.size(); ++i) {
      const double d = list[i].true_rad - list[i].commanded_rad;
      largest = std::max(largest, std::abs(d));
      if (i > 0) {
        const double before = list[i - 1].true_rad - list[i - 1].commanded_rad;
        EXPECT_LE(std::abs(d - before), geometry::DegToRad(kSlipDeg) + 1e-12);
      }
    }
  }
  calib::RigCalibrationOptions options;
  options.table_angle_prior = calib::RigCalibrationOptions::TableAnglePrior::kIncrements;
  const auto initial = calib::CalibrateThreeStep(data, options);
  ASSERT_TRUE(initial.ok()) << initial.status().ToString();
  const auto refined = calib::RefineRig(data, *initial, options);
  ASSERT_TRUE(refined.ok()) << refined.status().ToString();
  const Errors e = ErrorsOf(refined->estimate.rig, *truth_rig);
  Print("cumulative slip, prior on each move", refined->summary, e);
  AngleErrors angle_errors;
  ASSERT_NO_FATAL_FAILURE(RefinedAnglesAgainstTruth(data, refined->estimate, angles, &angle_errors));
  std::printf("%zu views; true drift up to %.3f deg; refined angles vs truth: worst %.4f deg; step scale %+.4f %%\n",
              data.target_views.size(), geometry::RadToDeg(largest), angle_errors.worst_deg,
              100.0 * (refined->estimate.rig.step_angle_rad / truth_rig->step_angle_rad - 1.0));
  EXPECT_GT(geometry::RadToDeg(largest), kSlipDeg);
  EXPECT_LT(angle_errors.worst_deg, 0.02);
  EXPECT_LT(e.fx_percent, 0.1);
  for (int l = 0; l < 2; ++l) {
    EXPECT_LT(e.normal_deg[l], 0.05) << l;
    EXPECT_LT(e.offset_mm[l], 0.05) << l;
  }
  EXPECT_LT(e.axis_mm, 0.1);
  EXPECT_LT(e.axis_deg, 0.05);
  EXPECT_LT(refined->summary.rms_px, options.max_rms_px);
}

}  // namespace
}  // namespace rotoscan::pipeline
