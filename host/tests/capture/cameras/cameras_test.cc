// The v4l2 backend's pure parts: MJPEG decoding (against OpenCV's encoder), YUYV conversion, what a
// buffer's timestamp flags mean, sequence numbers across a wrap.
#include <linux/videodev2.h>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "capture/v4l2_camera.h"

namespace rotoscan::capture {
namespace {

cv::Mat Scene(int width, int height) {
  cv::Mat m(height, width, CV_8UC3);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      m.at<cv::Vec3b>(y, x) = cv::Vec3b(static_cast<uint8_t>(3 * x), static_cast<uint8_t>(2 * y),
                                        static_cast<uint8_t>(100 + x - y));
    }
  }
  cv::rectangle(m, cv::Rect(20, 10, 6, 30), cv::Scalar(255, 255, 255), cv::FILLED);
  return m;
}

std::vector<uint8_t> Jpeg(const cv::Mat& image) {
  std::vector<uint8_t> bytes;
  cv::imencode(".jpg", image, bytes, {cv::IMWRITE_JPEG_QUALITY, 95});
  return bytes;
}

// Removes the Huffman tables (DHT segments), as UVC MJPEG frames come.
std::vector<uint8_t> WithoutHuffmanTables(const std::vector<uint8_t>& jpeg) {
  std::vector<uint8_t> out(jpeg.begin(), jpeg.begin() + 2);
  size_t i = 2;
  while (i + 4 <= jpeg.size() && jpeg[i] == 0xff) {
    const uint8_t marker = jpeg[i + 1];
    const size_t length = (static_cast<size_t>(jpeg[i + 2]) << 8) | jpeg[i + 3];
    if (marker == 0xda) break;  // start of scan: the rest is entropy-coded data
    if (marker != 0xc4) out.insert(out.end(), jpeg.begin() + static_cast<long>(i), jpeg.begin() + static_cast<long>(i + 2 + length));
    i += 2 + length;
  }
  out.insert(out.end(), jpeg.begin() + static_cast<long>(i), jpeg.end());
  return out;
}

TEST(Mjpeg, DecodesWhatOpenCvEncoded) {
  const cv::Mat scene = Scene(64, 48);
  const auto bytes = Jpeg(scene);
  auto bgr = DecodeMjpeg(bytes.data(), bytes.size(), 64, 48, PixelFormat::kBgr8);
  ASSERT_TRUE(bgr.ok()) << bgr.status().ToString();
  ASSERT_EQ(bgr->type(), CV_8UC3);
  // The same bytes through OpenCV's decoder: the same pixels within a level (IDCT rounding).
  const cv::Mat reference = cv::imdecode(bytes, cv::IMREAD_COLOR);
  EXPECT_LE(cv::norm(*bgr, reference, cv::NORM_INF), 1.0);
  cv::Mat diff;
  cv::absdiff(*bgr, scene, diff);
  EXPECT_LT(cv::mean(diff)[0], 3.0);
  auto gray = DecodeMjpeg(bytes.data(), bytes.size(), 64, 48, PixelFormat::kGray8);
  ASSERT_TRUE(gray.ok());
  EXPECT_EQ(gray->type(), CV_8UC1);
  EXPECT_LE(cv::norm(*gray, cv::imdecode(bytes, cv::IMREAD_GRAYSCALE), cv::NORM_INF), 1.0);
}

TEST(Mjpeg, DecodesFramesWithoutHuffmanTablesLikeUvcCameras) {
  const auto bytes = Jpeg(Scene(64, 48));
  const auto stripped = WithoutHuffmanTables(bytes);
  ASSERT_LT(stripped.size(), bytes.size());
  auto with = DecodeMjpeg(bytes.data(), bytes.size(), 64, 48, PixelFormat::kBgr8);
  auto without = DecodeMjpeg(stripped.data(), stripped.size(), 64, 48, PixelFormat::kBgr8);
  ASSERT_TRUE(with.ok());
  ASSERT_TRUE(without.ok()) << without.status().ToString();
  EXPECT_EQ(cv::norm(*with, *without, cv::NORM_INF), 0.0);  // OpenCV writes the standard tables
}

