#include "rotoscan/pipeline/process.h"

#include <cmath>
#include <cstdio>
#include <sstream>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "command.h"
#include "rotoscan/bundle/bundle.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/pipeline/calibrate.h"
#include "testing/testing.h"

namespace rotoscan::pipeline {
namespace {

constexpr double kRadius = 30.0;

// A small rig: 160x120 camera, 20 degree field of view, table axis 300 mm ahead pointing up (-y), lasers
// 173.2 mm left and right with planes containing the axis.
geometry::Rig SmallRig() {
  geometry::Rig rig;
  rig.camera = geometry::CameraModel::FromFieldOfView(160, 120, 20.0);
  rig.axis_point_in_cam = Eigen::Vector3d(0, 0, 300);
  rig.axis_direction_in_cam = Eigen::Vector3d(0, -1, 0);
  for (int l = 0; l < 2; ++l) {
    const Eigen::Vector3d origin(l == 0 ? -173.2 : 173.2, 0, 0);
    const Eigen::Vector3d normal = rig.axis_direction_in_cam.cross(rig.axis_point_in_cam - origin);
    rig.laser_plane[l] = geometry::Plane::FromPointNormal(origin, normal);
  }
  rig.step_angle_rad = geometry::DegToRad(3.0);
  return rig;
}

// In-memory scan of a vertical cylinder (radius kRadius) standing off the table axis at `centre_in_table`:
// for every row the laser column is found by bisection on the ray-plane point's distance to the cylinder
// axis, and a Gaussian line (sigma 1.2 px) is drawn there. The natural frame is a flat color.
class CylinderSource : public StepSource {
 public:
  CylinderSource(const geometry::Rig& rig, int steps, Eigen::Vector3d centre_in_table)
      : rig_(rig), steps_(steps), centre_in_table_(std::move(centre_in_table)) {}
  int StepCount() const override { return steps_; }
  Result<StepFrames> Load(int index) const override {
    if (index == missing_off_step) {
      StepFrames f = Render(index);
      f.off = cv::Mat();
      return f;
    }
    if (index == corrupt_step) return CorruptDataError("frames/s0003_left.png cannot be decoded");
    return Render(index);
  }
  int missing_off_step = -1;
  int corrupt_step = -1;
  cv::Size size_override;

  StepFrames Render(int index) const {
    const geometry::CameraModel& cam = rig_.camera;
    StepFrames f;
    f.step = index;
    f.name = "step " + std::to_string(index);
    f.table_angle_rad = index * rig_.step_angle_rad;
    const cv::Size size = size_override.width > 0 ? size_override : cv::Size(cam.width, cam.height);
    f.off = cv::Mat(size, CV_8UC1, cv::Scalar(20));
    f.natural = cv::Mat(size, CV_8UC3, cv::Scalar(50, 100, 200));  // BGR: RGB (200, 100, 50)
    // The cylinder axis in the camera frame at this angle.
    const Eigen::Isometry3d cam_from_world = rig_.WorldFromCamAtAngle(f.table_angle_rad).inverse();
    const Eigen::Vector3d c = cam_from_world * centre_in_table_;
    const Eigen::Vector3d a = (cam_from_world.linear() * Eigen::Vector3d::UnitZ()).normalized();
    for (int l = 0; l < 2; ++l) {
      cv::Mat on = f.off.clone();
      for (int r = 0; r < std::min(size.height, cam.height); ++r) {
        auto excess = [&](double col) {
          const Eigen::Vector3d ray = cam.PixelToRay(Eigen::Vector2d(col, r));
          const auto t = rig_.laser_plane[l].IntersectRay(Eigen::Vector3d::Zero(), ray);
          const Eigen::Vector3d p = *t * ray - c;
          return (p - p.dot(a) * a).norm() - kRadius;
        };
        // The visible crossing: scan columns for the first sign change from outside to inside, seen from
        // the side the laser comes from.
        double root = -1;
        const int step = l == 0 ? 1 : -1;
        for (int col = l == 0 ? 0 : cam.width - 1;; col += step) {
          const int next = col + step;
          if (next < 0 || next >= cam.width) break;
          if (excess(col) > 0 && excess(next) <= 0) {
            double lo = col, hi = next;
            for (int k = 0; k < 60; ++k) {
              const double mid = 0.5 * (lo + hi);
              (excess(mid) > 0 ? lo : hi) = mid;
            }
            root = 0.5 * (lo + hi);
            break;
          }
        }
        if (root < 0) continue;
        for (int x = std::max(0, static_cast<int>(root) - 8);
             x <= std::min(size.width - 1, static_cast<int>(root) + 8); ++x) {
          double v = 0;
          for (int k = 0; k < 5; ++k) {
            const double d = x - 0.4 + 0.2 * k - root;
            v += 150.0 * std::exp(-0.5 * d * d / (1.2 * 1.2)) / 5;
          }
          on.at<uint8_t>(r, x) = cv::saturate_cast<uint8_t>(20 + v);
        }
      }
      f.laser[static_cast<size_t>(l)] = on;
    }
    return f;
  }

