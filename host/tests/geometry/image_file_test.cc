#include "rotoscan/geometry/image_file.h"

#include <gtest/gtest.h>

#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rotoscan/core/file.h"
#include "testing/testing.h"

namespace rotoscan::geometry {
namespace {

std::string Encode(const cv::Mat& image, const std::string& ext) {
  std::vector<uchar> bytes;
  EXPECT_TRUE(cv::imencode(ext, image, bytes));
  return std::string(bytes.begin(), bytes.end());
}

// Our PNG path gives the same pixels as OpenCV's imread for every kind of PNG our files hold: 8-bit gray,
// color, color with alpha, and 16-bit gray (which goes to OpenCV); gray of a color PNG within one level.
TEST(ImageFileTest, PngDecodesAsOpenCvDoes) {
  rotoscan::testing::ScratchDir dir;
  cv::RNG rng(3);
  cv::Mat gray(37, 53, CV_8UC1), color(37, 53, CV_8UC3), rgba(37, 53, CV_8UC4), deep(37, 53, CV_16UC1);
  rng.fill(gray, cv::RNG::UNIFORM, 0, 256);
  rng.fill(color, cv::RNG::UNIFORM, 0, 256);
  rng.fill(rgba, cv::RNG::UNIFORM, 0, 256);
  rng.fill(deep, cv::RNG::UNIFORM, 0, 65536);
  for (const cv::Mat* image : {&gray, &color, &rgba, &deep}) {
    const std::filesystem::path path = dir / "i.png";
    ASSERT_TRUE(WriteFileAtomically(path, Encode(*image, ".png")).ok());
    const Result<cv::Mat> ours = ReadImageFile(path);
    ASSERT_TRUE(ours.ok()) << ours.status().ToString();
    const cv::Mat theirs = cv::imread(path.string(), cv::IMREAD_UNCHANGED);
    ASSERT_EQ(ours->type(), theirs.type());
    EXPECT_EQ(cv::norm(*ours, theirs, cv::NORM_INF), 0.0);
    const Result<cv::Mat> as_gray = ReadImageFile(path, ImageRead::kGray);
    ASSERT_TRUE(as_gray.ok());
    ASSERT_EQ(as_gray->type(), CV_8UC1);
    if (image->depth() == CV_8U) {
      EXPECT_LE(cv::norm(*as_gray, cv::imread(path.string(), cv::IMREAD_GRAYSCALE), cv::NORM_INF), 1.0);
    }
    const Result<cv::Mat> as_color = ReadImageFile(path, ImageRead::kColor);
    ASSERT_TRUE(as_color.ok());
    EXPECT_EQ(as_color->type(), CV_8UC3);
  }
  // JPEG goes through OpenCV.
  ASSERT_TRUE(WriteFileAtomically(dir / "c.jpg", Encode(color, ".jpg")).ok());
  const Result<cv::Mat> jpeg = ReadImageFile(dir / "c.jpg");
  ASSERT_TRUE(jpeg.ok());
  EXPECT_EQ(cv::norm(*jpeg, cv::imread((dir / "c.jpg").string(), cv::IMREAD_UNCHANGED), cv::NORM_INF), 0.0);
}

TEST(ImageFileTest, BadFilesAreClearErrors) {
  rotoscan::testing::ScratchDir dir;
  EXPECT_EQ(ReadImageFile(dir / "none.png").status().code(), StatusCode::kNotFound);
  cv::Mat gray(20, 30, CV_8UC1, cv::Scalar(7));
  std::string png = Encode(gray, ".png");
  const std::size_t idat = png.find("IDAT");
  ASSERT_NE(idat, std::string::npos);
  ASSERT_TRUE(WriteFileAtomically(dir / "torn.png", png.substr(0, idat + 6)).ok());
  const Result<cv::Mat> torn = ReadImageFile(dir / "torn.png");
  EXPECT_EQ(torn.status().code(), StatusCode::kCorruptData);
  EXPECT_NE(torn.status().message().find("torn.png"), std::string::npos) << torn.status().ToString();
  ASSERT_TRUE(WriteFileAtomically(dir / "empty.png", "").ok());
  EXPECT_EQ(ReadImageFile(dir / "empty.png").status().code(), StatusCode::kCorruptData);
  ASSERT_TRUE(WriteFileAtomically(dir / "text.png", "not an image at all").ok());
  EXPECT_EQ(ReadImageFile(dir / "text.png").status().code(), StatusCode::kCorruptData);
}

}  // namespace
}  // namespace rotoscan::geometry
