// Line centre accuracy on frames rendered by the virtual scanner with its default noise and speckle,
// against the renderer's exact truth (truth/lines): the DESIGN.md target of 0.1 px RMS. The plane scene
// of the paper's Table 1 at 300 mm, full 1288x964 frames, one table step x 2 lasers (~2 s). Not a crop:
// with 480 rows the plane's line is short and a larger share of its points sit near the ends, where the
// smoothing window is one-sided (0.101 px measured on a 320x480 crop, 4 steps).
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "rotoscan/laser/extract.h"
#include "rotoscan/pipeline/accuracy.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"
#include "testing/testing.h"

namespace rotoscan::laser {
namespace {

TEST(RenderedLineTest, DefaultExtractionMeetsTheTargetUnderSpeckle) {
  rotoscan::testing::ScratchDir dir;
  auto plane = pipeline::RunPlaneAccuracy(300.0, dir.path(), 1, "");
  ASSERT_TRUE(plane.ok()) << plane.status().ToString();
  const auto bundle = dir / "plane-300";

  auto smoothed = pipeline::MeasureLineAccuracy(bundle, ExtractOptions{});
  ASSERT_TRUE(smoothed.ok()) << smoothed.status().ToString();
  ExtractOptions per_row;
  per_row.smooth_half_rows = 0;
  auto raw = pipeline::MeasureLineAccuracy(bundle, per_row);
  ASSERT_TRUE(raw.ok()) << raw.status().ToString();
  std::printf(
      "line centre, default speckle: %zu rows, rms %.4f px per row, %.4f px smoothed along the line\n",
      smoothed->matched, raw->rms_px(), smoothed->rms_px());
  EXPECT_GT(smoothed->matched, 1800u);  // 2 frames x 964 rows, minus the plane's edges
  EXPECT_EQ(smoothed->outliers, 0u);
  EXPECT_EQ(smoothed->spurious, 0u);
  EXPECT_LE(smoothed->rms_px(), 0.1);              // DESIGN.md target
  EXPECT_LT(std::abs(smoothed->mean_px()), 0.02);  // no bias
  // Speckle is what the smoothing removes: per row the same frames are clearly above the target.
  EXPECT_GT(raw->rms_px(), 0.12);
}

}  // namespace
}  // namespace rotoscan::laser

