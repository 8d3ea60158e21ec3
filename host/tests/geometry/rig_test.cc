#include "rotoscan/geometry/rig.h"

#include <gtest/gtest.h>

#include <fstream>

#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/geometry/yaml.h"
#include "testing/testing.h"

namespace rotoscan::geometry {
namespace {

using rotoscan::testing::EigenNear;
using rotoscan::testing::ScratchDir;

Rig ExampleRig() {
  Rig rig;
  rig.camera = CameraModel::FromFieldOfView(1288, 964, 20.0);
  rig.camera.distortion = {-0.05, 0.01, 0.0002, -0.0001, 0.0};
  // Lasers 100 mm left and right of the camera, aimed at the axis 300 mm ahead.
  const Eigen::Vector3d axis_point(0, 40, 300);
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector3d origin(i == 0 ? -100 : 100, 0, 0);
    const Eigen::Vector3d in_plane_1 = (axis_point - origin).normalized();
    rig.laser_plane[i] = Plane::FromPointNormal(origin, in_plane_1.cross(Eigen::Vector3d::UnitY()));
  }
  rig.axis_point_in_cam = axis_point;
  rig.axis_direction_in_cam = Eigen::Vector3d(0.01, -1, 0.02).normalized();
  rig.step_angle_rad = DegToRad(0.3);
  return rig;
}

TEST(RigTest, YamlRoundTrip) {
  ScratchDir dir;
  const Rig rig = ExampleRig();
  ASSERT_TRUE(WriteRigYaml(dir / "calib.yaml", rig).ok());
  const Result<Rig> back = ReadRigYaml(dir / "calib.yaml");
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->camera.width, 1288);
  EXPECT_EQ(back->camera.height, 964);
  EXPECT_NEAR(back->camera.fx, rig.camera.fx, 1e-9);
  EXPECT_NEAR(back->camera.cy, rig.camera.cy, 1e-9);
  EXPECT_NEAR(back->camera.distortion[2], 0.0002, 1e-15);
  EXPECT_THAT(back->laser_plane[1].normal, EigenNear(rig.laser_plane[1].normal, 1e-12));
  EXPECT_NEAR(back->laser_plane[0].offset, rig.laser_plane[0].offset, 1e-9);
  EXPECT_THAT(back->axis_direction_in_cam, EigenNear(rig.axis_direction_in_cam, 1e-12));
  EXPECT_NEAR(back->step_angle_rad, rig.step_angle_rad, 1e-15);
  // Readable by any OpenCV user under the documented keys.
  cv::FileStorage fs((dir / "calib.yaml").string(), cv::FileStorage::READ);
  cv::Mat k;
  fs["K"] >> k;
  EXPECT_NEAR(k.at<double>(0, 0), rig.camera.fx, 1e-9);
}

TEST(RigTest, ReadErrorsNameTheProblem) {
  ScratchDir dir;
  EXPECT_EQ(ReadRigYaml(dir / "none.yaml").status().code(), StatusCode::kNotFound);
  ASSERT_TRUE(WriteFileAtomically(dir / "junk.yaml", "this is: [not, closed").ok());
  EXPECT_FALSE(ReadRigYaml(dir / "junk.yaml").ok());
  ASSERT_TRUE(
      WriteFileAtomically(dir / "partial.yaml", "%YAML:1.0\n---\nimage_width: 10\nimage_height: 10\n").ok());
  const Status s = ReadRigYaml(dir / "partial.yaml").status();
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("'K'"), std::string::npos) << s.ToString();
}

// Found by the calib.yaml fuzzer: a matrix declaring billions of rows made OpenCV allocate them before it
// read the data (16 GB). The declared size is now bounded first, and the error names the key.
TEST(RigTest, MatrixDeclaringHugeRowsIsRefusedBeforeAllocating) {
  ScratchDir dir;
  ASSERT_TRUE(WriteRigYaml(dir / "calib.yaml", ExampleRig()).ok());
  const Result<std::string> text = ReadFile(dir / "calib.yaml");
  ASSERT_TRUE(text.ok());
  const std::size_t key = text->find("distortion:");
  ASSERT_NE(key, std::string::npos);
  const std::size_t rows = text->find("rows: ", key);
  ASSERT_NE(rows, std::string::npos);
  for (const std::string declared : {"2000000000", "&", "-3"}) {
    std::string bad = *text;
    bad.replace(rows + 6, bad.find('\n', rows) - (rows + 6), declared);
    ASSERT_TRUE(WriteFileAtomically(dir / "bad.yaml", bad).ok());
    const Status s = ReadRigYaml(dir / "bad.yaml").status();
    EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << declared << ": " << s.ToString();
    EXPECT_NE(s.message().find("distortion"), std::string::npos) << s.ToString();
  }
}

