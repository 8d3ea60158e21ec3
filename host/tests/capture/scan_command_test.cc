// `rotoscan scan` and `rotoscan devices` as the user runs them, with no hardware: the sim board and the
// virtual camera, --live processing into a cloud, and bad input answered with a message and an exit code.
#include <filesystem>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>
#include <unistd.h>

#include "command.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::cli {
namespace {

namespace fs = std::filesystem;

int RunCli(std::vector<std::string> args, std::string* out_text = nullptr, std::string* err_text = nullptr) {
  args.insert(args.begin(), "rotoscan");
  args.push_back("--no-progress");
  std::vector<const char*> argv;
  for (const auto& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int code = Main(static_cast<int>(argv.size()), argv.data(), out, err);
  if (out_text != nullptr) *out_text = out.str();
  if (err_text != nullptr) *err_text = err.str();
  return code;
}

class ScanCommandTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("rotoscan_scan_cmd_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    scene_ = (dir_ / "scene.json").string();
    std::ofstream(scene_) << R"({"camera": {"width": 256, "height": 192, "hfov_deg": 20},
      "objects": [{"type": "sphere", "radius_mm": 30, "color": [0.8, 0.8, 0.8]}]})";
    calib_ = (dir_ / "calib.yaml").string();
    ASSERT_TRUE(geometry::WriteRigYaml(calib_, sim::LoadScene(scene_).value().rig).ok());
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
  std::string scene_, calib_;
};

TEST_F(ScanCommandTest, SimBoardVirtualCameraLiveCloud) {
  std::string out, err;
  const std::string bundle = (dir_ / "scan").string();
  const std::string cloud = (dir_ / "cloud.ply").string();
  ASSERT_EQ(RunCli({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene_, "--calib", calib_, "--out",
                 bundle, "--steps", "8", "--live", "--cloud", cloud},
                &out, &err),
            0)
      << err;
  EXPECT_NE(out.find("frames captured 32, used 32"), std::string::npos) << out;
  auto points = cloud::ReadPly(cloud);
  ASSERT_TRUE(points.ok()) << points.status().ToString();
  EXPECT_GT(points.value().points.size(), 300u);
  EXPECT_TRUE(fs::exists(fs::path(bundle) / "bundle.json"));
}

// `scan --placement N` records the placement; the virtual camera films the scene's placement N, and a
// placement the scene does not define is refused before anything is written.
TEST_F(ScanCommandTest, PlacementIsRecordedAndRendered) {
  const std::string scene = (dir_ / "placed.json").string();
  std::ofstream(scene) << R"({"camera": {"width": 256, "height": 192, "hfov_deg": 20},
      "objects": [{"type": "box", "size_mm": [40, 20, 10]}],
      "placements": [{}, {"rotation_deg": [90, 0, 0]}]})";
  std::string out, err;
  const std::string bundle = (dir_ / "side").string();
  ASSERT_EQ(RunCli({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene, "--out", bundle, "--steps",
                    "4", "--placement", "1"},
                   &out, &err),
            0)
      << err;
  std::ifstream json(fs::path(bundle) / "bundle.json");
  const std::string text((std::istreambuf_iterator<char>(json)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("\"placement\": 1"), std::string::npos);
  EXPECT_EQ(RunCli({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene, "--out",
                    (dir_ / "nope").string(), "--steps", "4", "--placement", "2"},
                   nullptr, &err),
            1);
  EXPECT_NE(err.find("placement 2 is not defined"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir_ / "nope"));
}

TEST_F(ScanCommandTest, BadInputIsAClearError) {
  std::string err;
  const std::string bundle = (dir_ / "b").string();
  EXPECT_EQ(RunCli({"scan", "--device", "nosuch", "--out", bundle}, nullptr, &err), 1);
  EXPECT_NE(err.find("unknown board 'nosuch'"), std::string::npos) << err;
  EXPECT_EQ(RunCli({"scan", "--live", "--out", bundle}, nullptr, &err), 1);
  EXPECT_NE(err.find("--live needs --calib"), std::string::npos) << err;
  EXPECT_EQ(RunCli({"scan", "--timing", "sometimes", "--out", bundle}, nullptr, &err), 1);
  EXPECT_EQ(RunCli({"scan", "--device", "sim", "--camera", "virtual", "--scene", scene_, "--steps", "7",
                 "--timing", "triggered", "--out", bundle},
                nullptr, &err),
            1);
  EXPECT_NE(err.find("not a whole number of motor steps"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(bundle));
  std::string out;
  EXPECT_EQ(RunCli({"devices"}, &out, &err), 0);
  EXPECT_NE(out.find("sim"), std::string::npos) << out;
}

}  // namespace
}  // namespace rotoscan::cli
