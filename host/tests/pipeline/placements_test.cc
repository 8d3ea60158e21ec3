// Aligning the clouds of several placements (pipeline/placements.h) against the virtual scanner's truth:
// Spot's true surface in the demo scene's two placements (upright, on its side; sim::PlaceScene), each
// sampled where a turntable scan of that placement sees it, with noise; the demo's pair (upright, nose
// down) rendered and processed; a sphere, which no alignment can orient; and clouds that share nothing.
#include "rotoscan/pipeline/placements.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>

#include <gtest/gtest.h>

#include "command.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/cloud/filter.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/pipeline/process.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"
#include "testing/testing.h"

namespace rotoscan::pipeline {
namespace {

struct Placed {
  bundle::TruthMesh mesh;                  // in the placement's table frame
  Eigen::Isometry3d table_from_reference;  // the truth
};

Placed PlaceSpot(int placement) {
  auto scene = sim::LoadScene(testing::DataPath("scenes/spot.json"));
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  Placed out;
  auto placed = sim::PlaceScene(*scene, placement, &out.table_from_reference);
  EXPECT_TRUE(placed.ok()) << placed.status().ToString();
  auto renderer = sim::Renderer::Create(*placed);
  EXPECT_TRUE(renderer.ok()) << renderer.status().ToString();
  out.mesh = (*renderer)->ObjectMesh();
  return out;
}

// Area-uniform samples of `mesh` (one per spacing^2) where a turntable scan sees the surface: above the
// table top and not facing down (the camera looks 10 degrees down; the lasers come from its height), with
// Gaussian noise of `noise_mm` along the normal. The normals are the faces' (outwards).
cloud::PointCloud SampleScan(const bundle::TruthMesh& mesh, double spacing, double noise_mm, uint64_t seed,
                             const std::function<bool(const Eigen::Vector3d&)>& keep = {}) {
  std::mt19937_64 random(seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, noise_mm);
  cloud::PointCloud cloud;
  for (const Eigen::Vector3i& f : mesh.faces) {
    const Eigen::Vector3d a = mesh.vertices[static_cast<size_t>(f[0])].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[static_cast<size_t>(f[1])].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[static_cast<size_t>(f[2])].cast<double>();
    const Eigen::Vector3d cross = (b - a).cross(c - a);
    if (cross.norm() < 1e-12) continue;
    const Eigen::Vector3d n = cross.normalized();
    const double expected = 0.5 * cross.norm() / (spacing * spacing);
    int count = static_cast<int>(expected);
    if (uniform(random) < expected - count) ++count;
    for (int k = 0; k < count; ++k) {
      const double r1 = std::sqrt(uniform(random)), r2 = uniform(random);
      const Eigen::Vector3d p = (1 - r1) * a + r1 * (1 - r2) * b + r1 * r2 * c;
      if (p.z() < 0.5 || n.z() < -0.3) continue;
      if (keep && !keep(p)) continue;
      cloud::CloudPoint q;
      q.position_in_table = (p + gauss(random) * n).cast<float>();
      q.normal = n.cast<float>();
      q.color = {200, 200, 200};
      q.quality = 1.0f;
      cloud.points.push_back(q);
    }
  }
  return cloud;
}

AlignOptions TestOptions() {
  AlignOptions o;
  o.fine_voxel_mm = 0.0;  // the test clouds are thin already
  return o;
}

TEST(PlacementsTest, SpotOnItsSideIsAlignedToTheTruth) {
  const Placed upright = PlaceSpot(0), side = PlaceSpot(2);
  // Placement 1 truly is another pose: turned by 90 degrees.
  EXPECT_NEAR(Eigen::AngleAxisd((upright.table_from_reference * side.table_from_reference.inverse()).linear())
                  .angle(),
              geometry::DegToRad(90.0), 1e-9);
  const cloud::PointCloud c0 = SampleScan(upright.mesh, 0.45, 0.03, 1);
  const cloud::PointCloud c1 = SampleScan(side.mesh, 0.45, 0.03, 2);
  auto merged = MergePlacements({c0, c1}, TestOptions());
  ASSERT_TRUE(merged.ok()) << merged.status().ToString();
  ASSERT_EQ(merged->placements.size(), 2u);
  const Eigen::Isometry3d truth = upright.table_from_reference * side.table_from_reference.inverse();
  const AlignResult& a = merged->placements[1].alignment;
  const AlignmentError e =
      MeasureAlignmentError(a.target_from_source, truth, side.mesh.vertices, side.mesh.faces);
  EXPECT_LE(e.rms_mm, 0.02) << FormatPlacementReport(*merged);
  EXPECT_LE(e.angle_deg, 0.02) << FormatPlacementReport(*merged);
  EXPECT_FALSE(a.from_hint);
  // The two placements share the sides of the body: a large overlap, a residual of the noise's order
  // (two clouds of 0.03 mm noise: 0.042 mm apart along the normal, more between samples).
  EXPECT_GT(a.overlap, 0.3);
  EXPECT_LT(a.residual_mm, 0.25);
  // Nothing else fits nearly as well.
  EXPECT_LT(a.alternative_overlap, 0.85 * a.coarse_overlap);
  EXPECT_GE(a.alternatives_tried, 24);
  // Every point carries its placement; the disagreement of aligned shells is about zero.
  size_t ones = 0;
  for (const cloud::CloudPoint& p : merged->cloud.points) ones += p.placement == 1;
  EXPECT_EQ(ones, c1.size());
  EXPECT_EQ(merged->cloud.size(), c0.size() + c1.size());
  EXPECT_GT(merged->placements[1].disagreement.pairs, 1000u);
  EXPECT_LT(std::abs(merged->placements[1].disagreement.mean_signed_mm), 0.01);
  // The same clouds give the same alignment to the last bit (Open3D's ICP summed over OpenMP threads in
  // varying order made `merge` write different files from run to run; it runs on one thread now).
  auto again = MergePlacements({c0, c1}, TestOptions());
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_TRUE(again->placements[1].alignment.target_from_source.matrix() == a.target_from_source.matrix())
      << "run 1:\n" << a.target_from_source.matrix() << "\nrun 2:\n"
      << again->placements[1].alignment.target_from_source.matrix();
}

// The demo's pair rendered, extracted and processed (not sampled from the truth): Spot upright and nose
// down (placements 0 and 1 of spot.json), each over a whole turn in kSteps steps, processed with the true
// rig (so that only the alignment is measured), outliers removed as `process` does, then merged with the
// default options. The error against the true poses over the true surface must meet the issue's 0.02 mm RMS
// and 0.02 degrees (measured 2026-11-24 with 40 steps: see the printed line; the demo's 200 + 200 steps:
// README "Placements and color").
TEST(PlacementsTest, RenderedDemoPairIsAlignedWithinTheTolerance) {
  constexpr int kSteps = 40;
  testing::ScratchDir dir;
  auto scene = sim::LoadScene(testing::DataPath("scenes/spot.json"));
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  std::vector<cloud::PointCloud> clouds;
  Eigen::Isometry3d table_from_reference[2];
  for (int placement = 0; placement < 2; ++placement) {
    sim::SimulateOptions simulate;
    simulate.out = dir / ("scan" + std::to_string(placement));
    simulate.steps = kSteps;
    simulate.step_deg = 360.0 / kSteps;
    simulate.placement = placement;
    ASSERT_TRUE(sim::Simulate(*scene, simulate, nullptr).ok());
    auto truth = bundle::ReadPlacementTruth(bundle::TruthPlacementPath(simulate.out));
    ASSERT_TRUE(truth.ok()) << truth.status().ToString();
    table_from_reference[placement] = truth->table_from_reference;
    ProcessOptions process;
    process.color.enabled = false;
    auto processed = ProcessBundle(simulate.out, scene->rig, process);
    ASSERT_TRUE(processed.ok()) << processed.status().ToString();
    auto filtered = cloud::FilterCloud(processed->cloud, cloud::FilterOptions{});
    ASSERT_TRUE(filtered.ok());
    clouds.push_back(std::move(*filtered));
  }
  auto merged = MergePlacements(clouds, AlignOptions());
  ASSERT_TRUE(merged.ok()) << merged.status().ToString();
  const AlignResult& a = merged->placements[1].alignment;
  auto mesh = bundle::ReadPlyMesh(bundle::TruthMeshPath(dir / "scan1"));
  ASSERT_TRUE(mesh.ok());
  const Eigen::Isometry3d truth = table_from_reference[0] * table_from_reference[1].inverse();
  const AlignmentError e = MeasureAlignmentError(a.target_from_source, truth, mesh->vertices, mesh->faces);
  std::printf("rendered pair, %d + %d steps: alignment error %.4f mm RMS, %.4f deg (overlap %.1f %%)\n",
              kSteps, kSteps, e.rms_mm, e.angle_deg, 100 * a.overlap);
  EXPECT_LE(e.rms_mm, 0.02) << FormatPlacementReport(*merged);
  EXPECT_LE(e.angle_deg, 0.02) << FormatPlacementReport(*merged);
  EXPECT_FALSE(a.from_hint);
  EXPECT_GT(a.residual_scale_mm, 0.0);  // the robust stage ran
}

// A sphere resting on the table, and the same sphere rolled a quarter turn: every rotation about its
// centre fits as well as the true one.
TEST(PlacementsTest, SphereIsRefusedAsAmbiguousAndAHintDecides) {
  auto scene = sim::ParseScene(R"({"objects": [{"type": "sphere", "radius_mm": 25, "segments": 96}],
                                   "placements": [{}, {"rotation_deg": [90, 0, 30]}]})",
                               ".", "sphere scene");
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  Eigen::Isometry3d t0, t1;
  auto p0 = sim::PlaceScene(*scene, 0, &t0);
  auto p1 = sim::PlaceScene(*scene, 1, &t1);
  ASSERT_TRUE(p0.ok() && p1.ok());
  auto mesh0 = (*sim::Renderer::Create(*p0))->ObjectMesh();
  auto mesh1 = (*sim::Renderer::Create(*p1))->ObjectMesh();
  const cloud::PointCloud c0 = SampleScan(mesh0, 0.7, 0.03, 3);
  const cloud::PointCloud c1 = SampleScan(mesh1, 0.7, 0.03, 4);
  auto refused = MergePlacements({c0, c1}, TestOptions());
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(refused.status().message().find("ambiguous"), std::string::npos) << refused.status().ToString();
  EXPECT_NE(refused.status().message().find("--hint"), std::string::npos);

