#include "rotoscan/pipeline/accuracy.h"

#include <cstdio>

#include <gtest/gtest.h>

#include "testing/testing.h"

namespace rotoscan::pipeline {
namespace {

TEST(AccuracyTest, CompareWithTruthCountsMatchesOutliersAndMisses) {
  laser::Line line;
  line.points = {
      {0, 10.1f, 100, 5, 1, 0}, {1, 10.0f, 100, 5, 1, 0}, {2, 30.0f, 100, 5, 1, 0}, {3, 12.0f, 100, 5, 1, 0}};
  std::vector<bundle::LinePoint> truth(4);
  truth[0].row = 0, truth[0].column = 10.0;
  truth[1].row = 1, truth[1].column = 10.2;
  truth[2].row = 1, truth[2].column = 50.0;  // a second crossing in row 1: the nearest counts
  truth[3].row = 2, truth[3].column = 20.0;  // 10 px away: outlier
  // row 3 has no truth: spurious; no truth row is missed... add one
  truth.push_back({});
  truth[4].row = 5, truth[4].column = 1.0;
  const LineAccuracy a = CompareWithTruth(line, truth, 2.0);
  EXPECT_EQ(a.truth_rows, 4u);
  EXPECT_EQ(a.matched, 2u);
  EXPECT_EQ(a.outliers, 1u);
  EXPECT_EQ(a.spurious, 1u);
  EXPECT_EQ(a.missed, 1u);
  EXPECT_NEAR(a.mean_px(), (0.1 - 0.2) / 2, 1e-6);
  EXPECT_NEAR(a.rms_px(), std::sqrt((0.01 + 0.04) / 2), 1e-6);
}

// Rows split by what the true line lies on: a row crossed by an object's line is the object's (even where
// the table's line crosses it too), one crossed by the table's line alone is the table's; the two add up.
TEST(AccuracyTest, CompareWithTruthByPartSplitsObjectAndTableRows) {
  std::vector<bundle::LinePoint> truth(5);
  truth[0].row = 0, truth[0].column = 10.0, truth[0].object = 1;
  truth[1].row = 1, truth[1].column = 10.0, truth[1].object = 1;
  truth[2].row = 1, truth[2].column = 80.0, truth[2].object = 0;  // both lines in row 1: the object's row
  truth[3].row = 2, truth[3].column = 90.0, truth[3].object = 0;
  truth[4].row = 3, truth[4].column = 95.0, truth[4].object = 0;  // not found
  laser::Line line;
  // Row 1's point lies on the table's line: still the object's row, matched to the nearest crossing.
  line.points = {{0, 10.5f, 100, 5, 1, 0}, {1, 80.2f, 100, 5, 1, 0}, {2, 95.0f, 100, 5, 1, 0}};
  const LineAccuracyParts p = CompareWithTruthByPart(line, truth, 2.0);
  EXPECT_EQ(p.all.truth_rows, 4u);
  EXPECT_EQ(p.object.truth_rows, 2u);
  EXPECT_EQ(p.table.truth_rows, 2u);
  EXPECT_EQ(p.object.missed, 0u);
  EXPECT_EQ(p.table.missed, 1u);
  EXPECT_EQ(p.all.missed, 1u);
  EXPECT_EQ(p.object.matched, 2u);
  EXPECT_NEAR(p.object.rms_px(), std::sqrt((0.25 + 0.04) / 2), 1e-6);
  EXPECT_EQ(p.table.outliers, 1u);  // row 2: 5 px off
  EXPECT_EQ(p.all.outliers, 1u);
  EXPECT_EQ(p.all.matched, 2u);
  const LineAccuracy all = CompareWithTruth(line, truth, 2.0);
  EXPECT_EQ(all.matched, p.all.matched);
  EXPECT_EQ(all.missed, p.all.missed);
}

// A steep true line (10 px per row): a point 5 px along its row from the truth lies 5 / sqrt(101) px from
// the line, and one on the line between two rows' crossings lies on it; across the line neither is an
// outlier, along the row the first is.
TEST(AccuracyTest, CompareWithTruthMeasuresAcrossASteepLine) {
  std::vector<bundle::LinePoint> truth;
  for (int row = 0; row < 10; ++row) {
    truth.emplace_back();
    truth.back().row = row;
    truth.back().column = 100.0 + 10.0 * row;
  }
  laser::Line line;
  line.points = {{4, 145.0f, 100, 5, 1, 0}, {6, 160.0f, 100, 5, 1, 0}};
  const LineAccuracy a = CompareWithTruth(line, truth, 2.0);
  EXPECT_EQ(a.outliers, 1u);  // the 5 px row error
  EXPECT_EQ(a.matched, 1u);
  EXPECT_EQ(a.across_outliers, 0u);
  ASSERT_EQ(a.across_matched, 2u);
  EXPECT_NEAR(a.across_rms_px(), std::sqrt((25.0 / 101.0 + 0.0) / 2), 1e-9);
  // Two lines far apart are not joined: a point between them is far from both.
  truth.emplace_back();
  truth.back().row = 20, truth.back().column = 100.0;
  truth.emplace_back();
  truth.back().row = 21, truth.back().column = 400.0;
  line.points = {{20, 250.0f, 100, 5, 1, 0}};
  const LineAccuracy b = CompareWithTruth(line, truth, 2.0);
  EXPECT_EQ(b.across_outliers, 1u);
}

// The virtual scanner (sim module) renders a plane 300 mm away; a 320x240 crop of the default camera
// (same pixel footprint: 5 degrees instead of 20) keeps the test fast.
constexpr const char* kSmallCamera = "\"camera\": {\"width\": 320, \"height\": 240, \"hfov_deg\": 4.97}";

TEST(AccuracyTest, PlaneOnTheVirtualScannerMeetsTheTarget) {
  rotoscan::testing::ScratchDir dir;
  auto a = RunPlaneAccuracy(300.0, dir.path(), 1, kSmallCamera);
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  std::printf("plane at 300 mm: %zu points, mean %.4f mm, rms %.4f mm\n", a->points, a->mean_mm, a->rms_mm);
  EXPECT_GT(a->points, 300u);
  EXPECT_LT(a->rms_mm, 0.05);  // DESIGN.md target at 300 mm
  EXPECT_LT(std::abs(a->mean_mm), 0.02);
  // The line centres of the same bundle against truth/lines. With the default speckle (contrast 0.15)
  // the error is ~0.19 px RMS at full size, above the 0.1 px target: speckle deforms the profile itself
  // (without speckle it is 0.025 px, see the next test). Bound it here so that a regression shows.
  auto lines = MeasureLineAccuracy(dir / "plane-300", laser::ExtractOptions{});
  ASSERT_TRUE(lines.ok()) << lines.status().ToString();
  std::printf("line centre with speckle: %zu matched, rms %.4f px\n", lines->matched, lines->rms_px());
  EXPECT_GT(lines->matched, 400u);
  EXPECT_EQ(lines->outliers, 0u);
  EXPECT_LT(lines->rms_px(), 0.3);
}

TEST(AccuracyTest, LineCentreWithoutSpeckleIsWithinTarget) {
  rotoscan::testing::ScratchDir dir;
  const std::string overrides =
      std::string(kSmallCamera) +
      ", \"lasers\": {\"left\": {\"speckle_contrast\": 0}, \"right\": {\"speckle_contrast\": 0}}";
  auto a = RunPlaneAccuracy(300.0, dir.path(), 1, overrides);
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  auto lines = MeasureLineAccuracy(dir / "plane-300", laser::ExtractOptions{});
  ASSERT_TRUE(lines.ok()) << lines.status().ToString();
  std::printf("line centre without speckle: %zu matched, rms %.4f px\n", lines->matched, lines->rms_px());
  EXPECT_GT(lines->matched, 400u);
  EXPECT_LT(lines->rms_px(), 0.1);  // DESIGN.md target
  EXPECT_EQ(MeasureLineAccuracy(dir / "nothing", laser::ExtractOptions{}).status().code(),
            StatusCode::kNotFound);
}

}  // namespace
}  // namespace rotoscan::pipeline
