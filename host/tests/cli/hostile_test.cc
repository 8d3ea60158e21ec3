// Issue 20: hostile inputs and faults against every command. Each case is generated here (no binaries kept
// in the tree), runs the command through Main() as the program does, and checks the exit code (1 or 2),
// that the message names the file or field, and that nothing was left behind or replaced. The regression
// test of each of the issue's 13 defects is named after it.
#include <gtest/gtest.h>

#include <cmath>
#include <csignal>
#include <cstdlib>
#include <fstream>
#include <random>
#include <sstream>
#include <sys/stat.h>
#include <sys/sysmacros.h>

#include <opencv2/imgcodecs.hpp>

#include "command.h"
#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/mesh/mesh.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"
#include "testing/testing.h"

namespace rotoscan::cli {
namespace {
namespace fs = std::filesystem;
using rotoscan::testing::ListTree;
using rotoscan::testing::RunWithFullDisk;
using rotoscan::testing::ScratchDir;

struct Outcome {
  int code;
  std::string out, err;
};

Outcome Call(const std::vector<std::string>& args) {
  std::vector<const char*> argv{"rotoscan", "--no-progress"};
  for (const auto& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int code = Main(static_cast<int>(argv.size()), argv.data(), out, err);
  return {code, out.str(), err.str()};
}

std::string Text(const fs::path& path) {
  auto text = ReadFile(path);
  return text.ok() ? *text : std::string("<") + text.status().ToString() + ">";
}

void WriteText(const fs::path& path, const std::string& text) { ASSERT_TRUE(WriteFileAtomically(path, text).ok()); }

// A sphere of 30 mm with outward normals: a cloud that meshes at depth 5 in a fraction of a second.
cloud::PointCloud Sphere(int n = 3000) {
  cloud::PointCloud sphere;
  std::mt19937 rng(7);
  std::normal_distribution<float> normal(0.f, 1.f);
  for (int i = 0; i < n; ++i) {
    cloud::CloudPoint p;
    p.normal = Eigen::Vector3f(normal(rng), normal(rng), normal(rng)).normalized();
    p.position_in_table = 30.f * p.normal + Eigen::Vector3f(0, 0, 40);
    p.color = {200, 180, 40};
    sphere.points.push_back(p);
  }
  return sphere;
}

// A PNG that declares `width` x `height` gray pixels and holds none (OpenCV refuses, or throws, at the size).
std::string PngDeclaring(uint32_t width, uint32_t height) {
  auto crc32 = [](const std::string& bytes) {
    uint32_t crc = 0xFFFFFFFFu;
    for (unsigned char c : bytes) {
      crc ^= c;
      for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return crc ^ 0xFFFFFFFFu;
  };
  auto be32 = [](uint32_t v) {
    return std::string{static_cast<char>(v >> 24), static_cast<char>(v >> 16), static_cast<char>(v >> 8),
                       static_cast<char>(v)};
  };
  auto chunk = [&](const std::string& type, const std::string& data) {
    return be32(static_cast<uint32_t>(data.size())) + type + data + be32(crc32(type + data));
  };
  const std::string ihdr = be32(width) + be32(height) + std::string("\x08\x00\x00\x00\x00", 5);
  return std::string("\x89PNG\r\n\x1a\n", 8) + chunk("IHDR", ihdr) + chunk("IEND", "");
}

// The value list of `key`'s OpenCV matrix in a YAML text replaced by `data` ("1e300, 0, 0").
// The first value of `"field":` in a JSON text replaced by `value` (the value runs to the next ',' or '}').
// (No std::regex: GCC 12's -Wmaybe-uninitialized fires inside it in the sanitized build.)
std::string ReplaceFirstValue(const std::string& json, const std::string& field, const std::string& value) {
  const std::string key = "\"" + field + "\":";
  const std::size_t at = json.find(key);
  if (at == std::string::npos) return json;
  std::size_t begin = at + key.size();
  while (begin < json.size() && json[begin] == ' ') ++begin;
  const std::size_t end = json.find_first_of(",}", begin);
  return json.substr(0, begin) + value + json.substr(end);
}

std::string ReplaceYamlData(const std::string& yaml, const std::string& key, const std::string& data) {
  const size_t at = yaml.find(key + ":");
  const size_t open = yaml.find('[', at);
  const size_t close = yaml.find(']', open);
  if (at == std::string::npos || open == std::string::npos || close == std::string::npos) return yaml;
  return yaml.substr(0, open + 1) + " " + data + " " + yaml.substr(close);
}

constexpr const char* kTinyScene =
    R"({"seed": 3, "steps": 3, "camera": {"width": 320, "height": 240, "hfov_deg": 20, "supersampling": 1},
        "objects": [{"type": "sphere", "radius_mm": 20}]})";

// One small scan bundle (3 steps at 320x240, 257 points) and a good cloud, shared by the cases (read only).
class HostileTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    shared_ = new ScratchDir;
    ASSERT_TRUE(WriteFileAtomically(*shared_ / "scene.json", kTinyScene).ok());
    const Outcome r = Call({"simulate", (*shared_ / "scene.json").string(), "--out", (*shared_ / "bundle").string(),
                        "--threads", "1"});
    ASSERT_EQ(r.code, kExitOk) << r.err;
    ASSERT_TRUE(cloud::WritePly(*shared_ / "cloud.ply", Sphere()).ok());
  }
  static void TearDownTestSuite() {
    delete shared_;
    shared_ = nullptr;
  }
  static fs::path Shared(const std::string& name) { return *shared_ / name; }