 private:
  geometry::Rig rig_;
  int steps_;
  Eigen::Vector3d centre_in_table_;
};

double DistanceToCylinder(const Eigen::Vector3f& p, const Eigen::Vector3d& centre) {
  return std::hypot(p.x() - centre.x(), p.y() - centre.y()) - kRadius;
}

TEST(PipelineTest, OffAxisCylinderIsReconstructedInTheTableFrame) {
  const geometry::Rig rig = SmallRig();
  const Eigen::Vector3d centre(8, -5, 0);
  // 30 steps of 3 degrees: the lasers, 60 degrees apart around the axis, overlap on ~30 degrees.
  CylinderSource source(rig, 30, centre);
  ProcessOptions options;
  options.merge = false;
  auto result = ProcessSteps(rig, source, options);
  ASSERT_TRUE(result.ok()) << result.status().ToString();
  const ProcessSummary& s = result->summary;
  EXPECT_EQ(s.processed_steps, 30);
  EXPECT_GT(s.points_per_laser[0], 30u * 100);
  EXPECT_GT(s.points_per_laser[1], 30u * 100);
  double sum2 = 0, worst = 0;
  size_t normals_ok = 0, normals = 0;
  for (const cloud::CloudPoint& p : result->cloud.points) {
    const double d = DistanceToCylinder(p.position_in_table, centre);
    sum2 += d * d;
    worst = std::max(worst, std::abs(d));
    EXPECT_EQ(p.color, (std::array<uint8_t, 3>{200, 100, 50}));
    if (p.normal.squaredNorm() > 0) {
      ++normals;
      const Eigen::Vector3f radial =
          Eigen::Vector3f(p.position_in_table.x() - static_cast<float>(centre.x()),
                          p.position_in_table.y() - static_cast<float>(centre.y()), 0)
              .normalized();
      if (p.normal.dot(radial) > 0.95f) ++normals_ok;
    }
  }
  const double rms = std::sqrt(sum2 / result->cloud.size());
  // 1 px at 300 mm is 0.66 mm here; 0.05 px of line noise is ~0.06 mm in depth.
  EXPECT_LT(rms, 0.08) << "worst " << worst;
  EXPECT_GT(normals, result->cloud.size() * 8 / 10);
  EXPECT_GT(normals_ok, normals * 95 / 100);
  // Both lasers see the same cylinder: no systematic offset.
  EXPECT_GT(s.merge.disagreement.pairs, 100u);
  EXPECT_LT(std::abs(s.merge.disagreement.mean_signed_mm), 0.05);
}

TEST(PipelineTest, WrongLaserPlaneShowsAsDisagreementAndMergeRemovesTheDoubleShell) {
  const geometry::Rig truth = SmallRig();
  const CylinderSource source(truth, 30, Eigen::Vector3d(0, 0, 0));
  geometry::Rig bad = truth;
  // The right laser plane shifted 0.3 mm along its normal: the "double shell" of a bad calibration (the
  // points move ~0.6 mm along the camera rays, which meet the plane at ~60 degrees).
  bad.laser_plane[1].offset += 0.3;
  ProcessOptions options;
  auto result = ProcessSteps(bad, source, options);
  ASSERT_TRUE(result.ok()) << result.status().ToString();
  const auto& d = result->summary.merge.disagreement;
  EXPECT_GT(d.pairs, 100u);
  EXPECT_GT(std::abs(d.mean_signed_mm), 0.2);
  EXPECT_LT(result->summary.points_out,
            result->summary.points_per_laser[0] + result->summary.points_per_laser[1]);
  // With the true planes there is no offset.
  auto good = ProcessSteps(truth, source, options);
  ASSERT_TRUE(good.ok());
  EXPECT_LT(std::abs(good->summary.merge.disagreement.mean_signed_mm), 0.05);
}

TEST(PipelineTest, ThreadCountDoesNotChangeTheResult) {
  const geometry::Rig rig = SmallRig();
  const CylinderSource source(rig, 6, Eigen::Vector3d(5, 0, 0));
  ProcessOptions one;
  one.threads = 1;
  ProcessOptions two;
  two.threads = 2;
  auto a = ProcessSteps(rig, source, one);
  auto b = ProcessSteps(rig, source, two);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_EQ(a->cloud.size(), b->cloud.size());
  EXPECT_EQ(cloud::EncodePly(a->cloud), cloud::EncodePly(b->cloud));
}

TEST(PipelineTest, MissingAndCorruptFramesAreCountedSkips) {
  const geometry::Rig rig = SmallRig();
  CylinderSource source(rig, 6, Eigen::Vector3d(0, 0, 0));
  source.missing_off_step = 2;
  source.corrupt_step = 3;
  auto result = ProcessSteps(rig, source, ProcessOptions{});
  ASSERT_TRUE(result.ok()) << result.status().ToString();
  EXPECT_EQ(result->summary.processed_steps, 4);
  EXPECT_EQ(result->summary.skipped_steps, 2);
  ASSERT_EQ(result->summary.warnings.size(), 2u);
  const std::string summary = FormatSummary(result->summary);
  EXPECT_NE(summary.find("no laser-off frame"), std::string::npos) << summary;
  EXPECT_NE(summary.find("cannot be decoded"), std::string::npos) << summary;
}

TEST(PipelineTest, BadInputIsAnError) {
  const geometry::Rig rig = SmallRig();
  CylinderSource wrong_size(rig, 3, Eigen::Vector3d(0, 0, 0));
  wrong_size.size_override = cv::Size(100, 120);
  auto r = ProcessSteps(rig, wrong_size, ProcessOptions{});
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("100x120"), std::string::npos) << r.status().message();
  CylinderSource none(rig, 0, Eigen::Vector3d(0, 0, 0));
  EXPECT_EQ(ProcessSteps(rig, none, ProcessOptions{}).status().code(), StatusCode::kInvalidArgument);
  CylinderSource all_bad(rig, 1, Eigen::Vector3d(0, 0, 0));
  all_bad.corrupt_step = 0;
  EXPECT_EQ(ProcessSteps(rig, all_bad, ProcessOptions{}).status().code(), StatusCode::kInvalidArgument);
  ProcessOptions no_laser;
  no_laser.use_laser[0] = no_laser.use_laser[1] = false;
  EXPECT_EQ(ProcessSteps(rig, all_bad, no_laser).status().code(), StatusCode::kInvalidArgument);
}

// Calibration from bundles (pipeline/calibrate.h) says what is wrong with its input: no bundle, a directory
// that is no bundle, a scan bundle. (Its results are checked against truth by
// calib/rendered_calibration_test, calibrate_command_test and the install test's calibrate_and_scan example.)
TEST(PipelineTest, CalibrateFromBundlesRefusesWhatIsNoCalibrationBundle) {
  rotoscan::testing::ScratchDir dir;
  Result<BundleCalibration> r = CalibrateFromBundles({});
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("no calibration bundle"), std::string::npos) << r.status().message();
  EXPECT_FALSE(CalibrateFromBundles({dir / "missing"}).ok());
  const geometry::Rig rig = SmallRig();
  bundle::BundleHeader header;
  header.kind = bundle::BundleKind::kScan;
  header.camera.model = rig.camera;
  header.camera.channels = 1;
  auto writer = bundle::BundleWriter::Create(dir / "scan", header);
  ASSERT_TRUE(writer.ok()) << writer.status().ToString();
  bundle::FrameRecord record;
  record.laser = bundle::LaserState::kOff;
  ASSERT_TRUE((*writer)->AddFrame(record, cv::Mat(rig.camera.height, rig.camera.width, CV_8UC1, 10)).ok());
  ASSERT_TRUE((*writer)->Finish().ok());
  r = CalibrateFromBundles({dir / "scan"});
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("is a scan bundle"), std::string::npos) << r.status().message();
}

