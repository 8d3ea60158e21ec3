#include <array>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "rotoscan/cloud/cloud.h"
#include "rotoscan/cloud/merge.h"
#include "testing/testing.h"

namespace rotoscan::cloud {
namespace {

PointCloud RandomCloud(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-100.f, 100.f);
  PointCloud cloud;
  for (size_t i = 0; i < n; ++i) {
    CloudPoint p;
    p.position_in_table = Eigen::Vector3f(u(rng), u(rng), u(rng));
    p.normal = Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized();
    p.color = {static_cast<uint8_t>(rng() % 256), static_cast<uint8_t>(rng() % 256),
               static_cast<uint8_t>(rng() % 256)};
    p.laser = static_cast<uint8_t>(i % 2);
    p.step = static_cast<int32_t>(i * 7 % 1200);
    p.quality = static_cast<float>(i % 100) / 100.f;
    cloud.points.push_back(p);
  }
  return cloud;
}

TEST(PlyTest, RoundTripIsExact) {
  rotoscan::testing::ScratchDir dir;
  const PointCloud cloud = RandomCloud(1000, 1);
  ASSERT_TRUE(WritePly(dir / "cloud.ply", cloud).ok());
  EXPECT_EQ(std::filesystem::file_size(dir / "cloud.ply"),
            EncodePly(PointCloud{}).size() + 1000 * 36 + std::to_string(1000).size() - 1);
  auto read = ReadPly(dir / "cloud.ply");
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->size(), cloud.size());
  for (size_t i = 0; i < cloud.size(); ++i) {
    const CloudPoint& a = cloud.points[i];
    const CloudPoint& b = read->points[i];
    EXPECT_EQ(a.position_in_table, b.position_in_table);
    EXPECT_EQ(a.normal, b.normal);
    EXPECT_EQ(a.color, b.color);
    EXPECT_EQ(a.laser, b.laser);
    EXPECT_EQ(a.step, b.step);
    EXPECT_EQ(a.quality, b.quality);
  }
  // An empty cloud is a valid file too.
  ASSERT_TRUE(WritePly(dir / "empty.ply", PointCloud{}).ok());
  EXPECT_EQ(ReadPly(dir / "empty.ply")->size(), 0u);
}

TEST(PlyTest, HeaderIsWhatDesignSays) {
  const std::string bytes = EncodePly(RandomCloud(2, 2));
  EXPECT_EQ(bytes.rfind("ply\nformat binary_little_endian 1.0\n", 0), 0u);
  for (const char* p : {"property float x\n", "property float nx\n", "property uchar red\n",
                        "property uchar laser\n", "property int step\n", "property float quality\n"}) {
    EXPECT_NE(bytes.find(p), std::string::npos) << p;
  }
  // Little endian on the wire: x of the first point.
  const size_t data = bytes.find("end_header\n") + 11;
  uint32_t bits = 0;
  for (int i = 0; i < 4; ++i) bits |= uint32_t{static_cast<uint8_t>(bytes[data + i])} << (8 * i);
  float x;
  std::memcpy(&x, &bits, 4);
  EXPECT_EQ(x, RandomCloud(2, 2).points[0].position_in_table.x());
}