  // Runs a case that must fail: exit `code`, the message holding `named`, the scratch directory as before.
  void ExpectRefused(const std::vector<std::string>& args, int code, const std::string& named) {
    const std::vector<std::string> before = ListTree(dir_.path());
    const Outcome r = Call(args);
    EXPECT_EQ(r.code, code) << ::testing::PrintToString(args) << "\n" << r.err;
    EXPECT_NE(r.err.find(named), std::string::npos)
        << ::testing::PrintToString(args) << ": message does not name '" << named << "':\n" << r.err;
    EXPECT_EQ(r.err.find("internal error"), std::string::npos) << r.err;
    EXPECT_EQ(ListTree(dir_.path()), before) << ::testing::PrintToString(args) << " left something behind";
  }
  std::string P(const std::string& name) const { return (dir_ / name).string(); }

  ScratchDir dir_;
  static ScratchDir* shared_;
};
ScratchDir* HostileTest::shared_ = nullptr;

// Defect 1: a full disk fails the command, keeps the previous file and leaves no new one. The program runs
// in a child process whose files may not grow past a limit, with SIGXFSZ ignored (a write fails with EFBIG).
TEST_F(HostileTest, FullDiskFailsAndKeepsThePreviousFile) {
  WriteText(dir_ / "mesh.ply", "previous mesh");
  WriteText(dir_ / "mesh.png", "previous preview");
  std::string err;
  const int code = rotoscan::testing::RunProgram(
      {ROTOSCAN_CLI_PATH, "--no-progress", "mesh", Shared("cloud.ply").string(), "--out", P("mesh.ply"), "--method",
       "poisson", "--depth", "5", "--threads", "1"},
      20000, /*kill_at_limit=*/false, &err);
  EXPECT_EQ(code, kExitFailure) << err;
  EXPECT_NE(err.find("mesh.ply"), std::string::npos) << err;
  EXPECT_EQ(Text(dir_ / "mesh.ply"), "previous mesh");
  EXPECT_EQ(Text(dir_ / "mesh.png"), "previous preview");
  EXPECT_EQ(ListTree(dir_.path()), (std::vector<std::string>{"mesh.ply", "mesh.png"}));
  // The YAML writers (calib.yaml, camera.yaml, rig.yaml) go through memory and the same writer.
  const Result<geometry::Rig> rig = geometry::ReadRigYaml(bundle::TruthRigPath(Shared("bundle")));
  ASSERT_TRUE(rig.ok()) << rig.status().ToString();
  WriteText(dir_ / "calib.yaml", "previous calibration");
  EXPECT_EQ(RunWithFullDisk(300, [&] { return geometry::WriteRigYaml(dir_ / "calib.yaml", *rig).ok() ? 0 : 1; }),
            1);
  calib::CameraCalibration camera;
  camera.camera = rig->camera;
  WriteText(dir_ / "camera.yaml", "previous camera");
  EXPECT_EQ(
      RunWithFullDisk(300, [&] { return calib::WriteCameraYaml(dir_ / "camera.yaml", camera).ok() ? 0 : 1; }), 1);
  EXPECT_EQ(Text(dir_ / "calib.yaml"), "previous calibration");
  EXPECT_EQ(Text(dir_ / "camera.yaml"), "previous camera");
  EXPECT_EQ(ListTree(dir_.path()), (std::vector<std::string>{"calib.yaml", "camera.yaml", "mesh.ply", "mesh.png"}));
  // With room, they are written.
  ASSERT_TRUE(geometry::WriteRigYaml(dir_ / "calib.yaml", *rig).ok());
  EXPECT_TRUE(geometry::ReadRigYaml(dir_ / "calib.yaml").ok());
}