  // A rough hint (2 degrees and 1 mm off the true pose) decides; the centre is then found exactly.
  const Eigen::Isometry3d truth = t0 * t1.inverse();
  Eigen::Isometry3d hint = truth;
  hint.prerotate(Eigen::AngleAxisd(geometry::DegToRad(2.0), Eigen::Vector3d(1, 1, 0).normalized()));
  hint.pretranslate(Eigen::Vector3d(0.6, -0.5, 0.6));
  auto merged = MergePlacements({c0, c1}, TestOptions(), {std::nullopt, hint});
  ASSERT_TRUE(merged.ok()) << merged.status().ToString();
  const AlignResult& a = merged->placements[1].alignment;
  EXPECT_TRUE(a.from_hint);
  const Eigen::Vector3d centre(0, 0, 25);  // in both frames
  EXPECT_LT((a.target_from_source * centre - truth * centre).norm(), 0.02);
  EXPECT_THAT(a.target_from_source.linear(),
              testing::EigenNear(hint.linear(), 1e-12));  // the hint's rotation
}

TEST(PlacementsTest, CloudsSharingNothingAreRefused) {
  const Placed upright = PlaceSpot(0);
  const cloud::PointCloud front =
      SampleScan(upright.mesh, 0.6, 0.03, 5, [](const Eigen::Vector3d& p) { return p.y() < -12; });
  const cloud::PointCloud back =
      SampleScan(upright.mesh, 0.6, 0.03, 6, [](const Eigen::Vector3d& p) { return p.y() > 12; });
  ASSERT_GT(front.size(), 1000u);
  ASSERT_GT(back.size(), 1000u);
  auto merged = MergePlacements({front, back}, TestOptions());
  ASSERT_FALSE(merged.ok());
  EXPECT_EQ(merged.status().code(), StatusCode::kFailedPrecondition) << merged.status().ToString();
}