TEST(PlyTest, TruncatedAndHostileFilesAreRejected) {
  const std::string good = EncodePly(RandomCloud(10, 3));
  // Truncated anywhere in the data.
  for (size_t cut : {good.size() - 1, good.size() - 36, good.find("end_header") + 11 + 5}) {
    auto r = DecodePly(good.substr(0, cut), "t.ply");
    EXPECT_EQ(r.status().code(), StatusCode::kCorruptData) << cut;
    EXPECT_NE(r.status().message().find("t.ply"), std::string::npos);
  }
  // Truncated inside the header.
  EXPECT_EQ(DecodePly(good.substr(0, 40), "t.ply").status().code(), StatusCode::kCorruptData);
  // A huge vertex count must not allocate.
  std::string huge = good;
  huge.replace(huge.find("vertex 10"), 9, "vertex 99999999999");
  EXPECT_EQ(DecodePly(huge, "h.ply").status().code(), StatusCode::kCorruptData);
  PlyReadOptions small;
  small.max_points = 5;
  EXPECT_EQ(DecodePly(good, "s.ply", small).status().code(), StatusCode::kCorruptData);
  EXPECT_EQ(DecodePly("hello", "x").status().code(), StatusCode::kCorruptData);
  EXPECT_EQ(
      DecodePly("ply\nformat binary_big_endian 1.0\nelement vertex 0\nend_header\n", "x").status().code(),
      StatusCode::kCorruptData);
  EXPECT_EQ(DecodePly("ply\nformat ascii 1.0\nelement vertex 1\nproperty float y\nend_header\n1\n", "x")
                .status()
                .code(),
            StatusCode::kCorruptData);  // no x
  EXPECT_EQ(DecodePly("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                      "property float z\nend_header\nnan 1 2\n",
                      "x")
                .status()
                .code(),
            StatusCode::kCorruptData);
  EXPECT_EQ(DecodePly("ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n", "x")
                .status()
                .code(),
            StatusCode::kCorruptData);
  EXPECT_EQ(ReadPly("/nonexistent/cloud.ply").status().code(), StatusCode::kNotFound);
}

TEST(PlyTest, ReadsAsciiAndOtherTypesFromOtherTools) {
  const std::string ascii =
      "ply\nformat ascii 1.0\ncomment from another tool\nelement camera 1\nproperty float f\n"
      "element vertex 2\nproperty double x\nproperty double y\nproperty double z\nproperty uchar red\n"
      "property uchar green\nproperty uchar blue\nelement face 0\nproperty list uchar int vertex_indices\n"
      "end_header\n7\n1.5 2 3 255 0 10\n-1 -2 -3.25 0 128 0\n";
  auto r = DecodePly(ascii, "a.ply");
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_EQ(r->size(), 2u);
  EXPECT_EQ(r->points[0].position_in_table, Eigen::Vector3f(1.5f, 2, 3));
  EXPECT_EQ(r->points[1].position_in_table.z(), -3.25f);
  EXPECT_EQ(r->points[1].color[1], 128);
  EXPECT_EQ(r->points[0].normal, Eigen::Vector3f::Zero());
}

// Two lasers sampling the same plane z = 0, the right one offset by `offset` along the normal.
PointCloud TwoShells(double offset, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 50.f);
  std::normal_distribution<float> noise(0.f, 0.02f);
  PointCloud cloud;
  for (int laser = 0; laser < 2; ++laser) {
    for (int i = 0; i < 20000; ++i) {
      CloudPoint p;
      p.position_in_table =
          Eigen::Vector3f(u(rng), u(rng), noise(rng) + (laser == 1 ? static_cast<float>(offset) : 0.f));
      p.normal = Eigen::Vector3f::UnitZ();
      p.laser = static_cast<uint8_t>(laser);
      p.quality = laser == 0 ? 0.9f : 0.8f;
      cloud.points.push_back(p);
    }
  }
  return cloud;
}

TEST(MergeTest, MeasuresSystematicOffsetBetweenLasers) {
  for (double offset : {0.0, 0.3, -0.2}) {
    const LaserDisagreement d = MeasureLaserDisagreement(TwoShells(offset, 5), 1.0);
    EXPECT_GT(d.pairs, 19000u);
    EXPECT_NEAR(d.mean_signed_mm, offset, 0.01) << offset;
    EXPECT_NEAR(d.rms_mm, std::sqrt(offset * offset + 2 * 0.02 * 0.02), 0.01);
  }
}