// Issue 20, the two-file commit: the mesh (fusion: small) fits under the limit, its preview does not. The
// mesh must not be replaced alone: both keep their previous content. Then an OBJ, whose material and texture
// are committed with it, the same.
TEST_F(HostileTest, MeshAndPreviewAreCommittedTogether) {
  const std::vector<std::string> args = {ROTOSCAN_CLI_PATH, "--no-progress", "mesh", Shared("cloud.ply").string(),
                                         "--out", P("mesh.ply"), "--voxel", "8", "--threads", "1"};
  std::string err;
  ASSERT_EQ(rotoscan::testing::RunProgram(args, 0, false, &err), kExitOk) << err;
  const auto mesh_size = fs::file_size(dir_ / "mesh.ply"), preview_size = fs::file_size(dir_ / "mesh.png");
  ASSERT_LT(mesh_size * 2, preview_size);  // the limit below lies between them
  WriteText(dir_ / "mesh.ply", "previous mesh");
  WriteText(dir_ / "mesh.png", "previous preview");
  EXPECT_EQ(rotoscan::testing::RunProgram(args, (mesh_size + preview_size) / 2, false, &err), kExitFailure) << err;
  EXPECT_NE(err.find("mesh.png"), std::string::npos) << err;
  EXPECT_EQ(Text(dir_ / "mesh.ply"), "previous mesh");
  EXPECT_EQ(Text(dir_ / "mesh.png"), "previous preview");
  EXPECT_EQ(ListTree(dir_.path()), (std::vector<std::string>{"mesh.ply", "mesh.png"}));
  // An OBJ: mesh, material, texture and preview together; a full disk leaves none of them.
  std::vector<std::string> obj = args;
  obj[5] = P("m.obj");
  EXPECT_EQ(rotoscan::testing::RunProgram(obj, 2000, false, &err), kExitFailure) << err;
  EXPECT_EQ(ListTree(dir_.path()), (std::vector<std::string>{"mesh.ply", "mesh.png"}));
  ASSERT_EQ(rotoscan::testing::RunProgram(obj, 0, false, &err), kExitOk) << err;
  EXPECT_EQ(ListTree(dir_.path()), (std::vector<std::string>{"m.mtl", "m.obj", "m.png", "m_texture.png", "mesh.ply",
                                                             "mesh.png"}));
}

// A process killed in the middle of writing its output (SIGXFSZ at the limit) leaves the previous file and
// nothing else.
TEST_F(HostileTest, KillInTheMiddleOfAWriteLeavesThePreviousFile) {
  WriteText(dir_ / "cloud.ply", "previous cloud");
  std::string err;
  const int code = rotoscan::testing::RunProgram(
      {ROTOSCAN_CLI_PATH, "--no-progress", "process", Shared("bundle").string(), "--out", P("cloud.ply"),
       "--threads", "1"},
      4096, /*kill_at_limit=*/true, &err);
  EXPECT_EQ(code, 128 + SIGXFSZ) << err;
  EXPECT_EQ(Text(dir_ / "cloud.ply"), "previous cloud");
  EXPECT_EQ(ListTree(dir_.path()), std::vector<std::string>{"cloud.ply"});
}

// An output directory that disappears while the command works: an error naming it, nothing left.
TEST_F(HostileTest, OutputDirectoryRemovedDuringTheWork) {
  struct RemoveOnFirstStep : Progress {
    fs::path dir;
    void Begin(const std::string&, uint64_t) override {}
    void Advance(uint64_t) override { fs::remove_all(dir); }
    void End() override {}
  };
  fs::create_directories(dir_ / "out");
  RemoveOnFirstStep progress;
  progress.dir = dir_ / "out";
  std::ostringstream out, err;
  const std::string cloud = Shared("cloud.ply").string(), mesh = P("out/m.ply");
  const std::vector<const char*> argv{"rotoscan", "mesh", cloud.c_str(), "--out", mesh.c_str(), "--depth", "5",
                                    "--threads", "1"};
  Context context{&out, &err, &progress};
  CLI::App app;
  int code = -1;
  RegisterMesh(app, context, &code);
  app.parse(static_cast<int>(argv.size()), argv.data());
  EXPECT_EQ(code, kExitFailure);
  EXPECT_NE(err.str().find("out"), std::string::npos) << err.str();
  EXPECT_TRUE(ListTree(dir_.path()).empty());
}

