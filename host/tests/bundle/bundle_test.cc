#include "rotoscan/bundle/bundle.h"

#include <unistd.h>

#include <fstream>
#include <thread>

#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "rotoscan/bundle/truth.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rigid.h"
#include "testing/testing.h"

namespace rotoscan::bundle {
namespace {

namespace fs = std::filesystem;
using rotoscan::testing::EigenNear;
using rotoscan::testing::ScratchDir;

BundleHeader SmallHeader(int channels = 3, int bit_depth = 8) {
  BundleHeader h;
  h.kind = BundleKind::kScan;
  h.created_by = "bundle_test";
  h.camera.name = "test camera";
  h.camera.model = geometry::CameraModel::FromFieldOfView(32, 24, 20.0);
  h.camera.model.distortion = {-0.1, 0.01, 0.001, -0.002, 0.0};
  h.camera.channels = channels;
  h.camera.bit_depth = bit_depth;
  h.camera.pixel_size_um = 3.75;
  h.camera.laser_exposure_us = 2000;
  h.camera.natural_exposure_us = 20000;
  h.table_step_rad = geometry::DegToRad(0.3);
  h.device = {"virtual", "0001", "sim"};
  return h;
}

cv::Mat TestImage(int seed, int type = CV_8UC3) {
  cv::Mat m(24, 32, type);
  cv::RNG rng(seed);
  rng.fill(m, cv::RNG::UNIFORM, 0, CV_MAT_DEPTH(type) == CV_16U ? 65535 : 255);
  return m;
}

std::string WriteSmallBundle(const fs::path& dir, int steps) {
  auto writer = BundleWriter::Create(dir, SmallHeader());
  EXPECT_TRUE(writer.ok()) << writer.status().ToString();
  for (int s = 0; s < steps; ++s) {
    for (LaserState l : {LaserState::kNatural, LaserState::kOff, LaserState::kRight, LaserState::kLeft}) {
      FrameRecord r;
      r.step = s;
      r.laser = l;
      r.table_angle_rad = s * geometry::DegToRad(0.3);
      r.trigger_seq = static_cast<uint32_t>(4 * s + static_cast<int>(l));
      r.device_time_us = 1000 * r.trigger_seq;
      r.exposure_us = 2000;
      EXPECT_TRUE((*writer)->AddFrame(r, TestImage(s * 4 + static_cast<int>(l))).ok());
    }
  }
  EXPECT_TRUE((*writer)->Finish().ok());
  return (dir / "bundle.json").string();
}

TEST(BundleTest, RoundTripsHeaderFramesAndImages) {
  ScratchDir scratch;
  const fs::path dir = scratch / "scan";
  WriteSmallBundle(dir, 3);
  auto bundle = ReadBundle(dir);
  ASSERT_TRUE(bundle.ok()) << bundle.status().ToString();
  const BundleHeader expected = SmallHeader();
  EXPECT_EQ(bundle->header.kind, BundleKind::kScan);
  EXPECT_EQ(bundle->header.camera.model.width, 32);
  EXPECT_DOUBLE_EQ(bundle->header.camera.model.fx, expected.camera.model.fx);
  EXPECT_DOUBLE_EQ(bundle->header.camera.model.distortion[3], -0.002);
  EXPECT_NEAR(bundle->header.table_step_rad, expected.table_step_rad, 1e-15);
  EXPECT_EQ(bundle->header.device.serial, "0001");
  ASSERT_EQ(bundle->frames.size(), 12u);
  EXPECT_EQ(bundle->StepCount(), 3);
  EXPECT_FALSE(bundle->has_truth);
  // Sorted by step, then left, right, off, natural.
  EXPECT_EQ(bundle->frames[0].laser, LaserState::kLeft);
  EXPECT_EQ(bundle->frames[3].laser, LaserState::kNatural);
  EXPECT_EQ(bundle->frames[4].step, 1);
  const int i = bundle->FindFrame(2, LaserState::kRight);
  ASSERT_GE(i, 0);
  EXPECT_EQ(bundle->frames[i].file, "frames/s0002_right.png");
  EXPECT_EQ(bundle->frames[i].trigger_seq, 9u);
  EXPECT_EQ(bundle->frames[i].device_time_us, 9000u);
  auto image = ReadFrame(*bundle, i);
  ASSERT_TRUE(image.ok()) << image.status().ToString();
  EXPECT_EQ(cv::norm(*image, TestImage(9), cv::NORM_INF), 0.0);  // lossless
  EXPECT_FALSE(fs::exists(BundleWriter::PartialDirectory(dir)));
}

TEST(BundleTest, SixteenBitGrayFramesAreLossless) {
  ScratchDir scratch;
  BundleHeader h = SmallHeader(1, 12);
  h.kind = BundleKind::kCalibration;
  h.target = {TargetKind::kCheckerboard, 9, 6, 10.0, "board"};
  h.target.origin_height_mm = 49.25;
  auto writer = BundleWriter::Create(scratch / "cal", h);
  ASSERT_TRUE(writer.ok());
  FrameRecord r;
  r.pose = 3;
  r.laser = LaserState::kNatural;
  const cv::Mat image = TestImage(7, CV_16UC1);
  ASSERT_TRUE((*writer)->AddFrame(r, image).ok());
  EXPECT_EQ((*writer)->AddFrame(r, image).code(), StatusCode::kInvalidArgument);  // duplicate
  EXPECT_EQ((*writer)->AddFrame(FrameRecord{}, TestImage(1)).code(), StatusCode::kInvalidArgument);  // 8UC3
  ASSERT_TRUE((*writer)->Finish().ok());
  auto bundle = ReadBundle(scratch / "cal");
  ASSERT_TRUE(bundle.ok()) << bundle.status().ToString();
  EXPECT_EQ(bundle->header.target.kind, TargetKind::kCheckerboard);
  EXPECT_EQ(bundle->header.target.cols, 9);
  EXPECT_EQ(bundle->header.target.origin_height_mm, 49.25);
  ASSERT_EQ(bundle->frames.size(), 1u);
  EXPECT_EQ(bundle->frames[0].file, "frames/p03_s0000_natural.png");
  auto read = ReadFrame(*bundle, 0);
  ASSERT_TRUE(read.ok());
  EXPECT_EQ(read->type(), CV_16UC1);
  EXPECT_EQ(cv::norm(*read, image, cv::NORM_INF), 0.0);
}

TEST(BundleTest, FramesFromManyThreads) {
  ScratchDir scratch;
  auto writer = BundleWriter::Create(scratch / "mt", SmallHeader());
  ASSERT_TRUE(writer.ok());
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int s = t; s < 20; s += 4) {
        FrameRecord r;
        r.step = s;
        r.laser = LaserState::kOff;
        EXPECT_TRUE((*writer)->AddFrame(r, TestImage(s)).ok());
      }
    });
  }
  for (auto& th : threads) th.join();
  ASSERT_TRUE((*writer)->Finish().ok());
  auto bundle = ReadBundle(scratch / "mt");
  ASSERT_TRUE(bundle.ok());
  ASSERT_EQ(bundle->frames.size(), 20u);
  for (int s = 0; s < 20; ++s) EXPECT_EQ(bundle->frames[s].step, s);
}