// Found by the CI fuzz smoke run (calib.yaml target, 2026-11-24): these 31 bytes made OpenCV 4.6's YAML
// parser loop forever ("- \xEC" sequence items: not UTF-8). Refused before the parser, at once; a written
// calib.yaml (ASCII) still reads.
TEST(RigTest, MalformedUtf8ThatHangsOpenCvsParserIsCorruptData) {
  const std::string hang("%YAML:1.0\n---AML:1.\n-\xec\n\n-\xec\n 21\n", 31);
  const Result<Rig> rig = ParseRigYaml(hang, "hang.yaml");
  EXPECT_EQ(rig.status().code(), StatusCode::kCorruptData) << rig.status().ToString();
  EXPECT_NE(rig.status().message().find("hang.yaml"), std::string::npos);
  EXPECT_EQ(ParseRigYaml(std::string("%YAML:1.0\n\x01\n", 13), "c.yaml").status().code(), StatusCode::kCorruptData);
  ScratchDir dir;
  ASSERT_TRUE(WriteRigYaml(dir / "calib.yaml", ExampleRig()).ok());
  EXPECT_TRUE(ReadRigYaml(dir / "calib.yaml").ok());
}

// The same 31 bytes through every YAML reader, which all go through geometry/yaml.h: the shared reader
// itself, calib.yaml from text and from a file (truth/rig.yaml is read the same way); camera.yaml:
// calib/camera_calibration_test.cc.
TEST(RigTest, EveryYamlReaderRefusesTheBytesThatHangOpenCv) {
  const std::string hang("%YAML:1.0\n---AML:1.\n-\xec\n\n-\xec\n 21\n", 31);
  bool called = false;
  const Status shared = ReadYamlText(hang, "hang.yaml", [&](const cv::FileNode&) {
    called = true;
    return Status::Ok();
  });
  EXPECT_EQ(shared.code(), StatusCode::kCorruptData) << shared.ToString();
  EXPECT_FALSE(called);  // the parser never saw it
  EXPECT_EQ(InvalidYamlByteAt(hang), 21u);
  EXPECT_EQ(InvalidYamlByteAt("a: 1\nb: \xc3\xa9\n"), std::string::npos);  // UTF-8 is fine
  ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomically(dir / "calib.yaml", hang).ok());
  const Result<Rig> rig = ReadRigYaml(dir / "calib.yaml");
  EXPECT_EQ(rig.status().code(), StatusCode::kCorruptData) << rig.status().ToString();
  EXPECT_NE(rig.status().message().find("calib.yaml"), std::string::npos);
  // An exception inside a reader's own code is an error too, not an escape.
  const Status thrown = ReadYamlText("%YAML:1.0\na: 1\n", "t.yaml", [](const cv::FileNode& root) -> Status {
    (void)root["a"].mat();  // not a matrix: cv::Exception
    return Status::Ok();
  });
  EXPECT_EQ(thrown.code(), StatusCode::kCorruptData) << thrown.ToString();
}

// Found by the calib.yaml fuzzer: a key mangled to ":dt:" makes OpenCV's YAML parser throw std::length_error
// (not a cv::Exception), which escaped the reader.
TEST(RigTest, MangledKeyIsCorruptDataNotAnException) {
  ScratchDir dir;
  ASSERT_TRUE(WriteRigYaml(dir / "calib.yaml", ExampleRig()).ok());
  Result<std::string> text = ReadFile(dir / "calib.yaml");
  ASSERT_TRUE(text.ok());
  const std::size_t dt = text->find("   dt: d");
  ASSERT_NE(dt, std::string::npos);
  text->replace(dt, 8, "   :dt: d");
  const Result<Rig> rig = ParseRigYaml(*text, "mangled.yaml");
  EXPECT_EQ(rig.status().code(), StatusCode::kCorruptData) << rig.status().ToString();
}

TEST(RigTest, InvalidRigIsNotWritten) {
  ScratchDir dir;
  Rig rig = ExampleRig();
  rig.laser_plane[0].normal = Eigen::Vector3d(0, 0, 2);
  const Status s = WriteRigYaml(dir / "calib.yaml", rig);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("laser_left_plane"), std::string::npos) << s.ToString();
  EXPECT_FALSE(std::filesystem::exists(dir / "calib.yaml"));
}

TEST(RigTest, WorldFromCamUndoesTheTableTurn) {
  const Rig rig = ExampleRig();
  const Eigen::Isometry3d cam_from_table = rig.CamFromTable();
  const Eigen::Vector3d point_in_world(20, -10, 35);  // table frame at angle 0, mm
  for (double angle : {0.0, 0.3, 1.7, -2.5}) {
    // The table turned by `angle` about its axis: the camera sees the point rotated about the axis.
    const Eigen::Vector3d point_in_cam =
        RotationAboutAxis(rig.axis_point_in_cam, rig.axis_direction_in_cam, angle) *
        (cam_from_table * point_in_world);
    EXPECT_THAT(rig.WorldFromCamAtAngle(angle) * point_in_cam, EigenNear(point_in_world, 1e-9)) << angle;
  }
  // The table frame's origin is on the axis and its z is the axis direction.
  EXPECT_THAT(cam_from_table * Eigen::Vector3d::Zero(), EigenNear(rig.axis_point_in_cam, 1e-12));
  EXPECT_THAT(Eigen::Vector3d(cam_from_table.linear().col(2)), EigenNear(rig.axis_direction_in_cam, 1e-12));
}

}  // namespace
}  // namespace rotoscan::geometry