// Defect 2.
TEST_F(HostileTest, MeshDegenerateCloudWithNoExtentIsAnError) {
  std::string ascii = "ply\nformat ascii 1.0\nelement vertex 100\nproperty float x\nproperty float y\n"
                      "property float z\nproperty float nx\nproperty float ny\nproperty float nz\nend_header\n";
  for (int i = 0; i < 100; ++i) ascii += "1 2 3 0 0 1\n";
  WriteText(dir_ / "same.ply", ascii);
  ExpectRefused({"mesh", P("same.ply"), "--out", P("m.ply"), "--depth", "5"}, kExitFailure, "no extent");
  cloud::PointCloud tiny;
  for (int i = 0; i < 200; ++i) {
    cloud::CloudPoint p;
    p.position_in_table = Eigen::Vector3f(1e-40f * static_cast<float>(i % 7), 1e-40f * static_cast<float>(i % 5), 0);
    p.normal = Eigen::Vector3f(0, 0, 1);
    tiny.points.push_back(p);
  }
  ASSERT_TRUE(cloud::WritePly(dir_ / "denormal.ply", tiny).ok());
  ExpectRefused({"mesh", P("denormal.ply"), "--out", P("m.ply"), "--depth", "5"}, kExitFailure, "no extent");
}

// Defect 12 (first case): a cloud flat along the up axis gave a mesh 3.2e13 mm wide.
TEST_F(HostileTest, MeshFlatCloudIsAnError) {
  cloud::PointCloud flat;
  for (int i = 0; i < 400; ++i) {
    cloud::CloudPoint p;
    p.position_in_table = Eigen::Vector3f(static_cast<float>(i % 20), static_cast<float>(i / 20), 5);
    p.normal = Eigen::Vector3f(0, 0, 1);
    flat.points.push_back(p);
  }
  ASSERT_TRUE(cloud::WritePly(dir_ / "flat.ply", flat).ok());
  ExpectRefused({"mesh", P("flat.ply"), "--out", P("m.ply"), "--depth", "5"}, kExitFailure, "flat");
}

// Defect 3: a wide-angle camera with the default distortion gave NaN rays and an Embree abort.
TEST_F(HostileTest, SimulateWideAngleCameraIsAnError) {
  WriteText(dir_ / "wide.json",
            R"({"camera":{"width":160,"height":120,"hfov_deg":120},"objects":[{"type":"sphere","radius_mm":20}]})");
  ExpectRefused({"simulate", P("wide.json"), "--out", P("b")}, kExitFailure, "camera");
  // 110 degrees can be inverted: the check does not refuse what works.
  Result<sim::Scene> scene = sim::ParseScene(
      R"({"camera":{"width":160,"height":120,"hfov_deg":110},"objects":[{"type":"sphere","radius_mm":20}]})",
      dir_.path(), "scene");
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
}

// Defect 4.
TEST_F(HostileTest, OutputThatIsADeviceFifoOrSymlinkIsNeverReplaced) {
  ASSERT_EQ(::mkfifo((dir_ / "fifo").c_str(), 0644), 0);
  fs::create_symlink("/dev/null", dir_ / "null");
  fs::create_symlink(Shared("cloud.ply"), dir_ / "link.ply");
  for (const std::string& out : {P("fifo"), P("null"), P("link.ply")}) {
    ExpectRefused({"process", Shared("bundle").string(), "--out", out}, kExitFailure, out);
    ExpectRefused({"extract", "--on", Shared("cloud.ply").string(), "--off", Shared("cloud.ply").string(), "--out",
                   out},
                  kExitFailure, out);
  }
  EXPECT_TRUE(fs::is_fifo(fs::symlink_status(dir_ / "fifo")));
  // A character device: our own node like /dev/null where we may make one (never /dev/null itself: a
  // broken check would replace the system's).
  if (::mknod((dir_ / "device").c_str(), S_IFCHR | 0666, makedev(1, 3)) == 0) {
    ExpectRefused({"mesh", Shared("cloud.ply").string(), "--out", P("m.ply"), "--preview", P("device")},
                  kExitFailure, "a device");
    ExpectRefused({"calibrate", Shared("bundle").string(), "--out", P("device")}, kExitFailure, "a device");
    EXPECT_TRUE(fs::is_character_file(dir_ / "device"));
  }
}