TEST(Mjpeg, CorruptOrTruncatedFramesAreErrorsNotImages) {
  const auto bytes = Jpeg(Scene(64, 48));
  // Cut inside the entropy-coded data: libjpeg only warns ("premature end of data segment") and would
  // return a grey-filled image; here it is an error.
  for (const double keep : {0.9, 0.6, 0.3, 0.05}) {
    const size_t n = static_cast<size_t>(static_cast<double>(bytes.size()) * keep);
    auto r = DecodeMjpeg(bytes.data(), n, 64, 48, PixelFormat::kBgr8);
    ASSERT_FALSE(r.ok()) << "kept " << keep;
    EXPECT_EQ(r.status().code(), StatusCode::kCorruptData);
  }
  std::vector<uint8_t> flipped = bytes;
  for (size_t i = bytes.size() / 2; i < bytes.size() / 2 + 40; ++i) flipped[i] = 0xff;
  EXPECT_FALSE(DecodeMjpeg(flipped.data(), flipped.size(), 64, 48, PixelFormat::kBgr8).ok());
  const std::vector<uint8_t> garbage(500, 0x5a);
  EXPECT_EQ(DecodeMjpeg(garbage.data(), garbage.size(), 64, 48, PixelFormat::kBgr8).status().code(),
            StatusCode::kCorruptData);
  EXPECT_FALSE(DecodeMjpeg(nullptr, 0, 64, 48, PixelFormat::kBgr8).ok());
  // The right JPEG at the wrong size.
  auto wrong = DecodeMjpeg(bytes.data(), bytes.size(), 32, 24, PixelFormat::kBgr8);
  ASSERT_FALSE(wrong.ok());
  EXPECT_THAT(wrong.status().message(), ::testing::HasSubstr("64x48"));
}

TEST(Yuyv, GrayIsTheLumaAndShortFramesAreErrors) {
  std::vector<uint8_t> yuyv(8 * 2 * 2);
  for (size_t i = 0; i < yuyv.size(); ++i) yuyv[i] = static_cast<uint8_t>(i * 7);
  auto gray = ConvertYuyv(yuyv.data(), yuyv.size(), 8, 2, 16, PixelFormat::kGray8);
  ASSERT_TRUE(gray.ok());
  for (int y = 0; y < 2; ++y) {
    for (int x = 0; x < 8; ++x) EXPECT_EQ(gray->at<uint8_t>(y, x), yuyv[static_cast<size_t>(y * 16 + 2 * x)]);
  }
  // Neutral chroma: BGR is the luma expanded from studio range (BT.601): Y 16 -> 0, 235 -> 255.
  std::vector<uint8_t> neutral = {16, 128, 235, 128};
  auto bgr = ConvertYuyv(neutral.data(), neutral.size(), 2, 1, 4, PixelFormat::kBgr8);
  ASSERT_TRUE(bgr.ok());
  EXPECT_LE(std::abs(bgr->at<cv::Vec3b>(0, 0)[1] - 0), 1);
  EXPECT_LE(std::abs(bgr->at<cv::Vec3b>(0, 1)[1] - 255), 1);
  EXPECT_EQ(ConvertYuyv(yuyv.data(), yuyv.size() - 1, 8, 2, 16, PixelFormat::kGray8).status().code(),
            StatusCode::kCorruptData);
}

TEST(V4l2Timestamps, FlagsSayWhichClockAndWhichInstant) {
  const auto uvc = DecodeTimestampFlags(V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_TSTAMP_SRC_SOE);
  EXPECT_TRUE(uvc.monotonic);
  EXPECT_TRUE(uvc.start_of_exposure);
  const auto eof = DecodeTimestampFlags(V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_TSTAMP_SRC_EOF);
  EXPECT_TRUE(eof.monotonic);
  EXPECT_FALSE(eof.start_of_exposure);
  EXPECT_FALSE(DecodeTimestampFlags(V4L2_BUF_FLAG_TIMESTAMP_COPY).monotonic);
  // Start of exposure: the stamp is the first row's start. End of frame: back by readout and exposure.
  EXPECT_EQ(ExposureStartFromStamp(1'000'000, uvc, 10'000, 30'000), 1'000'000);
  EXPECT_EQ(ExposureStartFromStamp(1'000'000, eof, 10'000, 30'000), 960'000);
}

TEST(V4l2Sequence, ExtendsAcrossTheWrapAndKeepsGaps) {
  SequenceExtender s;
  EXPECT_EQ(s.Extend(0xfffffffeu), 0xfffffffeull);
  EXPECT_EQ(s.Extend(0xffffffffu), 0xffffffffull);
  EXPECT_EQ(s.Extend(1), 0x100000001ull);  // 0 was dropped: a gap of one
  EXPECT_EQ(s.Extend(2), 0x100000002ull);
}

}  // namespace
}  // namespace rotoscan::capture