namespace rotoscan::laser {
namespace {

// Issue 15: frames of the webcam preset (f/4 speckle, MJPEG, rolling-shutter flicker, changing ambient)
// of a glossy object (glints) and a dark-and-white textured one (notches), against the renderer's truth:
// per point, the error against the quality. The worst-quality tenth must hold the largest errors; the
// issue's figures are printed (the full sets are `rotoscan bench accuracy --webcam`, README).
struct PointError {
  float quality;
  double error;    // along the row, signed
  double across;   // to the true line (pipeline::DistanceAcrossLine)
  float peak, uncertainty;
  uint8_t flags;
  int object;      // of the nearest true crossing (0: the table)
};

// Rows > 1 px off by cause, each row counted once, first cause first: a glint (flagged), the albedo
// divided out (flagged), a steep line (within 1 px across the line: the row's error is the slope's),
// a weak line (peak under 30 DN: ~3x the detection threshold), and the rest (speckle on a strong line:
// the SpeckleLimitTest figures); the table's line apart.
void PrintCauses(const char* file, const std::vector<PointError>& points, size_t lit) {
  int glint = 0, albedo = 0, steep = 0, weak = 0, rest = 0, table = 0, total = 0, rest_across = 0;
  int beyond_uncertainty = 0;
  for (const PointError& p : points) {
    if (std::abs(p.error) <= 1.0) continue;
    ++total;
    beyond_uncertainty += std::abs(p.error) > p.uncertainty;
    table += p.object == 0;
    if (p.flags & kFlagGlint) {
      ++glint;
    } else if (p.flags & kFlagAlbedoEdge) {
      ++albedo;
    } else if (p.across <= 1.0) {
      ++steep;
    } else if (p.peak < 30) {
      ++weak;
    } else {
      ++rest;
      rest_across += p.across > 1.0;
    }
  }
  std::printf("  %s: rows > 1 px off %d of %zu lit (%.2f %%): glint %d, albedo edge %d, steep (<= 1 px across) %d, "
              "weak (peak < 30 DN) %d, the rest (strong, unflagged, > 1 px across) %d; on the table %d; beyond "
              "their own uncertainty %d\n",
              file, total, lit, 100.0 * total / lit, glint, albedo, steep, weak, rest, table, beyond_uncertainty);
}

std::vector<PointError> WebcamPointErrors(const std::string& scene_file, int steps, pipeline::LineAccuracyParts* total,
                                          int* glints, int* albedo_edges, int* missed_rows) {
  auto scene = sim::LoadScene(rotoscan::testing::DataPath("scenes/" + scene_file));
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  auto renderer = sim::Renderer::Create(*scene);
  EXPECT_TRUE(renderer.ok());
  LineExtractor extractor;
  std::vector<PointError> out;
  for (int step = 0; step < steps; ++step) {
    const double angle = step * 2.0 * 3.14159265358979323846 / steps;
    const sim::RenderedStep frames =
        (*renderer)->RenderStep(angle, sim::FrameSeed(scene->seed, 0, step, 0), {true, true, true, false});
    for (int k = 0; k < 2; ++k) {
      const auto truth = (*renderer)->LineTruth(static_cast<geometry::LaserId>(k), angle);
      Line line;
      EXPECT_TRUE(extractor.Extract(frames.frames[k], frames.frames[2], &line).ok());
      total->Add(pipeline::CompareWithTruthByPart(line, truth, 1.0));
      std::map<int, std::vector<double>> by_row;
      std::map<int, std::vector<const bundle::LinePoint*>> truth_by_row;
      for (const bundle::LinePoint& t : truth) {
        by_row[t.row].push_back(t.column);
        truth_by_row[t.row].push_back(&t);
      }
      {
        std::map<int, int> seen;
        for (const LinePoint& p : line.points) seen[p.row] = 1;
        std::map<int, int> row_object;  // a true row's object: the table only where nothing else crosses it
        for (const bundle::LinePoint& t : truth) row_object[t.row] = std::max(row_object[t.row], t.object);
        for (const auto& [row, object] : row_object) missed_rows[object != 0 ? 1 : 0] += seen.count(row) == 0;
      }
      for (const LinePoint& p : line.points) {
        *glints += (p.flags & kFlagGlint) != 0;
        *albedo_edges += (p.flags & kFlagAlbedoEdge) != 0;
        auto it = truth_by_row.find(p.row);
        if (it == truth_by_row.end()) continue;
        const bundle::LinePoint* nearest = it->second[0];
        for (const bundle::LinePoint* t : it->second)
          if (std::abs(p.column - t->column) < std::abs(p.column - nearest->column)) nearest = t;
        out.push_back({p.quality, p.column - nearest->column, pipeline::DistanceAcrossLine(p.column, p.row, by_row),
                       p.peak, p.uncertainty_px, p.flags, nearest->object});
      }
    }
  }
  return out;
}

TEST(RenderedLineTest, WebcamQualityPredictsErrorAndFigures) {
  std::vector<const char*> files = {"glossy-webcam.json", "textured-webcam.json"};
  for (const char* file : files) {
    pipeline::LineAccuracyParts parts;
    int glints = 0, albedo_edges = 0, missed_rows[2] = {0, 0};  // [on an object]
    std::vector<PointError> points = WebcamPointErrors(file, 3, &parts, &glints, &albedo_edges, missed_rows);
    ASSERT_GT(points.size(), 1000u) << file;
    const pipeline::LineAccuracy& total = parts.all;
    std::printf("%s: flagged: glint %d, albedo edge %d\n", file, glints, albedo_edges);
    // The target is judged on all rows across the line (README's figures table, issue 15); the rest is information.
    const std::pair<const char*, const pipeline::LineAccuracy*> split[] = {
        {"all", &parts.all}, {"object", &parts.object}, {"table", &parts.table}};
    for (const auto& [name, a] : split) {
      const double lit = static_cast<double>(std::max<size_t>(1, a->truth_rows));
      std::printf("  %-6s lit rows %zu, found %.2f %% | across the line: > 1 px off %.3f %%, rms %.3f px | per "
                  "row: > 1 px off %.3f %%, rms (within 1 px) %.3f px\n",
                  name, a->truth_rows, 100.0 * (lit - a->missed) / lit, 100.0 * a->across_outliers / lit,
                  a->across_rms_px(), 100.0 * a->outliers / lit, a->rms_px());
    }
    EXPECT_EQ(parts.object.truth_rows + parts.table.truth_rows, total.truth_rows) << file;
    EXPECT_EQ(parts.object.missed + parts.table.missed, total.missed) << file;
    EXPECT_EQ(static_cast<size_t>(missed_rows[0]), parts.table.missed) << file;
    EXPECT_EQ(static_cast<size_t>(missed_rows[1]), parts.object.missed) << file;
    PrintCauses(file, points, total.truth_rows);
    std::printf("  lit rows not found: %d on the table's line alone, %d with an object's line\n", missed_rows[0],
                missed_rows[1]);
    std::sort(points.begin(), points.end(), [](const PointError& a, const PointError& b) { return a.quality < b.quality; });
    const size_t tenth = points.size() / 10;
    double rms[10], clipped[10];
    int over[10];
    for (int d = 0; d < 10; ++d) {
      double sum = 0, sum_clipped = 0;
      over[d] = 0;
      for (size_t i = d * tenth; i < (d + 1) * tenth; ++i) {
        const double e = std::abs(points[i].error);
        sum += e * e;
        sum_clipped += std::min(e, 2.0) * std::min(e, 2.0);
        over[d] += e > 1.0;
      }
      rms[d] = std::sqrt(sum / tenth);
      clipped[d] = std::sqrt(sum_clipped / tenth);
    }
    std::printf("  by quality tenth (worst first): rms");
    for (double r : rms) std::printf(" %.3f", r);
    std::printf(" px\n  errors clipped at 2 px, rms");
    for (double r : clipped) std::printf(" %.3f", r);
    std::printf(" px\n  over 1 px");
    for (int o : over) std::printf(" %d", o);
    std::printf(" of %zu\n", tenth);
    // The worst-quality tenth has the largest errors, on both sets (issue 15's "the worst-quality tenth
    // has the largest errors"). Textured: met since the albedo division's residual sets a divided point's
    // uncertainty (ninth session: rms 5.49 against at most 2.62 px; clipped at 2 px 0.83 against 0.82, so
    // only the rms is ordered strictly); before, the second-worst tenth nearly tied (4.25 against 4.34).
    for (int d = 1; d < 10; ++d) EXPECT_GT(rms[0], rms[d]) << file << ": tenth " << d;
    if (std::string(file) != "glossy-webcam.json") {
      // Textured: the worst tenth's errors are also well above the better half's (clipped rms 0.83 against
      // at most 0.53 px, over 1 px 56 against at most 6 of 280). With the smoothing joining steep steps
      // (eleventh session) the worst tenth's errors fell (clipped 0.63 against at most 0.43 px: the
      // smoothed steep rows rank low by quality), hence 1.4 rather than 1.5.
      for (int d = 5; d < 10; ++d) {
        EXPECT_GT(clipped[0], 1.4 * clipped[d]) << file << ": tenth " << d;
        EXPECT_GT(over[0], 2 * over[d]) << file << ": tenth " << d;
      }
    }
  }
}


// Issue 15: laser light scattered into a concavity (renderer.h, "Interreflection") makes a second, weaker
// line along the inside corner of concave-webcam.json (two boards in a 90 degree V). The extractor must
// keep the primary line: lit rows found and rows > 1 px off against the renderer's truth, with the bounce
// on and off on the same frames' seeds, and no row's point on the bounce (> 3 px from the true line).
TEST(RenderedLineTest, WebcamConcaveCornerKeepsThePrimaryLine) {
  auto scene = sim::LoadScene(rotoscan::testing::DataPath("scenes/concave-webcam.json"));
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  ASSERT_TRUE(scene->laser_interreflection);  // the webcam preset's default
  sim::Scene without = *scene;
  without.laser_interreflection = false;
  LineExtractor extractor;
  pipeline::LineAccuracy totals[2], far[2];
  int far_on_boards[2][2] = {{0, 0}, {0, 0}};  // [bounce][on the boards]: points > 3 px off
  std::map<int, int> missed_by_object, lit_by_object;
  std::map<int, std::vector<int>> peaks_by_object;  // the red difference at the true centre, bounce on
  for (int bounce = 0; bounce < 2; ++bounce) {
    auto renderer = sim::Renderer::Create(bounce != 0 ? *scene : without);
    ASSERT_TRUE(renderer.ok());
    for (int step = 0; step < 3; ++step) {
      const double angle = (step - 1) * 20.0 * 3.14159265358979323846 / 180.0;  // -20, 0, 20 degrees
      const sim::RenderedStep frames =
          (*renderer)->RenderStep(angle, sim::FrameSeed(scene->seed, 0, step, 0), {true, true, true, false});
      for (int k = 0; k < 2; ++k) {
        const auto truth = (*renderer)->LineTruth(static_cast<geometry::LaserId>(k), angle);
        Line line;
        ASSERT_TRUE(extractor.Extract(frames.frames[k], frames.frames[2], &line).ok());
        totals[bounce].Add(pipeline::CompareWithTruth(line, truth, 1.0));
        {
          std::map<int, int> rows_seen;
          for (const LinePoint& p : line.points) rows_seen[p.row] = 1;
          for (const bundle::LinePoint& t : truth) {
            missed_by_object[t.object] += rows_seen.count(t.row) == 0;
            lit_by_object[t.object] += 1;
            const int x = static_cast<int>(std::lround(t.column));
            if (bounce != 0 && x >= 0 && x < frames.frames[k].cols) {
              peaks_by_object[t.object].push_back(frames.frames[k].at<cv::Vec3b>(t.row, x)[2] -
                                                  frames.frames[2].at<cv::Vec3b>(t.row, x)[2]);
            }
          }
        }
        far[bounce].Add(pipeline::CompareWithTruth(line, truth, 3.0));
        {
          // The points > 3 px off, by the object the nearest true crossing lies on (0: the table).
          std::map<int, std::vector<const bundle::LinePoint*>> by_row;
          for (const bundle::LinePoint& t : truth) by_row[t.row].push_back(&t);
          for (const LinePoint& p : line.points) {
            auto it = by_row.find(p.row);
            if (it == by_row.end()) continue;
            const bundle::LinePoint* nearest = it->second[0];
            for (const bundle::LinePoint* t : it->second)
              if (std::abs(t->column - p.column) < std::abs(nearest->column - p.column)) nearest = t;
            if (std::abs(nearest->column - p.column) > 3.0) ++far_on_boards[bounce][nearest->object != 0 ? 1 : 0];
          }
        }
      }
    }
  }
  for (int bounce = 0; bounce < 2; ++bounce) {
    const pipeline::LineAccuracy& t = totals[bounce];
    const double lit = static_cast<double>(t.truth_rows);
    std::printf("concave-webcam, bounce %s: lit rows %zu, found %.2f %%, > 1 px off %.3f %% (across the line "
                "%.3f %%), > 3 px off %zu, spurious %zu, rms (within 1 px) %.3f px, mean %+.3f px\n",
                bounce != 0 ? "on " : "off", t.truth_rows, 100.0 * (lit - t.missed) / lit,
                100.0 * t.outliers / lit, 100.0 * t.across_outliers / lit, far[bounce].outliers, t.spurious,
                t.rms_px(), t.mean_px());
  }
  for (auto& [object, n] : lit_by_object) {
    std::vector<int>& peaks = peaks_by_object[object];
    std::sort(peaks.begin(), peaks.end());
    std::printf("%s %d: truth points %d (both renders), their row not found %d; red difference at the true "
                "centre: median %d DN\n", object == 0 ? "table " : "object", object, n, missed_by_object[object],
                peaks.empty() ? 0 : peaks[peaks.size() / 2]);
  }
  int object_points = 0, object_missed = 0;
  for (const auto& [object, n] : lit_by_object) {
    if (object == 0) continue;
    object_points += n;
    object_missed += missed_by_object[object];
  }
  const pipeline::LineAccuracy& on = totals[1];
  const double lit = static_cast<double>(on.truth_rows);
  EXPECT_GT(on.truth_rows, 2000u);
  for (int bounce = 0; bounce < 2; ++bounce) {
    std::printf("bounce %s: > 3 px off on the table %d, on the boards %d\n", bounce != 0 ? "on " : "off",
                far_on_boards[bounce][0], far_on_boards[bounce][1]);
  }
  // With the detection threshold at 6 sigma of the frame's noise (8-10 DN here; extract.cc) the table's
  // line (albedo 0.08, ~10 DN) is found in 85 % of its rows (before, at the fixed 12 DN: half); on the
  // two boards every true point's row is found. The bounce must not pull points off the boards' line
  // (> 3 px off, measured: 7 with and without it); on the table, at the boards' foot, the scattered
  // light is as strong as the table's own line (5-14 DN against ~10), and a few more rows take it
  // (measured: 23 without, 40 with, of 2,296 table points), which the bound on the whole holds.
  (void)lit;
  EXPECT_GE(1.0 - static_cast<double>(object_missed) / object_points, 0.99);
  EXPECT_LE(far_on_boards[1][1], far_on_boards[0][1] + 5);  // points taken on the bounce instead of the line
  EXPECT_LE(far[1].outliers, far[0].outliers + 30);
  EXPECT_LE(on.outliers, totals[0].outliers + on.truth_rows / 50);
}

}  // namespace
}  // namespace rotoscan::laser