// Defect 5.
TEST_F(HostileTest, ResumeChecksTheSceneAndWhatIsOnDisk) {
  // An interrupted run: cancelled after the first step.
  struct StopAfter : Progress {
    int left;
    explicit StopAfter(int n) : left(n) {}
    void Begin(const std::string&, uint64_t) override {}
    void Advance(uint64_t) override { --left; }
    void End() override {}
    bool Cancelled() const override { return left <= 0; }
  };
  Result<sim::Scene> scene = sim::LoadScene(Shared("scene.json"));
  ASSERT_TRUE(scene.ok());
  sim::SimulateOptions options;
  options.out = dir_ / "b";
  options.threads = 1;
  StopAfter stop(1);
  ASSERT_EQ(sim::Simulate(*scene, options, &stop).code(), StatusCode::kCancelled);
  ASSERT_TRUE(fs::is_directory(dir_ / "b.partial"));
  // Another scene (a larger sphere: the same header): refused, the partial bundle untouched.
  WriteText(dir_ / "other.json",
            ReplaceFirstValue(kTinyScene, "radius_mm", "25"));
  const std::vector<std::string> partial = ListTree(dir_ / "b.partial");
  Outcome r = Call({"simulate", P("other.json"), "--out", P("b"), "--resume", "--threads", "1"});
  EXPECT_EQ(r.code, kExitFailure);
  EXPECT_NE(r.err.find("another scene"), std::string::npos) << r.err;
  EXPECT_EQ(ListTree(dir_ / "b.partial"), partial);
  // Damage on disk: a 0-byte frame and a stray temporary file are not trusted.
  fs::path frame;
  for (const auto& entry : fs::directory_iterator(dir_ / "b.partial" / "frames")) frame = entry.path();
  ASSERT_FALSE(frame.empty());
  std::ofstream(frame, std::ios::trunc).close();
  WriteText(dir_ / "b.partial" / "frames" / "s0001_left.png.tmp-99999-0", "half");
  r = Call({"simulate", Shared("scene.json").string(), "--out", P("b"), "--resume", "--threads", "1"});
  ASSERT_EQ(r.code, kExitOk) << r.err;
  Result<bundle::Bundle> b = bundle::ReadBundle(dir_ / "b");
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  EXPECT_EQ(b->frames.size(), 12u);
  for (std::size_t i = 0; i < b->frames.size(); ++i) {
    EXPECT_TRUE(bundle::ReadFrame(*b, i).ok()) << b->frames[i].file;
  }
  for (const std::string& name : ListTree(dir_.path())) {
    EXPECT_EQ(name.find(".tmp-"), std::string::npos) << name;
  }
  // The resumed bundle is the same as one rendered at once (the same frames, bit for bit).
  Result<bundle::Bundle> whole = bundle::ReadBundle(Shared("bundle"));
  ASSERT_TRUE(whole.ok());
  for (std::size_t i = 0; i < b->frames.size(); ++i) {
    EXPECT_EQ(Text(b->FramePath(b->frames[i])), Text(whole->FramePath(whole->frames[i]))) << b->frames[i].file;
  }
}

// Defect 6.
TEST_F(HostileTest, ProcessAbsurdCalibrationOrNoPointIsAnError) {
  const std::string truth = Text(bundle::TruthRigPath(Shared("bundle")));
  WriteText(dir_ / "far.yaml", ReplaceYamlData(truth, "axis_point", "1e300, 0., 0."));
  ExpectRefused({"process", Shared("bundle").string(), "--calib", P("far.yaml"), "--out", P("c.ply")}, kExitFailure,
                "axis_point");
  for (const char* quality : {"2", "nan", "-1"}) {
    ExpectRefused({"process", Shared("bundle").string(), "--out", P("c.ply"), "--min-quality", quality},
                  kExitFailure, "min_quality");
  }
  // A tiny focal length: no point, no file.
  WriteText(dir_ / "away.yaml", ReplaceYamlData(truth, "K", "1e-3, 0., 160., 0., 1e-3, 120., 0., 0., 1."));
  ExpectRefused({"process", Shared("bundle").string(), "--calib", P("away.yaml"), "--out", P("c.ply")}, kExitFailure,
                "no point");
}

