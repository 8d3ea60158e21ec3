#include "rotoscan/cloud/filter.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <unordered_set>

namespace rotoscan::cloud {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr float kRadius = 40.0f;  // mm
const Eigen::Vector3f kCentre(0, 0, 50);

// A turntable scan of a sphere: 200 laser lines (one per table step), a point every 0.1 mm along each, 0.02
// mm of noise; then `strays` points scattered uniformly in the sphere's box, each more than 1.5 mm from the
// surface (the truth says which is which: quality 0.5 marks them).
PointCloud ScannedSphereWithStrays(int strays, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, 0.02f);
  PointCloud cloud;
  for (int step = 0; step < 200; ++step) {
    const double azimuth = 2 * kPi * step / 200;
    for (double polar = 0.05; polar < kPi - 0.05; polar += 0.1 / kRadius) {
      const Eigen::Vector3f d(static_cast<float>(std::sin(polar) * std::cos(azimuth)),
                              static_cast<float>(std::sin(polar) * std::sin(azimuth)),
                              static_cast<float>(std::cos(polar)));
      CloudPoint p;
      p.position_in_table = kCentre + (kRadius + noise(rng)) * d;
      p.normal = d;
      p.step = step;
      p.quality = 0.9f;
      cloud.points.push_back(p);
    }
  }
  std::uniform_real_distribution<float> box(-kRadius - 5, kRadius + 5);
  for (int added = 0; added < strays;) {
    CloudPoint p;
    p.position_in_table = kCentre + Eigen::Vector3f(box(rng), box(rng), box(rng));
    if (std::abs((p.position_in_table - kCentre).norm() - kRadius) < 1.5f) continue;
    p.quality = 0.5f;
    cloud.points.push_back(p);
    ++added;
  }
  return cloud;
}

TEST(FilterTest, StrayPointsAreRemovedAndTheSurfaceKept) {
  const int kStrays = 2000;
  const PointCloud cloud = ScannedSphereWithStrays(kStrays, 7);
  const size_t surface = cloud.size() - kStrays;
  FilterSummary summary;
  const Result<PointCloud> clean = FilterCloud(cloud, FilterOptions{}, &summary);
  ASSERT_TRUE(clean.ok()) << clean.status().ToString();
  size_t strays_left = 0, surface_left = 0;
  double worst = 0;
  for (const CloudPoint& p : clean->points) {
    (p.quality == 0.5f ? strays_left : surface_left) += 1;
    worst = std::max(worst, static_cast<double>(std::abs((p.position_in_table - kCentre).norm() - kRadius)));
  }
  // Against the truth: every stray point goes (they lie >= 1.5 mm off the surface, alone), at most 0.5 % of
  // the surface's points go with them.
  EXPECT_EQ(strays_left, 0u);
  EXPECT_GE(surface_left, static_cast<size_t>(0.995 * static_cast<double>(surface)));
  EXPECT_LT(worst, 0.15);  // what is left is the surface (noise 0.02 mm)
  EXPECT_EQ(summary.input, cloud.size());
  EXPECT_EQ(summary.outliers, cloud.size() - clean->size());
  EXPECT_EQ(summary.output, clean->size());
  EXPECT_GT(summary.outlier_threshold_mm, 0.05);
  EXPECT_LT(summary.outlier_threshold_mm, 1.0);
  // Without the removal they all stay.
  FilterOptions off;
  off.remove_outliers = false;
  const Result<PointCloud> kept = FilterCloud(cloud, off);
  ASSERT_TRUE(kept.ok());
  EXPECT_EQ(kept->size(), cloud.size());
}