TEST(BundleTest, UnfinishedWriterLeavesNoBundle) {
  ScratchDir scratch;
  {
    auto writer = BundleWriter::Create(scratch / "kept", SmallHeader());
    ASSERT_TRUE(writer.ok());
    ASSERT_TRUE((*writer)->AddFrame(FrameRecord{}, TestImage(0)).ok());
  }
  // Nothing under the final name; the frames stay in the partial directory to be resumed.
  EXPECT_FALSE(fs::exists(scratch / "kept"));
  EXPECT_TRUE(fs::exists(BundleWriter::PartialDirectory(scratch / "kept") / "frames" / "s0000_off.png"));
  {
    auto writer = BundleWriter::Create(scratch / "gone", SmallHeader());
    ASSERT_TRUE(writer.ok());
    ASSERT_TRUE((*writer)->AddFrame(FrameRecord{}, TestImage(0)).ok());
    (*writer)->Discard();
  }
  EXPECT_FALSE(fs::exists(scratch / "gone"));
  EXPECT_FALSE(fs::exists(BundleWriter::PartialDirectory(scratch / "gone")));
}

TEST(BundleTest, ExistingDirectoryNeedsOverwrite) {
  ScratchDir scratch;
  WriteSmallBundle(scratch / "b", 1);
  EXPECT_EQ(BundleWriter::Create(scratch / "b", SmallHeader()).status().code(),
            StatusCode::kFailedPrecondition);
  auto writer = BundleWriter::Create(scratch / "b", SmallHeader(), {true});
  ASSERT_TRUE(writer.ok());
  ASSERT_TRUE((*writer)->Finish().ok());
  auto bundle = ReadBundle(scratch / "b");
  ASSERT_TRUE(bundle.ok());
  EXPECT_TRUE(bundle->frames.empty());
  EXPECT_FALSE(fs::exists(scratch / "b" / "frames" / "s0000_left.png"));
}