// Defect 7.
TEST_F(HostileTest, OutputThatIsAnInputIsRefused) {
  const std::string cloud = Shared("cloud.ply").string();
  const std::string before = Text(cloud);
  ExpectRefused({"mesh", cloud, "--out", cloud}, kExitFailure, "is also an input");
  ExpectRefused({"mesh", cloud, "--out", P("m.ply"), "--preview", P("m.ply")}, kExitFailure, "--preview");
  ExpectRefused({"extract", "--on", cloud, "--off", P("x.png"), "--out", cloud}, kExitFailure, "is also an input");
  ExpectRefused({"process", Shared("bundle").string(), "--calib", cloud, "--out", cloud}, kExitFailure,
                "is also an input");
  ExpectRefused({"evaluate", cloud, "--truth", Shared("bundle").string(), "--report", cloud}, kExitFailure,
                "is also an input");
  ExpectRefused({"simulate", Shared("scene.json").string(), "--out", Shared("").string()}, kExitFailure,
                "is also an input");
  EXPECT_EQ(Text(cloud), before);
}

// Defect 8: outputs are checked before the work, and a failure leaves no partial result.
TEST_F(HostileTest, OutputPathsAreCheckedBeforeTheWork) {
  ExpectRefused({"calibrate", Shared("bundle").string(), "--out", P("cal.yaml"), "--report", P("nodir/r.json")},
                kExitFailure, "nodir");
  ExpectRefused({"calibrate", Shared("bundle").string(), "--out", P("nodir/cal.yaml")}, kExitFailure, "nodir");
  ExpectRefused({"calibrate", "camera", "--images", Shared("").string(), "--pattern", "9x6", "--square", "25",
                 "--out", P("nodir/camera.yaml")},
                kExitFailure, "nodir");
  ExpectRefused({"process", Shared("bundle").string(), "--out", P("nodir/c.ply")}, kExitFailure, "nodir");
  ExpectRefused({"simulate", Shared("scene.json").string(), "--out", P("nodir/b")}, kExitFailure, "nodir");
  WriteText(dir_ / "file", "x");
  ExpectRefused({"simulate", Shared("scene.json").string(), "--out", P("file")}, kExitFailure, "not a directory");
  ExpectRefused({"mesh", Shared("cloud.ply").string(), "--out", P("m.vrml")}, kExitFailure, "m.vrml");
}

// Defect 9.
TEST_F(HostileTest, InterruptedOverwriteCanBeResumed) {
  struct StopAt : Progress {
    int left = 1;
    void Begin(const std::string&, uint64_t) override {}
    void Advance(uint64_t) override { --left; }
    void End() override {}
    bool Cancelled() const override { return left <= 0; }
  };
  fs::create_directories(dir_ / "b");
  WriteText(dir_ / "b" / "old", "the previous bundle");
  Result<sim::Scene> scene = sim::LoadScene(Shared("scene.json"));
  ASSERT_TRUE(scene.ok());
  sim::SimulateOptions options;
  options.out = dir_ / "b";
  options.threads = 1;
  options.overwrite = true;
  StopAt stop;
  const Status interrupted = sim::Simulate(*scene, options, &stop);
  ASSERT_EQ(interrupted.code(), StatusCode::kCancelled);
  EXPECT_NE(interrupted.message().find("--resume"), std::string::npos);
  EXPECT_EQ(Text(dir_ / "b" / "old"), "the previous bundle");  // kept until the new one is complete
  const Outcome r = Call({"simulate", Shared("scene.json").string(), "--out", P("b"), "--resume", "--threads", "1"});
  ASSERT_EQ(r.code, kExitOk) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "b" / "old"));
  EXPECT_FALSE(fs::exists(dir_ / "b.partial"));
  EXPECT_TRUE(bundle::ReadBundle(dir_ / "b").ok());
}

