// Issue 15: is each point's uncertainty honest? LinePoint::uncertainty_px is about two standard errors of
// `column`, i.e. of the centre along the row; so a point's error here is along the row: the distance from
// its column to the nearest true crossing in its row (the renderer's LineTruth). About 5 % of the points
// should lie beyond 1x their uncertainty and very few beyond 2x.
//
// UncertaintyCoverageTest.ByPointClass renders the webcam sets (glossy, textured; f/4 as the scenes have
// it) as `rotoscan bench accuracy` does (the same seeds and angles), extracts each laser frame with the
// default options, and prints per point class: points, share with error > 1x / > 2x their uncertainty,
// median error / uncertainty, and the share over 1 px along the row. Points with no true crossing in their
// row, or more than 3 px across from the truth (another line: bench accuracy's "not found"), are left out.
// Classes, each point in the first that applies:
//   glint (kFlagGlint), filled (added by the gap step: no point in that row without it), junction (a row
//   within kJunctionRows of a row whose truth is the other part's: the table's line meets the object's),
//   line end (the truth of its part stops within kJunctionRows rows), albedo (kFlagAlbedoEdge),
//   saturated (kFlagSaturated), steep (the truth's slope over 2 columns per row), plain (the rest).
// The bench's 8 steps (~9 s; ROTOSCAN_COVERAGE_STEPS=N for another number; ROTOSCAN_COVERAGE_DUMP=1 prints
// the junction and line-end points beyond their uncertainty, with the truth and the points of rows -4..4).
//
// Checked: the plain points (the bulk) within their uncertainty but for at most 10 %; and the junction
// points (WidenAtLineBreaks, point.cc): of both sets' 164, beyond 1x their uncertainty at most 10 % and
// beyond 2x at most 5 % (before it, 25.6 % and 12.2 %: 42 and 20 of 164; after, 3.7 % and 1.2 %).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "rotoscan/laser/extract.h"
#include "rotoscan/pipeline/accuracy.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"
#include "testing/testing.h"
#include "webcam_truth.h"