TEST(MergeTest, MergeLeavesOneLaserPerVoxel) {
  const PointCloud cloud = TwoShells(0.3, 6);
  MergeReport report;
  MergeOptions options;
  options.voxel_mm = 2.0;
  const PointCloud merged = MergeLasers(cloud, options, &report);
  EXPECT_EQ(report.left_in, 20000u);
  EXPECT_EQ(report.right_in, 20000u);
  EXPECT_EQ(report.left_out + report.right_out, merged.size());
  EXPECT_GT(report.shared_voxels, 500u);
  // About half the points go: the overlap is total here.
  EXPECT_NEAR(static_cast<double>(merged.size()), 20000.0, 3000.0);
  // No voxel has both lasers any more: measuring the merged cloud at a radius well inside a voxel finds
  // almost no pairs (only across voxel borders).
  const LaserDisagreement after = MeasureLaserDisagreement(merged, 0.5);
  const LaserDisagreement before = MeasureLaserDisagreement(cloud, 0.5);
  EXPECT_LT(after.pairs, before.pairs / 3);
  EXPECT_NEAR(report.disagreement.mean_signed_mm, 0.3, 0.01);
  // Disjoint lasers: nothing removed.
  PointCloud apart = cloud;
  for (CloudPoint& p : apart.points) {
    if (p.laser == 1) p.position_in_table.x() += 100;
  }
  EXPECT_EQ(MergeLasers(apart, options, nullptr).size(), apart.size());
  MergeOptions bad;
  bad.voxel_mm = 0;
  EXPECT_FALSE(bad.Check().ok());
  EXPECT_THROW(MergeLasers(cloud, bad, nullptr), PreconditionError);
}

// Merged clouds of several placements carry `placement` per point; single scans keep the old layout.
TEST(PlyTest, PlacementPropertyRoundTripsAndIsOnlyWrittenWhenUsed) {
  PointCloud cloud = RandomCloud(50, 5);
  EXPECT_EQ(EncodePly(cloud).find("placement"), std::string::npos);
  for (size_t i = 0; i < cloud.size(); ++i) cloud.points[i].placement = static_cast<uint8_t>(i % 3);
  const std::string bytes = EncodePly(cloud);
  EXPECT_NE(bytes.find("property uchar placement\nend_header"), std::string::npos);
  auto read = DecodePly(bytes, "placements");
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->size(), cloud.size());
  for (size_t i = 0; i < cloud.size(); ++i) {
    EXPECT_EQ(read->points[i].placement, cloud.points[i].placement);
    EXPECT_EQ(read->points[i].quality, cloud.points[i].quality);
  }
}

TEST(MergeTest, DisagreementBetweenAnyTwoSetsOfPoints) {
  // Two parallel planes 0.1 mm apart, told apart by index sets (as two placements are).
  PointCloud cloud;
  std::vector<uint32_t> a, b;
  for (int i = 0; i < 40; ++i) {
    for (int j = 0; j < 40; ++j) {
      CloudPoint p;
      p.position_in_table = Eigen::Vector3f(0.25f * i, 0.25f * j, 0.f);
      p.normal = Eigen::Vector3f::UnitZ();
      p.color = {100, 110, 120};
      a.push_back(static_cast<uint32_t>(cloud.size()));
      cloud.points.push_back(p);
      p.position_in_table.z() = 0.1f;
      // The second set darker by 6 levels of luminance where i is even, brighter by 3 where it is odd.
      p.color = i % 2 == 0 ? std::array<uint8_t, 3>{94, 104, 114} : std::array<uint8_t, 3>{103, 113, 123};
      b.push_back(static_cast<uint32_t>(cloud.size()));
      cloud.points.push_back(p);
    }
  }
  const LaserDisagreement d = MeasureDisagreement(cloud, a, b, 1.0);
  EXPECT_EQ(d.pairs, a.size());
  EXPECT_NEAR(d.mean_signed_mm, 0.1, 1e-6);
  EXPECT_NEAR(d.median_abs_mm, 0.1, 1e-6);
  EXPECT_NEAR(d.color_mean_signed, -1.5, 1e-9);
  EXPECT_NEAR(d.color_mean_abs, 4.5, 1e-9);
}

}  // namespace
}  // namespace rotoscan::cloud