namespace rotoscan::laser {
namespace {

// Glints (extract.cc, "Glints") against the truth: the glossy webcam scene and the same scene with its
// specular lobes off, rendered with the same seeds; the glint is where the glossy laser frame's red
// exceeds the matte one within 15 px of the point (>= 30 DN: in a glint; < 5 DN: far from any). 3 steps
// x 2 lasers.
TEST(RenderedLineTest, GlintsAreFlaggedWhereTheTruthHasThem) {
  auto scene = sim::LoadScene(rotoscan::testing::DataPath("scenes/glossy-webcam.json"));
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  sim::Scene matte = *scene;
  for (sim::ObjectSpec& object : matte.objects) object.specular = 0.0;
  auto glossy_renderer = sim::Renderer::Create(*scene);
  auto matte_renderer = sim::Renderer::Create(matte);
  ASSERT_TRUE(glossy_renderer.ok() && matte_renderer.ok());
  LineExtractor extractor;
  int in_glint = 0, in_glint_flagged = 0, far = 0, far_flagged = 0, between_flagged = 0, points = 0, stats_glints = 0;
  for (int step = 0; step < 3; ++step) {
    const double angle = step * 2.0 * 3.14159265358979323846 / 3;
    const uint64_t seed = sim::FrameSeed(scene->seed, 0, step, 0);
    const sim::RenderedStep glossy = (*glossy_renderer)->RenderStep(angle, seed, {true, true, true, false});
    const sim::RenderedStep plain = (*matte_renderer)->RenderStep(angle, seed, {true, true, false, false});
    for (int k = 0; k < 2; ++k) {
      Line line;
      ASSERT_TRUE(extractor.Extract(glossy.frames[k], glossy.frames[2], &line).ok());
      stats_glints += line.stats.glints;
      cv::Mat g, m;
      cv::extractChannel(glossy.frames[k], g, 2);
      cv::extractChannel(plain.frames[k], m, 2);
      for (const LinePoint& p : line.points) {
        const int c = static_cast<int>(p.column + 0.5);
        int extra = 0;
        for (int x = std::max(0, c - 15); x <= std::min(g.cols - 1, c + 15); ++x)
          extra = std::max(extra, g.at<uint8_t>(p.row, x) - m.at<uint8_t>(p.row, x));
        const bool flagged = (p.flags & kFlagGlint) != 0;
        ++points;
        if (extra >= 30) {
          ++in_glint;
          in_glint_flagged += flagged;
        } else if (extra < 5) {
          ++far;
          far_flagged += flagged;
        } else {
          between_flagged += flagged;
        }
      }
    }
  }
  std::printf("glints: %d points, %d in a glint (%d flagged), %d far from any (%d flagged), %d flagged between\n",
              points, in_glint, in_glint_flagged, far, far_flagged, between_flagged);
  EXPECT_GT(in_glint, 50);  // the scene has glints
  EXPECT_GE(in_glint_flagged, in_glint * 8 / 10);
  EXPECT_EQ(far_flagged, 0);  // the line elsewhere is kept as it was
  EXPECT_EQ(stats_glints, in_glint_flagged + far_flagged + between_flagged);
}

}  // namespace
}  // namespace rotoscan::laser