TEST(BundleTest, InvalidHeaderIsRefused) {
  ScratchDir scratch;
  BundleHeader h = SmallHeader();
  h.camera.channels = 2;
  EXPECT_EQ(BundleWriter::Create(scratch / "x", h).status().code(), StatusCode::kInvalidArgument);
  h = SmallHeader();
  h.camera.model.fx = -1;
  EXPECT_EQ(BundleWriter::Create(scratch / "x", h).status().code(), StatusCode::kInvalidArgument);
}

TEST(BundleTest, MissingFrameIsNotFound) {
  ScratchDir scratch;
  WriteSmallBundle(scratch / "b", 2);
  fs::remove(scratch / "b" / "frames" / "s0001_off.png");
  auto bundle = ReadBundle(scratch / "b");
  EXPECT_EQ(bundle.status().code(), StatusCode::kNotFound);
  EXPECT_NE(bundle.status().message().find("s0001_off.png"), std::string::npos);
  auto lazy = ReadBundle(scratch / "b", {false});
  ASSERT_TRUE(lazy.ok());
  EXPECT_EQ(ReadFrame(*lazy, lazy->FindFrame(1, LaserState::kOff)).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(ReadBundle(scratch / "nothing").status().code(), StatusCode::kNotFound);
}

TEST(BundleTest, CorruptFrameIsCorruptData) {
  ScratchDir scratch;
  WriteSmallBundle(scratch / "b", 1);
  ASSERT_TRUE(WriteFileAtomically(scratch / "b" / "frames" / "s0000_left.png", "not a png").ok());
  auto bundle = ReadBundle(scratch / "b");
  ASSERT_TRUE(bundle.ok());
  EXPECT_EQ(ReadFrame(*bundle, 0).status().code(), StatusCode::kCorruptData);
}

// Each entry: a mutation of a valid bundle.json and the field its error must name.
TEST(BundleTest, BadJsonNamesTheField) {
  ScratchDir scratch;
  const std::string path = WriteSmallBundle(scratch / "b", 1);
  const std::string good = *ReadFile(path);
  ASSERT_TRUE(ParseBundleJson(good, "b").ok());
  struct Case {
    std::string from, to, field;
  };
  const std::vector<Case> cases = {
      {"\"format_version\": 1", "\"format_version\": 7", "format_version"},
      {"\"kind\": \"scan\"", "\"kind\": \"scam\"", "kind"},
      {"\"width\": 32", "\"width\": -32", "camera.width"},
      {"\"width\": 32", "\"width\": 1e9", "camera.width"},
      {"\"height\": 24", "\"height\": \"24\"", "camera.height"},
      {"\"laser\": \"left\"", "\"laser\": \"up\"", "frames[0].laser"},
      {"\"step\": 0,", "\"step\": -3,", "frames[0].step"},
      {"\"file\": \"frames/s0000_left.png\"", "\"file\": \"../../etc/passwd\"", "frames[0].file"},
      {"\"file\": \"frames/s0000_right.png\"", "\"file\": \"frames/s0000_left.png\"", "frames[1].file"},
      {"\"table_step_deg\"", "\"table_stepdeg\"", "table_step_deg"},
      {"\"trigger_seq\": 0", "\"trigger_seq\": 99999999999", "frames[0].trigger_seq"},
  };
  for (const Case& c : cases) {
    std::string text = good;
    const std::size_t at = text.find(c.from);
    ASSERT_NE(at, std::string::npos) << c.from;
    text.replace(at, c.from.size(), c.to);
    auto parsed = ParseBundleJson(text, "b/bundle.json");
    ASSERT_FALSE(parsed.ok()) << c.to;
    EXPECT_NE(parsed.status().message().find(c.field), std::string::npos) << parsed.status().ToString();
    EXPECT_NE(parsed.status().message().find("b/bundle.json"), std::string::npos);
  }
  // The target's table-top height: optional (unknown stays NaN), and refused when it is no height.
  const std::string target = "\"frames\": [";
  std::string with_target = good;
  with_target.replace(with_target.find(target), target.size(),
                      "\"target\": {\"kind\": \"table_checkerboard\", \"origin_height_mm\": 1e9}, " + target);
  auto bad_height = ParseBundleJson(with_target, "b/bundle.json");
  ASSERT_FALSE(bad_height.ok());
  EXPECT_NE(bad_height.status().message().find("target.origin_height_mm"), std::string::npos);
  with_target.replace(with_target.find("1e9"), 3, "12.5");
  auto good_height = ParseBundleJson(with_target, "b/bundle.json");
  ASSERT_TRUE(good_height.ok()) << good_height.status().ToString();
  EXPECT_EQ(good_height->header.target.origin_height_mm, 12.5);
  EXPECT_TRUE(std::isnan(ParseBundleJson(good, "b")->header.target.origin_height_mm));
  EXPECT_EQ(ParseBundleJson("{\"format\": ", "x").status().code(), StatusCode::kCorruptData);
  EXPECT_EQ(ParseBundleJson("[]", "x").status().code(), StatusCode::kCorruptData);
}

TEST(TruthTest, PlyMeshRoundTrip) {
  ScratchDir scratch;
  TruthMesh mesh;
  mesh.vertices = {{0, 0, 0}, {10.5f, 0, 0}, {0, 20.25f, -3}, {1, 2, 3}};
  mesh.colors = {{{255, 0, 0}}, {{0, 255, 0}}, {{0, 0, 255}}, {{1, 2, 3}}};
  mesh.faces = {{0, 1, 2}, {1, 3, 2}};
  ASSERT_TRUE(WritePlyMesh(scratch / "m.ply", mesh).ok());
  auto read = ReadPlyMesh(scratch / "m.ply");
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->vertices.size(), 4u);
  EXPECT_THAT(read->vertices[2], EigenNear(mesh.vertices[2], 0.0f));
  EXPECT_EQ(read->colors[3], mesh.colors[3]);
  ASSERT_EQ(read->faces.size(), 2u);
  EXPECT_EQ(read->faces[1], mesh.faces[1]);

  // Truncated, lying counts, bad indices.
  const std::string data = *ReadFile(scratch / "m.ply");
  ASSERT_TRUE(WriteFileAtomically(scratch / "t.ply", data.substr(0, data.size() - 5)).ok());
  EXPECT_EQ(ReadPlyMesh(scratch / "t.ply").status().code(), StatusCode::kCorruptData);
  std::string huge = data;
  huge.replace(huge.find("element vertex 4"), 16, "element vertex 999999999999");
  ASSERT_TRUE(WriteFileAtomically(scratch / "h.ply", huge).ok());
  EXPECT_EQ(ReadPlyMesh(scratch / "h.ply").status().code(), StatusCode::kCorruptData);
  TruthMesh bad = mesh;
  bad.faces.push_back({0, 1, 9});
  EXPECT_EQ(WritePlyMesh(scratch / "b.ply", bad).code(), StatusCode::kInvalidArgument);
  ASSERT_TRUE(
      WriteFileAtomically(scratch / "a.ply",
                          "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float "
                          "y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                          "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n")
          .ok());
  EXPECT_EQ(ReadPlyMesh(scratch / "a.ply").status().code(), StatusCode::kCorruptData);
}

TEST(TruthTest, LineTruthAndPosesRoundTrip) {
  ScratchDir scratch;
  std::vector<LinePoint> points(3);
  for (int i = 0; i < 3; ++i) {
    points[i].row = 10 + i;
    points[i].column = 100.123456789 + i;
    points[i].point_in_cam = Eigen::Vector3d(1.000000001 * i, -2.5, 300.123456789);
    points[i].point_in_world = Eigen::Vector3d(0.5, 1e-9, -40);
    points[i].object = i;
  }
  FrameRecord frame;
  frame.file = "frames/s0012_left.png";
  const fs::path path = LineTruthPath(scratch.path(), frame);
  EXPECT_EQ(path, scratch / "truth" / "lines" / "s0012_left.csv");
  ASSERT_TRUE(WriteLineTruth(path, points).ok());
  auto read = ReadLineTruth(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  ASSERT_EQ(read->size(), 3u);
  EXPECT_EQ((*read)[2].row, 12);
  EXPECT_NEAR((*read)[2].column, points[2].column, 1e-9);
  EXPECT_THAT((*read)[1].point_in_cam, EigenNear(points[1].point_in_cam, 1e-9));
  EXPECT_THAT((*read)[1].point_in_world, EigenNear(points[1].point_in_world, 1e-12));
  EXPECT_EQ((*read)[2].object, 2);

  ASSERT_TRUE(WriteFileAtomically(path, "# rotoscan line truth 1\nrow,column\n1,2,3\n").ok());
  EXPECT_EQ(ReadLineTruth(path).status().code(), StatusCode::kCorruptData);
  ASSERT_TRUE(WriteFileAtomically(path, "something else\n").ok());
  EXPECT_EQ(ReadLineTruth(path).status().code(), StatusCode::kCorruptData);

  std::vector<TargetPose> poses(2);
  poses[1].pose = 1;
  poses[1].step = 5;
  poses[1].cam_from_target =
      Eigen::Translation3d(1, 2, 300) * Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized());
  ASSERT_TRUE(WriteTargetPoses(scratch / "poses.csv", poses).ok());
  auto read_poses = ReadTargetPoses(scratch / "poses.csv");
  ASSERT_TRUE(read_poses.ok()) << read_poses.status().ToString();
  ASSERT_EQ(read_poses->size(), 2u);
  EXPECT_EQ((*read_poses)[1].step, 5);
  EXPECT_THAT((*read_poses)[1].cam_from_target.matrix(), EigenNear(poses[1].cam_from_target.matrix(), 1e-10));
}

}  // namespace
}  // namespace rotoscan::bundle