// Defect 10.
TEST_F(HostileTest, ImageDeclaringHugeSizeIsAnError) {
  WriteText(dir_ / "huge.png", PngDeclaring(100000, 100000));
  ExpectRefused({"extract", "--on", P("huge.png"), "--off", P("huge.png"), "--out", P("l.csv")}, kExitFailure,
                "huge.png");
  // In an image folder it is skipped like any unreadable file (and the folder then has too few views).
  fs::create_directories(dir_ / "images");
  WriteText(dir_ / "images" / "huge.png", PngDeclaring(100000, 100000));
  ExpectRefused({"calibrate", "camera", "--images", P("images"), "--pattern", "9x6", "--square", "25", "--out",
                 P("camera.yaml")},
                kExitFailure, "could be read");
}

// Defect 13, raw libpng lines: a PNG with a corrupt chunk (a CRC mismatch, a torn IDAT) gives our clear
// error naming the file and nothing from libpng on stderr (the program runs in a child process, so that
// what libpng would print with fprintf is caught as well).
TEST_F(HostileTest, CorruptPngPrintsNoRawLibpngLines) {
  cv::Mat gray(48, 64, CV_8UC1);
  cv::randu(gray, 0, 255);
  std::vector<uchar> png;
  ASSERT_TRUE(cv::imencode(".png", gray, png));
  WriteText(dir_ / "good.png", std::string(png.begin(), png.end()));
  std::string crc(png.begin(), png.end());
  const std::size_t idat = crc.find("IDAT");
  ASSERT_NE(idat, std::string::npos);
  crc[idat + 10] = static_cast<char>(crc[idat + 10] ^ 0x5a);  // the chunk's data no longer matches its CRC
  WriteText(dir_ / "crc.png", crc);
  WriteText(dir_ / "torn.png", std::string(png.begin(), png.begin() + static_cast<std::ptrdiff_t>(idat + 40)));
  for (const char* bad : {"crc.png", "torn.png"}) {
    std::string err;
    const int code = rotoscan::testing::RunProgram(
        {ROTOSCAN_CLI_PATH, "--no-progress", "extract", "--on", P(bad), "--off", P("good.png"), "--out", P("l.csv")},
        0, false, &err);
    EXPECT_EQ(code, kExitFailure) << err;
    EXPECT_NE(err.find(bad), std::string::npos) << err;
    EXPECT_EQ(err.find("libpng"), std::string::npos) << err;
    EXPECT_FALSE(fs::exists(dir_ / "l.csv"));
  }
  // The good one still reads.
  std::string err;
  EXPECT_EQ(rotoscan::testing::RunProgram({ROTOSCAN_CLI_PATH, "--no-progress", "extract", "--on", P("good.png"),
                                           "--off", P("good.png"), "--out", P("l.csv")},
                                          0, false, &err),
            kExitOk)
      << err;
}

// Defect 11.
TEST_F(HostileTest, PatternOverflowIsAnError) {
  for (const char* option : {"--pattern", "--charuco"}) {
    ExpectRefused({"calibrate", "camera", "--images", Shared("").string(), option, "4294967305x6", "--square", "25",
                   "--marker", "15", "--out", P("camera.yaml")},
                  kExitFailure, "4294967305x6");
  }
  ExpectRefused({"calibrate", "camera", "--images", Shared("").string(), "--pattern", "9x6x", "--square", "25",
                 "--out", P("camera.yaml")},
                kExitFailure, "9x6x");
}

// Defect 12 (the others).
TEST_F(HostileTest, AbsurdValuesAreRefused) {
  ExpectRefused({"mesh", Shared("cloud.ply").string(), "--out", P("m.ply"), "--trim", "nan"}, kExitFailure, "trim");
  // A bundle with an angle of 1e300 degrees, and one with a pose in a scan bundle.
  fs::copy(Shared("bundle"), dir_ / "b", fs::copy_options::recursive);
  const std::string json = Text(dir_ / "b" / "bundle.json");
  WriteText(dir_ / "b" / "bundle.json",
            ReplaceFirstValue(json, "table_angle_deg", "1e300"));
  ExpectRefused({"process", P("b"), "--out", P("c.ply")}, kExitFailure, "table_angle_deg");
  WriteText(dir_ / "b" / "bundle.json",
            ReplaceFirstValue(json, "pose", "2"));
  ExpectRefused({"process", P("b"), "--out", P("c.ply")}, kExitFailure, "pose");
  WriteText(dir_ / "b" / "bundle.json", json);
  ExpectRefused({"bench", "accuracy", "--steps", "0"}, kExitUsage, "steps");
  ::setenv("ROTOSCAN_LOG_LEVEL", "loud", 1);
  const Outcome r = Call({"mesh", "--help"});
  ::unsetenv("ROTOSCAN_LOG_LEVEL");
  EXPECT_EQ(r.code, kExitUsage);
  EXPECT_NE(r.err.find("ROTOSCAN_LOG_LEVEL"), std::string::npos) << r.err;
}