namespace rotoscan::laser {
namespace {

constexpr int kJunctionRows = 4;

int EnvInt(const char* name, int fallback) {
  const char* v = std::getenv(name);
  return v != nullptr && *v != '\0' ? std::atoi(v) : fallback;
}

enum Class { kGlint, kFilled, kJunction, kEnd, kAlbedo, kSaturated, kSteep, kPlain, kClasses };
const char* const kClassNames[kClasses] = {"glint", "filled", "junction", "line end", "albedo", "saturated", "steep",
                                           "plain"};

struct ClassRows {
  std::vector<double> ratio;  // error along the row / uncertainty
  int over_1px = 0;
  int Beyond(double k) const {
    return static_cast<int>(std::count_if(ratio.begin(), ratio.end(), [k](double r) { return r > k; }));
  }
  double Median() const {
    if (ratio.empty()) return 0;
    std::vector<double> v = ratio;
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  }
};

struct SetCoverage {
  ClassRows by_class[kClasses];
};

SetCoverage Measure(const std::string& scene_file, int steps) {
  SetCoverage out;
  auto scene = sim::LoadScene(rotoscan::testing::DataPath("scenes/" + scene_file));
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  if (!scene.ok()) return out;
  auto renderer = sim::Renderer::Create(*scene);
  EXPECT_TRUE(renderer.ok());
  if (!renderer.ok()) return out;
  LineExtractor extractor{ExtractOptions{}};
  ExtractOptions no_gaps_options;
  no_gaps_options.fill_gaps = false;
  LineExtractor no_gaps{no_gaps_options};
  for (int step = 0; step < steps; ++step) {
    const double angle = step * 2.0 * 3.14159265358979323846 / steps;
    const uint64_t seed = sim::FrameSeed(scene->seed, -1, step, 0);  // as rotoscan simulate (and bench) a scan
    const sim::RenderedStep frames = (*renderer)->RenderStep(angle, seed, {true, true, true, false});
    for (int k = 0; k < 2; ++k) {
      const auto truth = (*renderer)->LineTruth(static_cast<geometry::LaserId>(k), angle);
      testing::TruthByRow truth_rows = testing::TruthRows(truth);
      std::map<int, std::vector<double>>& all_by_row = truth_rows.all;
      std::map<int, bool>& object_row = truth_rows.object;
      Line line, plain;
      EXPECT_TRUE(extractor.Extract(frames.frames[k], frames.frames[2], &line).ok());
      EXPECT_TRUE(no_gaps.Extract(frames.frames[k], frames.frames[2], &plain).ok());
      std::map<int, bool> plain_row;
      for (const LinePoint& p : plain.points) plain_row[p.row] = true;
      for (const LinePoint& p : line.points) {
        const auto t = all_by_row.find(p.row);
        if (t == all_by_row.end()) continue;
        if (pipeline::DistanceAcrossLine(p.column, p.row, all_by_row) > 3.0) continue;
        double error = 1e9, nearest = 0;
        for (double c : t->second)
          if (std::abs(c - p.column) < error) error = std::abs(c - p.column), nearest = c;
        bool junction = false, end = false;
        for (int dr = -kJunctionRows; dr <= kJunctionRows; ++dr) {
          const auto n = object_row.find(p.row + dr);
          if (n == object_row.end()) {
            end = true;
          } else if (n->second != object_row[p.row]) {
            junction = true;
          }
        }
        double slope = 0;
        const auto up = all_by_row.find(p.row - 1), down = all_by_row.find(p.row + 1);
        auto nearest_in = [&](const std::vector<double>& v) {
          double best = v[0];
          for (double c : v)
            if (std::abs(c - nearest) < std::abs(best - nearest)) best = c;
          return best;
        };
        if (up != all_by_row.end() && down != all_by_row.end()) {
          slope = 0.5 * std::abs(nearest_in(down->second) - nearest_in(up->second));
        }
        Class c = kPlain;
        if (p.flags & kFlagGlint) {
          c = kGlint;
        } else if (plain_row.count(p.row) == 0) {
          c = kFilled;
        } else if (junction) {
          c = kJunction;
        } else if (end) {
          c = kEnd;
        } else if (p.flags & kFlagAlbedoEdge) {
          c = kAlbedo;
        } else if (p.flags & kFlagSaturated) {
          c = kSaturated;
        } else if (slope > 2.0) {
          c = kSteep;
        }
        if (std::getenv("ROTOSCAN_COVERAGE_DUMP") != nullptr && (c == kJunction || c == kEnd) &&
            error > p.uncertainty_px) {
          std::printf("    %s %s r%d col %.2f err %.2f unc %.2f q %.3f w %.1f fl %d truth:", scene_file.c_str(),
                      kClassNames[c], p.row, p.column, error, p.uncertainty_px, p.quality, p.width, p.flags);
          for (int dr = -4; dr <= 4; ++dr) {
            const auto n = all_by_row.find(p.row + dr);
            if (n == all_by_row.end()) { std::printf(" -"); continue; }
            std::printf(" %.1f%s", n->second[0], object_row[p.row + dr] ? "o" : "t");
            if (n->second.size() > 1) std::printf("/%.1f", n->second[1]);
          }
          std::printf(" pts:");
          for (const LinePoint& q : line.points)
            if (std::abs(q.row - p.row) <= 4) std::printf(" %d:%.1f", q.row - p.row, q.column);
          std::printf("\n");
        }
        ClassRows& rows = out.by_class[c];
        rows.ratio.push_back(error / std::max(1e-6, static_cast<double>(p.uncertainty_px)));
        rows.over_1px += error > 1.0;
      }
    }
  }
  return out;
}

void Print(const char* set, const SetCoverage& s) {
  std::printf("  %-9s %-9s %6s %8s %8s %7s %8s\n", set, "class", "points", ">1x u %", ">2x u %", "median", ">1px %");
  for (int c = 0; c < kClasses; ++c) {
    const ClassRows& r = s.by_class[c];
    const double n = std::max<size_t>(1, r.ratio.size());
    std::printf("  %-9s %-9s %6zu %8.1f %8.1f %7.2f %8.1f\n", "", kClassNames[c], r.ratio.size(),
                100.0 * r.Beyond(1.0) / n, 100.0 * r.Beyond(2.0) / n, r.Median(), 100.0 * r.over_1px / n);
  }
}

TEST(UncertaintyCoverageTest, ByPointClass) {
  const int steps = std::max(1, EnvInt("ROTOSCAN_COVERAGE_STEPS", 8));
  std::printf("  error along the row against uncertainty_px, %d steps x 2 lasers, f/4\n", steps);
  ClassRows junction;
  for (const char* set : {"glossy-webcam.json", "textured-webcam.json"}) {
    const SetCoverage s = Measure(set, steps);
    const ClassRows& j = s.by_class[kJunction];
    junction.ratio.insert(junction.ratio.end(), j.ratio.begin(), j.ratio.end());
    Print(std::string(set).substr(0, std::string(set).find('-')).c_str(), s);
    // The plain points are the bulk; their uncertainty must cover most of them (about two sigma).
    const ClassRows& plain = s.by_class[kPlain];
    ASSERT_GT(plain.ratio.size(), 300u) << set;
    EXPECT_LT(plain.Beyond(1.0), 0.10 * static_cast<double>(plain.ratio.size())) << set;
  }
  // Where the table's line meets the object's, the row may hold either line's light: the uncertainty must
  // say so (issue 15, rfjunction: of 51 such rows over 1 px, 34 had an uncertainty under their error).
  ASSERT_GT(junction.ratio.size(), 20u);
  const double n = static_cast<double>(junction.ratio.size());
  std::printf("  junction points, both sets: %zu, beyond 1x %.1f %%, beyond 2x %.1f %%\n", junction.ratio.size(),
              100.0 * junction.Beyond(1.0) / n, 100.0 * junction.Beyond(2.0) / n);
  EXPECT_LE(junction.Beyond(1.0), 0.10 * n);
  EXPECT_LE(junction.Beyond(2.0), 0.05 * n);
}

}  // namespace
}  // namespace rotoscan::laser