namespace rotoscan::laser {
namespace {

// The speckle limit of the line centre (doc/issue15-log.md): Dorsch, Haeusler and Herrmann (Applied Optics
// 33(7), 1994) give the centre uncertainty in the image plane as C lambda F# / pi, C the speckle contrast
// (1 for fully developed speckle): at 660 nm and 2.8 um pixels 0.30 px at f/4, 0.18 px at f/2.4 and 0.15 px
// at f/2.0. Here a perfect straight vertical line (a Gaussian profile, no blur, no noise, no JPEG, no
// texture), each pixel the integral over its cells of the profile times the renderer's fully developed
// speckle field (sim::SpeckleIntensity, as the renderer forms it), 8-bit; the extractor's per-row centre
// against the true one, per row and smoothed along the line (defaults), over several seeds.
TEST(SpeckleLimitTest, PerRowScatterAgainstDorsch) {
  const double pixel_um = 2.8, wavelength_nm = 660.0;
  const int rows = 256, cols = 96, seeds = 4;
  const double centre = 47.3;
  struct Case {
    double f_number, sigma_px, blur_px;
    double per_row = 0, smoothed = 0, found = 0, ideal = 0, over_1px = 0;
  };
  // The webcam preset's line (sigma 3.4 px: its 0.7 mm sheet at ~0.2 mm per pixel) and a narrower one;
  // f/4 (the renderer's webcam preset), f/2.4 and f/2.0 (a webcam's own lens: README); with no blur, and
  // with the preset's optical blur of 1.2 px (after the speckle, as the renderer does).
  std::vector<Case> cases = {{4.0, 3.4, 0.0}, {4.0, 1.5, 0.0}, {2.4, 3.4, 0.0}, {2.0, 3.4, 0.0},
                             {4.0, 3.4, 1.2}, {2.4, 3.4, 1.2}};
  for (Case& c : cases) {
    const int over = sim::SpeckleOversampling(pixel_um, wavelength_nm, c.f_number);
    double sum_row = 0, sum_smooth = 0, sum_ideal = 0;
    size_t n_row = 0, n_smooth = 0, n_over = 0;
    for (int seed = 1; seed <= seeds; ++seed) {
      const cv::Mat speckle = sim::SpeckleIntensity(rows, cols, pixel_um, wavelength_nm, c.f_number, over,
                                                    static_cast<uint64_t>(seed));
      cv::Mat on(rows, cols, CV_8UC1), off(rows, cols, CV_8UC1, cv::Scalar(10));
      cv::Mat image(rows, cols, CV_64F);
      for (int r = 0; r < rows; ++r) {
        for (int x = 0; x < cols; ++x) {
          double sum = 0;
          for (int i = 0; i < over; ++i) {
            for (int j = 0; j < over; ++j) {
              const double xc = x - 0.5 + (j + 0.5) / over - centre;
              sum += std::exp(-0.5 * xc * xc / (c.sigma_px * c.sigma_px)) * speckle.at<float>(r * over + i, x * over + j);
            }
          }
          image.at<double>(r, x) = 60.0 * sum / (over * over);
        }
      }
      if (c.blur_px > 0) cv::GaussianBlur(image, image, cv::Size(0, 0), c.blur_px, c.blur_px, cv::BORDER_REPLICATE);
      for (int r = 0; r < rows; ++r)
        for (int x = 0; x < cols; ++x) on.at<uint8_t>(r, x) = cv::saturate_cast<uint8_t>(10.0 + image.at<double>(r, x));
      // The physical limit of a centroid: the centre of mass of the whole profile (the difference over
      // +-3 sigma around the true centre, no threshold), which no extractor can beat by much.
      for (int r = 0; r < rows; ++r) {
        double m = 0, mx = 0;
        for (int x = static_cast<int>(centre - 3 * c.sigma_px); x <= static_cast<int>(centre + 3 * c.sigma_px) + 1; ++x) {
          const double v = on.at<uint8_t>(r, x) - 10.0;
          m += v;
          mx += v * x;
        }
        sum_ideal += (mx / m - centre) * (mx / m - centre);
      }
      for (int smooth : {0, 1}) {
        ExtractOptions o;
        o.noise_dn = 1.0;  // no noise here: the threshold of a clean frame
        if (smooth == 0) o.smooth_half_rows = 0;
        auto line = ExtractLine(on, off, o);
        ASSERT_TRUE(line.ok());
        for (const LinePoint& p : line->points) {
          const double e = p.column - centre;
          (smooth ? sum_smooth : sum_row) += e * e;
          if (smooth == 0 && std::abs(e) > 1.0) ++n_over;
          ++(smooth ? n_smooth : n_row);
        }
      }
    }
    c.found = static_cast<double>(n_row) / (rows * seeds);
    c.ideal = std::sqrt(sum_ideal / (rows * seeds));
    c.over_1px = static_cast<double>(n_over) / static_cast<double>(n_row);
    c.per_row = std::sqrt(sum_row / static_cast<double>(n_row));
    c.smoothed = std::sqrt(sum_smooth / static_cast<double>(n_smooth));
    const double dorsch = wavelength_nm * 1e-3 * c.f_number / 3.14159265358979323846 / pixel_um;
    std::printf("speckle f/%.1f, line sigma %.1f px, blur %.1f px: whole-profile centroid %.3f px per row (C = %.2f); the "
                "extractor: rows found %.1f %%, over 1 px %.1f %%, per row %.3f px (C = %.2f), smoothed %.3f px; "
                "Dorsch (C = 1) %.3f px\n",
                c.f_number, c.sigma_px, c.blur_px, c.ideal, c.ideal / dorsch, 100.0 * c.found, 100.0 * c.over_1px, c.per_row,
                c.per_row / dorsch, c.smoothed, dorsch);
  }
  // Against the published figure: unblurred, the whole-profile centroid scatters at least as much as
  // Dorsch's limit with C = 1 and at most 2.5 times it (measured C 1.2 for the narrow line, 2.0-2.3 for
  // the wide ones: a multiplicative speckle field over a profile wider than the grain moves its centroid
  // by ~sqrt(width x grain), where Dorsch's spot is about one grain), and it scales with F# as the formula
  // does (f/4 against f/2.0: 2.0 by the formula, measured 1.75; tolerance 1.5-2.5).
  for (size_t i = 0; i < 4; ++i) {
    const double dorsch = wavelength_nm * 1e-3 * cases[i].f_number / 3.14159265358979323846 / pixel_um;
    EXPECT_GE(cases[i].ideal, dorsch) << "case " << i;
    EXPECT_LE(cases[i].ideal, 2.5 * dorsch) << "case " << i;
  }
  EXPECT_GT(cases[0].ideal / cases[3].ideal, 1.5);
  EXPECT_LT(cases[0].ideal / cases[3].ideal, 2.5);
  // The f/4 limit per row is above issue 15's 0.25 px target for the webcam's line, whatever the extractor.
  EXPECT_GT(cases[0].ideal, 0.25);
}

}  // namespace
}  // namespace rotoscan::laser