namespace rotoscan::bundle {
namespace {

namespace fs = std::filesystem;
using rotoscan::testing::ScratchDir;

FrameRecord Record(int step, LaserState laser) {
  FrameRecord r;
  r.step = step;
  r.laser = laser;
  r.trigger_seq = static_cast<uint32_t>(4 * step + static_cast<int>(laser));
  return r;
}

TEST(BundleResumeTest, InterruptedWriterKeepsItsFramesAndResumes) {
  ScratchDir scratch;
  const fs::path dir = scratch / "scan";
  const fs::path partial = BundleWriter::PartialDirectory(dir);
  {
    auto writer = BundleWriter::Create(dir, SmallHeader());
    ASSERT_TRUE(writer.ok());
    ASSERT_TRUE((*writer)->AddFrame(Record(0, LaserState::kLeft), TestImage(1)).ok());
    ASSERT_TRUE((*writer)->AddFrame(Record(0, LaserState::kRight), TestImage(2)).ok());
    // A second writer of the same bundle while this one runs is refused (lock).
    auto rival = BundleWriter::Create(dir, SmallHeader(), {false, true});
    EXPECT_EQ(rival.status().code(), StatusCode::kFailedPrecondition);
    EXPECT_NE(rival.status().message().find("another process"), std::string::npos);
  }  // destroyed without Finish(): an interruption
  ASSERT_TRUE(fs::is_directory(partial));
  EXPECT_FALSE(fs::exists(dir));
  // Without resume (or overwrite) the interrupted bundle is not touched.
  auto plain = BundleWriter::Create(dir, SmallHeader());
  EXPECT_EQ(plain.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(plain.status().message().find("interrupted"), std::string::npos);
  // Another header cannot resume it.
  BundleHeader other = SmallHeader();
  other.camera.laser_exposure_us = 500;
  EXPECT_EQ(BundleWriter::Create(dir, other, {false, true}).status().code(), StatusCode::kFailedPrecondition);

  auto writer = BundleWriter::Create(dir, SmallHeader(), {false, true});
  ASSERT_TRUE(writer.ok()) << writer.status().ToString();
  EXPECT_EQ((*writer)->resumed_frame_count(), 2u);
  EXPECT_TRUE((*writer)->HasFrame("frames/s0000_left.png"));
  EXPECT_FALSE((*writer)->HasFrame("frames/s0000_off.png"));
  // A resumed frame may be written again (it replaces the old one); a new one only once.
  ASSERT_TRUE((*writer)->AddFrame(Record(0, LaserState::kRight), TestImage(5)).ok());
  ASSERT_TRUE((*writer)->AddFrame(Record(0, LaserState::kOff), TestImage(3)).ok());
  EXPECT_EQ((*writer)->AddFrame(Record(0, LaserState::kOff), TestImage(3)).code(),
            StatusCode::kInvalidArgument);
  ASSERT_TRUE((*writer)->Finish().ok());
  EXPECT_FALSE(fs::exists(partial));
  auto bundle = ReadBundle(dir);
  ASSERT_TRUE(bundle.ok()) << bundle.status().ToString();
  ASSERT_EQ(bundle->frames.size(), 3u);
  EXPECT_EQ(cv::norm(*ReadFrame(*bundle, 0), TestImage(1), cv::NORM_INF), 0.0);  // kept from before
  EXPECT_EQ(cv::norm(*ReadFrame(*bundle, 1), TestImage(5), cv::NORM_INF), 0.0);  // replaced
  for (const char* bookkeeping : {"journal.jsonl", "header.json", ".lock"}) {
    EXPECT_FALSE(fs::exists(dir / bookkeeping)) << bookkeeping;
  }
}

TEST(BundleResumeTest, TornJournalLineAndLostFramesAreWrittenAgain) {
  ScratchDir scratch;
  const fs::path dir = scratch / "scan";
  const fs::path partial = BundleWriter::PartialDirectory(dir);
  {
    auto writer = BundleWriter::Create(dir, SmallHeader());
    ASSERT_TRUE(writer.ok());
    for (LaserState l : {LaserState::kLeft, LaserState::kRight, LaserState::kOff}) {
      ASSERT_TRUE((*writer)->AddFrame(Record(0, l), TestImage(1)).ok());
    }
  }
  // A crash in the middle of a journal line, and a frame file lost after its record.
  {
    std::ofstream journal(partial / "journal.jsonl", std::ios::app);
    journal << R"({"file": "frames/s0000_natural.png", "st)";
  }
  fs::remove(partial / "frames" / "s0000_right.png");
  auto writer = BundleWriter::Create(dir, SmallHeader(), {false, true});
  ASSERT_TRUE(writer.ok()) << writer.status().ToString();
  EXPECT_TRUE((*writer)->HasFrame("frames/s0000_left.png"));
  EXPECT_FALSE((*writer)->HasFrame("frames/s0000_right.png"));
  EXPECT_FALSE((*writer)->HasFrame("frames/s0000_natural.png"));
  EXPECT_EQ((*writer)->resumed_frame_count(), 2u);
  ASSERT_TRUE((*writer)->AddFrame(Record(0, LaserState::kNatural), TestImage(4)).ok());
  writer->reset();
  // Interrupted again: the journal continued cleanly after the torn line.
  auto again = BundleWriter::Create(dir, SmallHeader(), {false, true});
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_EQ((*again)->resumed_frame_count(), 3u);
  again->reset();
  // A journal damaged in the middle is reported, not guessed at.
  {
    std::ofstream journal(partial / "journal.jsonl", std::ios::trunc);
    journal << "{not json\n" << R"({"file": "frames/s0000_left.png"})" << "\n";
  }
  auto damaged = BundleWriter::Create(dir, SmallHeader(), {false, true});
  EXPECT_EQ(damaged.status().code(), StatusCode::kCorruptData);
  // overwrite starts again.
  auto fresh = BundleWriter::Create(dir, SmallHeader(), {true, false});
  ASSERT_TRUE(fresh.ok()) << fresh.status().ToString();
  EXPECT_EQ((*fresh)->resumed_frame_count(), 0u);
  EXPECT_FALSE(fs::exists(partial / "frames" / "s0000_left.png"));
}

TEST(BundleResumeTest, WriterWithoutFramesLeavesNothing) {
  ScratchDir scratch;
  { ASSERT_TRUE(BundleWriter::Create(scratch / "empty", SmallHeader()).ok()); }
  EXPECT_FALSE(fs::exists(BundleWriter::PartialDirectory(scratch / "empty")));
  EXPECT_FALSE(fs::exists(scratch / "empty"));
}

TEST(BundleTest, PlacementRoundTripsAndDefaultsToZero) {
  BundleHeader header = SmallHeader();
  header.placement = 2;
  auto parsed = ParseBundleJson(BundleJson(header, {}), "test");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_EQ(parsed->header.placement, 2);
  std::string old = BundleJson(header, {});
  const size_t at = old.find("\"placement\"");
  ASSERT_NE(at, std::string::npos);
  old.erase(at, old.find('\n', at) - at + 1);  // a bundle written before placements existed
  parsed = ParseBundleJson(old, "old");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_EQ(parsed->header.placement, 0);
  std::string bad = BundleJson(header, {});
  bad.replace(bad.find("\"placement\": 2"), 14, "\"placement\": 999");
  EXPECT_EQ(ParseBundleJson(bad, "bad").status().code(), StatusCode::kCorruptData);
}

// A shared off frame (format_version 2): written and read back; a version-1 bundle (every bundle before
// it) reads as before; the field in a version-1 file, and version 2's flag asked of a version-1 header,
// are refused; a version above this build's is refused naming the field.
TEST(BundleTest, SharedOffFrameNeedsVersionTwoAndRoundTrips) {
  BundleHeader header = SmallHeader();
  EXPECT_EQ(header.format_version, 1);
  const std::string v1 = BundleJson(header, {});
  EXPECT_EQ(v1.find("shared_off_frame"), std::string::npos);  // unchanged for bundles without it
  auto parsed = ParseBundleJson(v1, "v1");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_FALSE(parsed->header.shared_off_frame);
  header.shared_off_frame = true;
  header.format_version = 2;
  parsed = ParseBundleJson(BundleJson(header, {}), "v2");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_TRUE(parsed->header.shared_off_frame);
  EXPECT_EQ(parsed->header.format_version, 2);
  std::string bad = BundleJson(header, {});
  bad.replace(bad.find("\"format_version\": 2"), 19, "\"format_version\": 1");
  auto refused = ParseBundleJson(bad, "bad");
  EXPECT_EQ(refused.status().code(), StatusCode::kCorruptData);
  EXPECT_NE(refused.status().message().find("shared_off_frame"), std::string::npos) << refused.status().ToString();
  bad.replace(bad.find("\"format_version\": 1"), 19, "\"format_version\": 3");
  EXPECT_EQ(ParseBundleJson(bad, "bad").status().code(), StatusCode::kCorruptData);
  ScratchDir scratch;
  header.format_version = 1;
  EXPECT_EQ(BundleWriter::Create(scratch / "b", header).status().code(), StatusCode::kInvalidArgument);
}

TEST(TruthTest, PlacementTruthRoundTrips) {
  ScratchDir scratch;
  PlacementTruth truth;
  truth.placement = 1;
  truth.table_from_reference = Eigen::Translation3d(1.5, -2.25, 17.0) *
                               Eigen::AngleAxisd(1.2, Eigen::Vector3d(0.3, 1, 0.2).normalized());
  const fs::path path = TruthPlacementPath(scratch.path());
  ASSERT_TRUE(WritePlacementTruth(path, truth).ok());
  auto read = ReadPlacementTruth(path);
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(read->placement, 1);
  EXPECT_THAT(read->table_from_reference.matrix(), EigenNear(truth.table_from_reference.matrix(), 1e-12));
  ASSERT_TRUE(WriteFileAtomically(path, "# rotoscan placement 1\nplacement\n1,2,3\n").ok());
  EXPECT_EQ(ReadPlacementTruth(path).status().code(), StatusCode::kCorruptData);
  ASSERT_TRUE(WriteFileAtomically(path, "# rotoscan placement 1\nplacement\n1,2,0,0,0,1,0,0,0,1,0,0,0\n").ok());
  EXPECT_EQ(ReadPlacementTruth(path).status().code(), StatusCode::kCorruptData);  // not a rotation
}

}  // namespace
}  // namespace rotoscan::bundle