TEST(PlacementsTest, BadInputIsRefused) {
  cloud::PointCloud tiny;
  tiny.points.resize(10);
  EXPECT_EQ(AlignClouds(tiny, tiny, AlignOptions()).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(MergePlacements({tiny}, AlignOptions()).status().code(), StatusCode::kInvalidArgument);
  AlignOptions bad;
  bad.voxel_mm = -1;
  EXPECT_FALSE(bad.Check().ok());
  bad = AlignOptions();
  bad.min_overlap = 2;
  EXPECT_FALSE(bad.Check().ok());
  bad = AlignOptions();
  bad.tukey_constant = std::nan("");
  EXPECT_FALSE(bad.Check().ok());
}

TEST(PlacementsTest, PoseHintsParse) {
  auto six = ParsePoseHint("90,0,0,1,2,3");
  ASSERT_TRUE(six.ok()) << six.status().ToString();
  EXPECT_THAT(Eigen::Vector3d(*six * Eigen::Vector3d(0, 1, 0)),
              testing::EigenNear(Eigen::Vector3d(1, 2, 4), 1e-12));
  testing::ScratchDir dir;
  {
    std::ofstream f(dir / "pose.txt");
    f << "# table_from_table\n1 0 0 5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
  }
  auto file = ParsePoseHint((dir / "pose.txt").string());
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  EXPECT_THAT(Eigen::Vector3d(file->translation()), testing::EigenNear(Eigen::Vector3d(5, 0, 0), 1e-12));
  EXPECT_EQ(ParsePoseHint("1,2,3").status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(ParsePoseHint("1,2,3,4,5,nan").status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(ParsePoseHint((dir / "missing.txt").string()).status().code(), StatusCode::kInvalidArgument);
  {
    std::ofstream f(dir / "shear.txt");
    f << "1 1 0 0  0 1 0 0  0 0 1 0  0 0 0 1\n";
  }
  EXPECT_EQ(ParsePoseHint((dir / "shear.txt").string()).status().code(), StatusCode::kInvalidArgument);
}

int RunCli(std::vector<std::string> args, std::ostream& out, std::ostream& err) {
  args.insert(args.begin(), {"rotoscan", "--no-progress"});
  std::vector<const char*> argv;
  for (const std::string& a : args) argv.push_back(a.c_str());
  return cli::Main(static_cast<int>(argv.size()), argv.data(), out, err);
}

// `rotoscan merge` end to end: the merged PLY has the placement of every point and the report says the
// alignment's figures; a bad hint is a clear error and no file.
TEST(PlacementsTest, MergeCommandWritesPlacementsPerPoint) {
  const Placed upright = PlaceSpot(0), side = PlaceSpot(2);
  testing::ScratchDir dir;
  ASSERT_TRUE(cloud::WritePly(dir / "a.ply", SampleScan(upright.mesh, 0.6, 0.03, 7)).ok());
  ASSERT_TRUE(cloud::WritePly(dir / "b.ply", SampleScan(side.mesh, 0.6, 0.03, 8)).ok());
  std::ostringstream out, err;
  const std::string a = (dir / "a.ply").string(), b = (dir / "b.ply").string(), m = (dir / "m.ply").string();
  EXPECT_EQ(RunCli({"merge", a, b, "--hint", "1,2", "--out", m}, out, err), cli::kExitFailure);
  EXPECT_NE(err.str().find("hint"), std::string::npos) << err.str();
  EXPECT_FALSE(std::filesystem::exists(m));
  out.str("");
  err.str("");
  ASSERT_EQ(RunCli({"merge", a, b, "--out", m}, out, err), cli::kExitOk) << err.str();
  EXPECT_NE(out.str().find("aligned automatically"), std::string::npos) << out.str();
  EXPECT_NE(out.str().find("disagreement"), std::string::npos) << out.str();
  auto read = cloud::ReadPly(m);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  size_t ones = 0;
  for (const cloud::CloudPoint& p : read->points) ones += p.placement == 1;
  EXPECT_GT(ones, 1000u);
  EXPECT_LT(ones, read->size());
}

// Clouds that know their camera path (rotoscan process writes it) merge into a cloud that knows each
// placement's, moved by the alignment: a point of placement 1 seen at step s has its camera where the
// second scan's camera was at step s, in the merged frame; mesh --watertight takes the merged cloud.
TEST(PlacementsTest, MergedCloudCarriesEachPlacementsCameraPath) {
  const Placed upright = PlaceSpot(0), side = PlaceSpot(2);
  cloud::PointCloud a = SampleScan(upright.mesh, 0.6, 0.03, 7), b = SampleScan(side.mesh, 0.6, 0.03, 8);
  const double step = geometry::DegToRad(1.8);
  for (cloud::PointCloud* c : {&a, &b}) {
    c->scan.known = true;
    c->scan.camera_at_step0 = Eigen::Vector3d(0, -310, 95);
    c->scan.step_rad = c == &a ? -step : -2 * step;  // the second scan with half as many steps
    // Each point's step: the one whose camera faces it best (any will do for the path's test).
    for (cloud::CloudPoint& p : c->points) {
      const double azimuth = std::atan2(p.position_in_table.y(), p.position_in_table.x());
      p.step = static_cast<int32_t>(std::lround((azimuth + 3.14159265358979 / 2) / c->scan.step_rad)) % 400;
    }
  }
  auto merged = MergePlacements({a, b}, TestOptions());
  ASSERT_TRUE(merged.ok()) << merged.status().ToString();
  const cloud::ScanGeometry& scan = merged->cloud.scan;
  ASSERT_TRUE(scan.known);
  ASSERT_EQ(scan.placements.size(), 2u);
  const Eigen::Isometry3d truth = upright.table_from_reference * side.table_from_reference.inverse();
  // The alignment's own accuracy (SpotOnItsSideIsAlignedToTheTruth): ~0.02 degrees, ~0.01 mm.
  const Eigen::Isometry3d& moved = scan.placements[1].merged_from_table;
  EXPECT_LT((moved.linear() - truth.linear()).cwiseAbs().maxCoeff(), 1e-3);
  EXPECT_LT((moved.translation() - truth.translation()).norm(), 0.05);
  EXPECT_NEAR(scan.placements[1].step_rad, -2 * step, 1e-12);
  // Placement 0's cameras are the first scan's; placement 1's are the second scan's, moved.
  EXPECT_LT((scan.CameraAt(0, 17) - a.scan.CameraAtStep(17)).norm(), 1e-9);
  EXPECT_LT((scan.CameraAt(1, 17) - truth * b.scan.CameraAtStep(17)).norm(), 0.5);
  // Through the file and into the watertight mesh.
  testing::ScratchDir dir;
  ASSERT_TRUE(cloud::WritePly(dir / "m.ply", merged->cloud).ok());
  auto read = cloud::ReadPly(dir / "m.ply");
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_TRUE(read->scan.known);
  ASSERT_EQ(read->scan.placements.size(), 2u);
  EXPECT_LT((read->scan.CameraAt(1, 17) - scan.CameraAt(1, 17)).norm(), 1e-9);
  std::ostringstream out, err;
  EXPECT_EQ(RunCli({"mesh", (dir / "m.ply").string(), "--watertight", "--open-bottom", "--out",
                    (dir / "mesh.ply").string()},
                   out, err),
            cli::kExitOk)
      << err.str();
  // A placement comment that does not parse drops the path (the cloud is still read).
  auto text = ReadFile(dir / "m.ply");
  ASSERT_TRUE(text.ok());
  std::string broken = *text;
  const size_t at = broken.find("merged_from_table 1 0 0");
  ASSERT_NE(at, std::string::npos);
  broken.replace(at, 23, "merged_from_table 2 0 0");  // not a rotation
  ASSERT_TRUE(WriteFileAtomically(dir / "broken.ply", broken).ok());
  auto broken_read = cloud::ReadPly(dir / "broken.ply");
  ASSERT_TRUE(broken_read.ok()) << broken_read.status().ToString();
  EXPECT_FALSE(broken_read->scan.known);
  EXPECT_EQ(broken_read->size(), read->size());
}

}  // namespace
}  // namespace rotoscan::pipeline