namespace rotoscan::laser {
namespace {

// The detection floor (extract.cc, "Detection threshold"): 6 sigma of the noise estimated per frame on
// its lit pixels. Two laser-off frames of the same step with different noise seeds (MJPEG, rolling-
// shutter flicker and the changing ambient included) have no laser: every row with a point is a false
// detection. Here, 2 steps of each of the three webcam scenes (5,760 rows), with the 6 DN floor: 4 sigma
// 25 rows, 5 sigma 10, 6 sigma 1 (the default); with a 2 DN floor, 3 steps each (8,640 rows): 4 sigma
// 151, 5 sigma 18, 6 sigma 1, 8 sigma 0. The estimated sigma is 1.1-1.3 DN on these pairs (checked
// against the difference's SD over the lit pixels), 1.2-1.8 DN on the laser pairs (DESIGN.md's real
// C270 frame: 1.4 DN).
TEST(DetectionFloorTest, FalseDetectionsOnLaserOffPairs) {
  const char* files[] = {"glossy-webcam.json", "textured-webcam.json", "concave-webcam.json"};
  int rows = 0, false_rows[3] = {0, 0, 0};  // at 4, 5 and 6 sigma
  for (const char* file : files) {
    auto scene = sim::LoadScene(rotoscan::testing::DataPath(std::string("scenes/") + file));
    ASSERT_TRUE(scene.ok()) << scene.status().ToString();
    auto renderer = sim::Renderer::Create(*scene);
    ASSERT_TRUE(renderer.ok());
    for (int step = 0; step < 2; ++step) {
      const double angle = step * 2.0 * 3.14159265358979323846 / 3;
      const sim::FrameMask off_only = {false, false, true, false};
      const cv::Mat off = (*renderer)->RenderStep(angle, sim::FrameSeed(scene->seed, 0, step, 0), off_only).frames[2];
      const cv::Mat other = (*renderer)->RenderStep(angle, sim::FrameSeed(scene->seed, 0, step, 7), off_only).frames[2];
      // The SD of the red difference over the pixels lit in the laser-off frame (>= 16 DN).
      cv::Mat a, b;
      cv::extractChannel(other, a, 2);
      cv::extractChannel(off, b, 2);
      double sum = 0, sum2 = 0;
      int n = 0;
      for (int r = 0; r < a.rows; ++r) {
        for (int x = 0; x < a.cols; ++x) {
          if (b.at<uint8_t>(r, x) < 16) continue;
          const double d = a.at<uint8_t>(r, x) - b.at<uint8_t>(r, x);
          sum += d;
          sum2 += d * d;
          ++n;
        }
      }
      const double sd = std::sqrt(sum2 / n - (sum / n) * (sum / n));
      for (int k = 0; k < 3; ++k) {
        ExtractOptions o;
        o.min_snr = 4.0 + k;
        auto extracted = ExtractLine(other, off, o);
        ASSERT_TRUE(extracted.ok());
        const Line& line = *extracted;
        false_rows[k] += static_cast<int>(line.points.size());
        if (k == 2) {
          rows += line.stats.rows;
          std::printf("%s step %d: noise estimated %.2f DN, SD over the lit pixels %.2f DN, threshold %.0f DN\n", file,
                      step, line.stats.noise_dn, sd, line.stats.threshold_dn);
          EXPECT_TRUE(line.stats.noise_on_lit) << file;
          EXPECT_GT(line.stats.noise_dn, 0.7 * sd) << file;
          EXPECT_LT(line.stats.noise_dn, 1.5 * sd) << file;
        }
      }
    }
  }
  std::printf("laser-off pairs, %d rows: rows with a (false) point at 4 / 5 / 6 sigma: %d / %d / %d\n", rows,
              false_rows[0], false_rows[1], false_rows[2]);
  EXPECT_EQ(ExtractOptions{}.min_snr, 6.0);
  EXPECT_LE(false_rows[2], rows / 2000);  // at most 0.05 % of the rows, a quarter of issue 15's 0.2 %
  EXPECT_GT(false_rows[0], false_rows[2]);  // the floor is where the false detections stop, not far above
}

}  // namespace
}  // namespace rotoscan::laser