// Sparse is not stray (filter.h): a band of the sphere (polar angle 1.2-1.6 rad) scanned as lines cross a
// surface at a grazing angle, every 3rd line only and 0.3 mm apart along the line (lines ~3.8 mm apart at
// the equator: as between the legs of the demo's Spot), plus strays 0.5-0.9 mm off the densely scanned
// surface (quality 0.5) and lone ones 1.5 mm or more off (quality 0.4). The whole cloud's threshold alone
// removes most of the band; the density-relative test keeps it (97 %) and still removes every stray.
TEST(FilterTest, SparselyScannedSurfaceIsKeptAndStraysNearTheSurfaceGo) {
  std::mt19937 rng(11);
  std::normal_distribution<float> noise(0.0f, 0.02f);
  std::uniform_real_distribution<float> off(0.5f, 0.9f);
  PointCloud cloud;
  auto on_sphere = [&](double polar, double azimuth, float radius) {
    const Eigen::Vector3f d(static_cast<float>(std::sin(polar) * std::cos(azimuth)),
                            static_cast<float>(std::sin(polar) * std::sin(azimuth)),
                            static_cast<float>(std::cos(polar)));
    CloudPoint p;
    p.position_in_table = kCentre + radius * d;
    p.normal = d;
    return p;
  };
  auto in_band = [](double polar) { return polar > 1.2 && polar < 1.6; };
  size_t band = 0;
  for (int step = 0; step < 200; ++step) {
    const double azimuth = 2 * kPi * step / 200;
    for (double polar = 0.05; polar < kPi - 0.05;) {
      const bool sparse = in_band(polar);
      if (!sparse || step % 3 == 0) {
        CloudPoint p = on_sphere(polar, azimuth, kRadius + noise(rng));
        p.step = step;
        p.quality = sparse ? 0.8f : 0.9f;
        band += sparse ? 1 : 0;
        cloud.points.push_back(p);
      }
      polar += (sparse ? 0.3 : 0.1) / kRadius;
    }
  }
  const size_t surface = cloud.size();
  std::uniform_real_distribution<double> polar_dense(0.1, 1.1), azimuth(0, 2 * kPi);
  for (int i = 0; i < 300; ++i) {
    CloudPoint p = on_sphere(polar_dense(rng), azimuth(rng), kRadius + (i % 2 ? 1.0f : -1.0f) * off(rng));
    p.quality = 0.5f;
    cloud.points.push_back(p);
  }
  const PointCloud lone = ScannedSphereWithStrays(300, 12);
  for (size_t i = lone.size() - 300; i < lone.size(); ++i) {
    cloud.points.push_back(lone.points[i]);
    cloud.points.back().quality = 0.4f;
  }
  auto count = [](const PointCloud& c, float quality) {
    return static_cast<size_t>(std::count_if(c.points.begin(), c.points.end(),
                                             [&](const CloudPoint& p) { return p.quality == quality; }));
  };
  FilterSummary summary;
  const Result<PointCloud> clean = FilterCloud(cloud, FilterOptions{}, &summary);
  ASSERT_TRUE(clean.ok()) << clean.status().ToString();
  EXPECT_EQ(count(*clean, 0.5f), 0u);  // near the surface
  EXPECT_EQ(count(*clean, 0.4f), 0u);  // lone
  // The band's end points next to the dense surface (~1.5 per line) are sparser than their neighbours there.
  EXPECT_GE(count(*clean, 0.8f), static_cast<size_t>(0.95 * static_cast<double>(band)));
  EXPECT_GE(count(*clean, 0.9f), static_cast<size_t>(0.995 * static_cast<double>(surface - band)));
  EXPECT_GT(summary.kept_sparse, band / 2);
  // The whole cloud's threshold alone (local_ratio 0, the filter before 2026-11-24) loses most of the band.
  FilterOptions global_only;
  global_only.local_ratio = 0;
  const Result<PointCloud> old = FilterCloud(cloud, global_only);
  ASSERT_TRUE(old.ok());
  EXPECT_LT(count(*old, 0.8f), band / 2);
}

TEST(FilterTest, ThinningKeepsOneBestPointPerVoxel) {
  PointCloud cloud = ScannedSphereWithStrays(0, 8);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> quality(0.1f, 1.0f);
  for (CloudPoint& p : cloud.points) p.quality = quality(rng);
  cloud.scan.known = true;
  cloud.scan.step_rad = 0.03;
  FilterOptions options;
  options.remove_outliers = false;
  options.thin_voxel_mm = 0.5;
  FilterSummary summary;
  const Result<PointCloud> thin = FilterCloud(cloud, options, &summary);
  ASSERT_TRUE(thin.ok());
  EXPECT_TRUE(thin->scan.known);
  EXPECT_LT(thin->size(), cloud.size() / 2);
  EXPECT_EQ(summary.thinned, cloud.size() - thin->size());
  // One point per voxel, and it is the best of its voxel; every original point has a kept one within a
  // voxel's diagonal.
  auto key = [](const Eigen::Vector3f& p) {
    const Eigen::Vector3i c = (p / 0.5f).array().floor().cast<int>();
    return (static_cast<int64_t>(c.x()) * 4096 + c.y()) * 4096 + c.z();
  };
  std::unordered_map<int64_t, float> best;
  for (const CloudPoint& p : cloud.points) {
    float& b = best[key(p.position_in_table)];
    b = std::max(b, p.quality);
  }
  std::unordered_set<int64_t> seen;
  for (const CloudPoint& p : thin->points) {
    EXPECT_TRUE(seen.insert(key(p.position_in_table)).second);
    EXPECT_EQ(p.quality, best[key(p.position_in_table)]);
  }
  EXPECT_EQ(seen.size(), best.size());
}

TEST(FilterTest, BadOptionsAreRefused) {
  const PointCloud cloud = ScannedSphereWithStrays(10, 9);
  FilterOptions bad;
  bad.std_ratio = std::nan("");
  EXPECT_EQ(FilterCloud(cloud, bad).status().code(), StatusCode::kInvalidArgument);
  bad = FilterOptions{};
  bad.neighbours = 0;
  EXPECT_EQ(FilterCloud(cloud, bad).status().code(), StatusCode::kInvalidArgument);
  bad = FilterOptions{};
  bad.local_ratio = -1;
  EXPECT_EQ(FilterCloud(cloud, bad).status().code(), StatusCode::kInvalidArgument);
  bad = FilterOptions{};
  bad.thin_voxel_mm = -1;
  EXPECT_EQ(FilterCloud(cloud, bad).status().code(), StatusCode::kInvalidArgument);
  PointCloud broken = cloud;
  broken.points[3].position_in_table.x() = std::nanf("");
  EXPECT_EQ(FilterCloud(broken, FilterOptions{}).status().code(), StatusCode::kInvalidArgument);
  // An empty cloud filters to an empty cloud.
  const Result<PointCloud> empty = FilterCloud(PointCloud{}, FilterOptions{});
  ASSERT_TRUE(empty.ok());
  EXPECT_TRUE(empty->empty());
}

}  // namespace
}  // namespace rotoscan::cloud