// Defect 13.
TEST_F(HostileTest, MessagesSayWhatIsWrong) {
  fs::create_directories(dir_ / "calib.yaml");
  ExpectRefused({"process", Shared("bundle").string(), "--calib", P("calib.yaml"), "--out", P("c.ply")},
                kExitFailure, "not a regular file");
  ExpectRefused({"frobnicate"}, kExitUsage, "unknown command 'frobnicate'");
  WriteText(dir_ / "demo-file", "x");
  ExpectRefused({"demo", "--data", rotoscan::testing::DataPath("").string(), "--out", P("demo-file")}, kExitFailure,
                "demo-file");
  ExpectRefused({"bench", "foo"}, kExitUsage, "unknown benchmark 'foo'");
  // calibrate lamp never writes the calibration into the sphere's bundle (it would replace one of its files).
  fs::create_directories(dir_ / "sphere");
  WriteText(dir_ / "sphere" / "bundle.json", "{}");
  ExpectRefused(
      {"calibrate", "lamp", P("sphere"), "--calib", P("calib.yaml"), "--out", P("sphere/bundle.json")},
      kExitFailure, "inside the bundle");
  ExpectRefused({"calibrate", "lamp", P("sphere"), "--calib", P("calib.yaml")}, kExitFailure,
                "not a regular file");
  // A PLY comment containing "end_header" does not end the header.
  cloud::PointCloud few = Sphere(10);
  std::string bytes = cloud::EncodePly(few);
  bytes.insert(bytes.find("comment"), "comment here is no end_header\n");
  Result<cloud::PointCloud> read = cloud::DecodePly(bytes, "c.ply", {});
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(read->size(), 10u);
}

// The commands of acquisition, placements and the device meet the same rules: a clear error naming the
// option or file, exit 1 or 2, nothing left behind, and output paths checked before a board is opened
// (`scan --out nodir/b` used to create nodir/ and start scanning).
TEST_F(HostileTest, ScanMergeAndDeviceRefuseBadInput) {
  const std::string scene = Shared("scene.json").string();
  const std::string cloud = Shared("cloud.ply").string();
  ExpectRefused({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene, "--out", P("nodir/b")},
                kExitFailure, "nodir");
  ExpectRefused({"scan", "--device", "nosuch", "--camera", "virtual", "--scene", scene, "--out", P("b")},
                kExitFailure, "unknown board 'nosuch'");
  ExpectRefused({"scan", "--device", "sim", "--camera", "nosuch:x", "--scene", scene, "--out", P("b")},
                kExitFailure, "unknown camera 'nosuch'");
  ExpectRefused({"scan", "--device", "sim", "--camera", "virtual", "--scene", P("missing.json"), "--out", P("b")},
                kExitFailure, "missing.json");
  ExpectRefused({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene, "--calib", P("missing.yaml"),
                 "--out", P("b"), "--live"},
                kExitFailure, "missing.yaml");
  ExpectRefused({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene, "--out", scene},
                kExitFailure, "--out");
  WriteText(dir_ / "bad.ply", "garbage");
  ExpectRefused({"merge", P("bad.ply"), cloud, "--out", P("m.ply")}, kExitFailure, "bad.ply");
  ExpectRefused({"merge", cloud, "--out", P("m.ply")}, kExitUsage, "at least two clouds");
  ExpectRefused({"merge", cloud, P("bad.ply"), "--out", P("bad.ply")}, kExitFailure, "is also an input");
  ExpectRefused({"merge", cloud, P("missing.ply"), "--out", P("m.ply")}, kExitFailure, "missing.ply");
  ExpectRefused({"merge", cloud, cloud, "--out", P("m.ply"), "--hint", "1,2"}, kExitFailure, "hint");
  ExpectRefused({"device", "flash", P("missing.bin")}, kExitFailure, "missing.bin");
}

}  // namespace
}  // namespace rotoscan::cli