TEST(PipelineTest, SampleRgbIsBilinear) {
  cv::Mat image(2, 2, CV_8UC3, cv::Scalar(0, 0, 0));
  image.at<cv::Vec3b>(0, 1) = cv::Vec3b(0, 0, 200);  // red at (column 1, row 0)
  EXPECT_EQ(SampleRgb(image, 0.5, 0.0)[0], 100);
  EXPECT_EQ(SampleRgb(image, 0.5, 0.5)[0], 50);
  EXPECT_EQ(SampleRgb(image, 5.0, -3.0)[0], 200);  // clamped
  cv::Mat gray16(2, 2, CV_16UC1, cv::Scalar(4095));
  EXPECT_EQ(To8Bit(gray16, 12).at<uint8_t>(0, 0), 255);
}

// A bundle on disk, through the command line.
TEST(PipelineTest, ProcessCommandWritesCloudFromBundle) {
  rotoscan::testing::ScratchDir dir;
  const geometry::Rig rig = SmallRig();
  const CylinderSource source(rig, 4, Eigen::Vector3d(0, 0, 0));
  bundle::BundleHeader header;
  header.kind = bundle::BundleKind::kScan;
  header.camera.model = rig.camera;
  header.camera.channels = 1;
  header.table_step_rad = rig.step_angle_rad;
  auto writer = bundle::BundleWriter::Create(dir / "scan", header);
  ASSERT_TRUE(writer.ok()) << writer.status().ToString();
  for (int i = 0; i < 4; ++i) {
    const StepFrames f = source.Render(i);
    auto add = [&](bundle::LaserState state, const cv::Mat& image) {
      bundle::FrameRecord record;
      record.step = i;
      record.table_angle_rad = f.table_angle_rad;
      record.laser = state;
      cv::Mat stored = image;
      if (image.channels() == 3) cv::cvtColor(image, stored, cv::COLOR_BGR2GRAY);
      ASSERT_TRUE((*writer)->AddFrame(record, stored).ok());
    };
    add(bundle::LaserState::kLeft, f.laser[0]);
    add(bundle::LaserState::kRight, f.laser[1]);
    add(bundle::LaserState::kOff, f.off);
    if (i != 2) add(bundle::LaserState::kNatural, f.natural);
  }
  ASSERT_TRUE((*writer)->Finish().ok());
  ASSERT_TRUE(geometry::WriteRigYaml(dir / "calib.yaml", rig).ok());

  auto run = [&](std::vector<std::string> args, std::string* out_text, std::string* err_text) {
    std::vector<const char*> argv{"rotoscan", "--no-progress"};
    for (const std::string& a : args) argv.push_back(a.c_str());
    std::ostringstream out, err;
    const int code = cli::Main(static_cast<int>(argv.size()), argv.data(), out, err);
    *out_text = out.str();
    *err_text = err.str();
    return code;
  };
  std::string out, err;
  const std::string ply = (dir / "cloud.ply").string();
  ASSERT_EQ(run({"process", (dir / "scan").string(), "--calib", (dir / "calib.yaml").string(), "--out", ply},
                &out, &err),
            0)
      << err;
  EXPECT_NE(out.find("steps 4 of 4"), std::string::npos) << out;
  auto cloud = cloud::ReadPly(ply);
  ASSERT_TRUE(cloud.ok()) << cloud.status().ToString();
  EXPECT_GT(cloud->size(), 400u);
  for (const cloud::CloudPoint& p : cloud->points) {
    EXPECT_LT(std::abs(DistanceToCylinder(p.position_in_table, Eigen::Vector3d::Zero())), 0.5);
  }
  // No calibration and no truth/: an error, and no output file.
  const std::string ply2 = (dir / "cloud2.ply").string();
  EXPECT_EQ(run({"process", (dir / "scan").string(), "--out", ply2}, &out, &err), 1);
  EXPECT_NE(err.find("--calib"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(ply2));
  // A missing bundle: exit 1, no file.
  EXPECT_EQ(run({"process", (dir / "nope").string(), "--calib", (dir / "calib.yaml").string(), "--out", ply2},
                &out, &err),
            1);
  EXPECT_FALSE(std::filesystem::exists(ply2));
  // A calibration of another image size.
  geometry::Rig other = rig;
  other.camera = geometry::CameraModel::FromFieldOfView(320, 240, 20.0);
  ASSERT_TRUE(geometry::WriteRigYaml(dir / "other.yaml", other).ok());
  EXPECT_EQ(run({"process", (dir / "scan").string(), "--calib", (dir / "other.yaml").string(), "--out", ply2},
                &out, &err),
            1);
  EXPECT_NE(err.find("differs"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(ply2));
  // The rig from truth/ when --calib is not given, said on stderr.
  std::filesystem::create_directories(dir / "scan" / "truth");
  ASSERT_TRUE(geometry::WriteRigYaml(dir / "scan" / "truth" / "rig.yaml", rig).ok());
  ASSERT_EQ(run({"process", (dir / "scan").string(), "--out", ply2}, &out, &err), 0) << err;
  EXPECT_NE(err.find("truth/rig.yaml"), std::string::npos) << err;
  EXPECT_TRUE(std::filesystem::exists(ply2));
}

TEST(ExtractCommandTest, WritesCsvAndRejectsBadInput) {
  rotoscan::testing::ScratchDir dir;
  cv::Mat off(30, 50, CV_8UC3, cv::Scalar(10, 10, 40));
  cv::Mat on = off.clone();
  for (int r = 0; r < 30; ++r) {
    for (int x = 20; x <= 30; ++x)
      on.at<cv::Vec3b>(r, x)[2] =
          static_cast<uint8_t>(40 + 150 * std::exp(-0.5 * (x - 25.5) * (x - 25.5) / 2.0));
  }
  ASSERT_TRUE(cv::imwrite((dir / "on.png").string(), on));
  ASSERT_TRUE(cv::imwrite((dir / "off.png").string(), off));
  ASSERT_TRUE(cv::imwrite((dir / "small.png").string(), cv::Mat(10, 10, CV_8UC3, cv::Scalar::all(0))));
  auto run = [&](std::vector<std::string> args, std::string* err_text) {
    std::vector<const char*> argv{"rotoscan"};
    for (const std::string& a : args) argv.push_back(a.c_str());
    std::ostringstream out, err;
    const int code = cli::Main(static_cast<int>(argv.size()), argv.data(), out, err);
    *err_text = err.str();
    return code;
  };
  std::string err;
  const std::string csv = (dir / "line.csv").string();
  ASSERT_EQ(
      run({"extract", "--on", (dir / "on.png").string(), "--off", (dir / "off.png").string(), "--out", csv},
          &err),
      0)
      << err;
  auto text = ReadFile(csv);
  ASSERT_TRUE(text.ok());
  std::istringstream lines(*text);
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line, "row,column,peak,width,quality");
  int count = 0;
  while (std::getline(lines, line)) {
    int row;
    double column, peak, width, quality;
    ASSERT_EQ(std::sscanf(line.c_str(), "%d,%lf,%lf,%lf,%lf", &row, &column, &peak, &width, &quality), 5)
        << line;
    EXPECT_EQ(row, count);
    EXPECT_NEAR(column, 25.5, 0.05);
    EXPECT_GT(quality, 0.5);
    ++count;
  }
  EXPECT_EQ(count, 30);
  const std::string bad = (dir / "bad.csv").string();
  EXPECT_EQ(
      run({"extract", "--on", (dir / "on.png").string(), "--off", (dir / "small.png").string(), "--out", bad},
          &err),
      1);
  EXPECT_NE(err.find("sizes differ"), std::string::npos) << err;
  EXPECT_EQ(run({"extract", "--on", (dir / "missing.png").string(), "--off", (dir / "off.png").string(),
                 "--out", bad},
                &err),
            1);
  EXPECT_NE(err.find("missing.png"), std::string::npos) << err;
  ASSERT_TRUE(WriteFileAtomically(dir / "garbage.png", "not a png").ok());
  EXPECT_EQ(run({"extract", "--on", (dir / "garbage.png").string(), "--off", (dir / "off.png").string(),
                 "--out", bad},
                &err),
            1);
  EXPECT_EQ(run({"extract", "--on", (dir / "on.png").string(), "--off", (dir / "off.png").string(),
                 "--channel", "uv", "--out", bad},
                &err),
            1);
  EXPECT_FALSE(std::filesystem::exists(bad));
  EXPECT_EQ(run({"extract", "--on", (dir / "on.png").string()}, &err), 2);
}

}  // namespace
}  // namespace rotoscan::pipeline
