// The renderer's real-camera effects (renderer.h, issue 15): speckle against the physics of fully
// developed speckle, glossy glints and highlights, notches over a dark-and-white texture, MJPEG, a
// flickering ambient read out by a rolling shutter, and the scene fields that turn them on.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"
#include "testing/testing.h"

namespace rotoscan::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;

// The normalised autocovariance of fully developed speckle through a circular pupil at lag r (same unit
// as lambda_n = wavelength * f-number): [2 J1(v) / v]^2, v = pi r / lambda_n (Goodman, Speckle
// Phenomena in Optics, eq. 5.2-13 for the image plane).
double AiryAutocovariance(double r, double lambda_n) {
  const double v = kPi * r / lambda_n;
  if (v < 1e-9) return 1.0;
  const double a = 2.0 * std::cyl_bessel_j(1.0, v) / v;
  return a * a;
}

// The measured normalised autocovariance of `intensity` at horizontal and vertical lag `lag` (cells),
// averaged over both directions.
double MeasuredAutocovariance(const cv::Mat& intensity, int lag) {
  cv::Scalar mean, stddev;
  cv::meanStdDev(intensity, mean, stddev);
  double sum = 0;
  int64_t n = 0;
  for (int y = 0; y + lag < intensity.rows; ++y) {
    const float* row = intensity.ptr<float>(y);
    const float* below = intensity.ptr<float>(y + lag);
    for (int x = 0; x + lag < intensity.cols; ++x) {
      sum += (row[x] - mean[0]) * (row[x + lag] - mean[0]) + (row[x] - mean[0]) * (below[x] - mean[0]);
      n += 2;
    }
  }
  return sum / n / (stddev[0] * stddev[0]);
}

// f/4 at 660 nm on the webcam's 2.8 µm pixels: grain radius 1.22 * 0.66 * 4 = 3.22 µm = 1.15 px. Before
// pixel integration the intensity must be exponential (contrast 1, P(I > t <I>) = e^-t) and correlated
// as the pupil's Airy pattern says, its first zero at the grain radius.
TEST(SpeckleTest, FullyDevelopedStatisticsAndGrainSizeFromThePupil) {
  const double pixel_um = 2.8, wavelength_nm = 660.0, f_number = 4.0;
  const int m = SpeckleOversampling(pixel_um, wavelength_nm, f_number);
  EXPECT_EQ(m, 3);  // 2.8 / (0.66 * 4 / 2) = 2.12 -> 3 cells per pixel
  const cv::Mat cells = SpeckleIntensity(200, 200, pixel_um, wavelength_nm, f_number, m, 7);
  ASSERT_EQ(cells.rows, 600);
  ASSERT_EQ(cells.cols, 600);
  cv::Scalar mean, stddev;
  cv::meanStdDev(cells, mean, stddev);
  int above1 = 0, above2 = 0, above4 = 0;
  for (int y = 0; y < cells.rows; ++y) {
    for (int x = 0; x < cells.cols; ++x) {
      const float v = cells.at<float>(y, x);
      above1 += v > 1.0f;
      above2 += v > 2.0f;
      above4 += v > 4.0f;
    }
  }
  const double n = static_cast<double>(cells.total());
  std::printf("speckle f/%.0f: mean %.4f contrast %.4f  P(>1) %.4f (e^-1 %.4f) P(>2) %.4f (%.4f) P(>4) %.4f (%.4f)\n",
              f_number, mean[0], stddev[0] / mean[0], above1 / n, std::exp(-1.0), above2 / n, std::exp(-2.0),
              above4 / n, std::exp(-4.0));
  // ~35,000 independent grains: the statistics are good to ~1-2 %.
  EXPECT_NEAR(mean[0], 1.0, 0.03);
  EXPECT_NEAR(stddev[0] / mean[0], 1.0, 0.05);
  EXPECT_NEAR(above1 / n, std::exp(-1.0), 0.015);
  EXPECT_NEAR(above2 / n, std::exp(-2.0), 0.01);
  EXPECT_NEAR(above4 / n, std::exp(-4.0), 0.004);
  // The autocovariance against the Airy formula, lag by lag, and its first zero against 1.22 lambda N.
  const double cell_um = pixel_um / m, lambda_n_um = wavelength_nm * 1e-3 * f_number;
  double previous = 1.0, zero_um = -1.0;
  for (int lag = 1; lag <= 8; ++lag) {
    const double measured = MeasuredAutocovariance(cells, lag);
    const double expected = AiryAutocovariance(lag * cell_um, lambda_n_um);
    std::printf("  lag %d cells (%.2f um): autocovariance %.4f, Airy %.4f\n", lag, lag * cell_um, measured,
                expected);
    EXPECT_NEAR(measured, expected, 0.04) << "lag " << lag;
    if (zero_um < 0 && measured <= 0.02 && previous > 0.02) {  // where it reaches the floor
      zero_um = (lag - 1 + (previous - 0.02) / (previous - measured)) * cell_um;
    }
    previous = measured;
  }
  std::printf("  grain radius (first zero of the autocovariance): %.2f um, 1.22 lambda N = %.2f um\n", zero_um,
              1.22 * lambda_n_um);
  EXPECT_NEAR(zero_um, 1.22 * lambda_n_um, 0.15 * 1.22 * lambda_n_um);
  // Integrated over the pixel the contrast drops (grains about the pixel's size) but stays strong.
  cv::Mat pixels;
  cv::resize(cells, pixels, cv::Size(200, 200), 0, 0, cv::INTER_AREA);
  cv::meanStdDev(pixels, mean, stddev);
  std::printf("  contrast over 2.8 um pixels: %.3f\n", stddev[0] / mean[0]);
  EXPECT_LT(stddev[0] / mean[0], 0.9);
  EXPECT_GT(stddev[0] / mean[0], 0.4);
  // A coarser pupil (f/8) makes grains twice as large.
  const int m8 = SpeckleOversampling(pixel_um, wavelength_nm, 8.0);
  const cv::Mat coarse = SpeckleIntensity(100, 100, pixel_um, wavelength_nm, 8.0, m8, 3);
  const double lag_um = 2 * pixel_um / m8;
  EXPECT_NEAR(MeasuredAutocovariance(coarse, 2), AiryAutocovariance(lag_um, 2 * lambda_n_um), 0.05);
}

Scene WebcamScene(const std::string& objects, const std::string& extra = "") {
  auto scene = ParseScene(R"({"preset": "webcam", "camera": {"width": 320, "height": 240, "hfov_deg": 25)" + extra +
                              R"(}, "objects": )" + objects + "}",
                          rotoscan::testing::DataPath("."), "webcam scene");
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  return *scene;
}

// The brightest red value of the laser-on frame minus the off frame over the image.
int PeakDifference(const RenderedStep& step) {
  cv::Mat on[3], off[3], d;
  cv::split(step.frames[0], on);
  cv::split(step.frames[2], off);
  cv::subtract(on[2], off[2], d);
  double max_value;
  cv::minMaxLoc(d, nullptr, &max_value);
  return static_cast<int>(max_value);
}

TEST(RealCameraTest, GlossySphereGlintsAndHighlights) {
  const std::string sphere = R"([{"type": "sphere", "radius_mm": 25, "segments": 64, "color": [0.1, 0.1, 0.1)";
  const Scene matte = WebcamScene(sphere + "]}]", R"(, "noise": false)");
  const Scene glossy = WebcamScene(sphere + R"(], "specular": 4.0, "shininess": 80}])", R"(, "noise": false)");
  auto rm = Renderer::Create(matte);
  auto rg = Renderer::Create(glossy);
  ASSERT_TRUE(rm.ok() && rg.ok());
  const RenderedStep a = (*rm)->RenderStep(0.0, 1), b = (*rg)->RenderStep(0.0, 1);
  // The laser: a dark matte sphere keeps the line below saturation; the glint saturates it.
  const int matte_peak = PeakDifference(a), glossy_peak = PeakDifference(b);
  std::printf("laser peak difference: matte %d DN, glossy %d DN\n", matte_peak, glossy_peak);
  EXPECT_LT(matte_peak, 200);
  EXPECT_GT(glossy_peak, matte_peak + 40);
  // The lamp: a white highlight in the natural frame.
  double matte_max, glossy_max;
  cv::Mat gray;
  cv::cvtColor(a.frames[3], gray, cv::COLOR_BGR2GRAY);
  cv::minMaxLoc(gray, nullptr, &matte_max);
  cv::cvtColor(b.frames[3], gray, cv::COLOR_BGR2GRAY);
  cv::minMaxLoc(gray, nullptr, &glossy_max);
  std::printf("natural frame maximum: matte %.0f, glossy %.0f\n", matte_max, glossy_max);
  EXPECT_GT(glossy_max, matte_max + 50);
}

// DESIGN.md's real row `146 145 53 164 44`: a saturated laser-on frame over a white cell of a dark and
// white texture leaves a notch in the difference, inside the line.
TEST(RealCameraTest, SaturationOverBrightTextureNotchesTheDifference) {
  const Scene scene = WebcamScene(
      R"([{"type": "plane", "distance_mm": 280, "size_mm": [120, 100], "color": [0.95, 0.95, 0.95], "checker_mm": 3, "dark_albedo": 0.1}])",
      R"(, "noise": false)");
  Scene bright = scene;
  bright.ambient = 4.5;
  bright.laser[0].power *= 2.5;
  auto renderer = Renderer::Create(bright);
  ASSERT_TRUE(renderer.ok());
  const RenderedStep step = (*renderer)->RenderStep(0.0, 1, {true, false, true, false});
  cv::Mat on[3], off[3];
  cv::split(step.frames[0], on);
  cv::split(step.frames[2], off);
  int notched = 0, lit = 0;
  for (int y = 0; y < on[2].rows; ++y) {
    // The run of saturated laser-on pixels; a notch: a pixel inside it whose difference is less than
    // half that of the run's best.
    int first = -1, last = -1;
    for (int x = 0; x < on[2].cols; ++x) {
      if (on[2].at<uint8_t>(y, x) == 255 && off[2].at<uint8_t>(y, x) < 255) {
        if (first < 0) first = x;
        last = x;
      }
    }
    if (first < 0 || last - first < 3) continue;
    ++lit;
    int best = 0, worst = 255;
    for (int x = first; x <= last; ++x) {
      const int d = 255 - off[2].at<uint8_t>(y, x);
      best = std::max(best, d);
      worst = std::min(worst, d);
    }
    notched += worst < best / 2;
  }
  {
    const int y = on[2].rows / 2;
    int peak = 0;
    for (int x = 0; x < on[2].cols; ++x) peak = on[2].at<uint8_t>(y, x) > on[2].at<uint8_t>(y, peak) ? x : peak;
    std::printf("row %d around the line: on/off", y);
    for (int x = std::max(0, peak - 8); x < std::min(on[2].cols, peak + 9); ++x)
      std::printf(" %d/%d", on[2].at<uint8_t>(y, x), off[2].at<uint8_t>(y, x));
    std::printf("\n");
  }
  std::printf("rows with a saturated line: %d, notched: %d\n", lit, notched);
  EXPECT_GT(lit, 100);
  EXPECT_GT(notched, lit / 10);
}

// MJPEG changes the frame by a few DN (blocks, ringing), the lossless frame stays as it was; a flickering
// ambient read out by a rolling shutter makes the off frame's rows differ from one frame to the next.
TEST(RealCameraTest, MjpegAndRollingShutterFlicker) {
  const std::string plane = R"([{"type": "plane", "distance_mm": 280, "size_mm": [200, 200], "checker_mm": 2}])";
  const Scene lossless = WebcamScene(plane, R"(, "noise": false, "jpeg_quality": 0, "line_time_us": 0)");
  Scene steady = lossless;
  steady.ambient_change = 0;
  steady.ambient_flicker = 0;
  Scene jpeg = steady;
  jpeg.sensor.jpeg_quality = 85;
  auto r0 = Renderer::Create(steady);
  auto r1 = Renderer::Create(jpeg);
  ASSERT_TRUE(r0.ok() && r1.ok());
  const FrameMask off_only = {false, false, true, false};
  const cv::Mat a = (*r0)->RenderStep(0.0, 1, off_only).frames[2];
  const cv::Mat b = (*r1)->RenderStep(0.0, 1, off_only).frames[2];
  const double mean_abs = cv::norm(a, b, cv::NORM_L1) / static_cast<double>(a.total() * 3);
  std::printf("MJPEG at quality 85: mean |change| %.3f DN, max %.0f DN\n", mean_abs, cv::norm(a, b, cv::NORM_INF));
  EXPECT_GT(mean_abs, 0.05);
  EXPECT_LT(mean_abs, 3.0);
  // Flicker: the row means of two off frames differ, and not by one gain for the whole frame.
  Scene flicker = steady;
  flicker.ambient_flicker = 0.2;
  flicker.sensor.line_time_us = 69.0;
  auto r2 = Renderer::Create(flicker);
  ASSERT_TRUE(r2.ok());
  const cv::Mat f1 = (*r2)->RenderStep(0.0, 1, off_only).frames[2];
  const cv::Mat f2 = (*r2)->RenderStep(0.0, 2, off_only).frames[2];
  cv::Mat m1, m2, m0;
  cv::reduce(f1, m1, 1, cv::REDUCE_AVG, CV_64F);
  cv::reduce(f2, m2, 1, cv::REDUCE_AVG, CV_64F);
  cv::reduce(a, m0, 1, cv::REDUCE_AVG, CV_64F);
  double min_ratio = 1e9, max_ratio = 0;
  for (int y = 20; y < f1.rows - 20; ++y) {
    const double ratio = cv::sum(m1.row(y))[0] / std::max(1.0, cv::sum(m0.row(y))[0]);
    min_ratio = std::min(min_ratio, ratio);
    max_ratio = std::max(max_ratio, ratio);
  }
  std::printf("flicker 20 %%: row gain %.3f .. %.3f; frames differ by %.2f DN mean\n", min_ratio, max_ratio,
              cv::norm(f1, f2, cv::NORM_L1) / static_cast<double>(f1.total() * 3));
  EXPECT_GT(max_ratio - min_ratio, 0.1);  // 240 rows x 69 us = 16.6 ms: over a whole 100 Hz period
  EXPECT_GT(cv::norm(f1, f2, cv::NORM_L1) / static_cast<double>(f1.total() * 3), 1.0);
}

// Laser light scattered into a concavity (renderer.h, "Interreflection"): in concave-webcam.json's 90
// degree inside corner each laser's line lies on one board, ~9 mm from the corner, and its diffuse bounce
// lights the other board: a second, weaker line near the corner's edge, apart from the primary one. Noise,
// speckle, MJPEG and flicker off, so that the bounce is the only difference between the two renders.
TEST(RealCameraTest, InterreflectionAddsASecondWeakerLineInAConcavity) {
  auto loaded = LoadScene(rotoscan::testing::DataPath("scenes/concave-webcam.json"));
  ASSERT_TRUE(loaded.ok()) << loaded.status().ToString();
  Scene scene = *loaded;
  ASSERT_TRUE(scene.laser_interreflection);
  scene.sensor.noise = false;
  scene.sensor.jpeg_quality = 0;
  scene.ambient_change = scene.ambient_flicker = 0;
  for (LaserModel& l : scene.laser) l.f_number = l.speckle_contrast = 0;
  Scene flat = scene;
  flat.laser_interreflection = false;
  auto with = Renderer::Create(scene);
  auto without = Renderer::Create(flat);
  ASSERT_TRUE(with.ok() && without.ok());
  const FrameMask left = {true, false, true, false};
  const RenderedStep a = (*with)->RenderStep(0.0, 1, left), b = (*without)->RenderStep(0.0, 1, left);
  cv::Mat on[3], plain[3], off[3];
  cv::split(a.frames[0], on);
  cv::split(b.frames[0], plain);
  cv::split(b.frames[2], off);
  EXPECT_EQ(cv::norm(a.frames[2], b.frames[2], cv::NORM_INF), 0.0);  // the off frame has no laser
  int rows = 0, apart = 0, min_bounce = 255, darker = 0;
  double sum_bounce = 0, sum_ratio = 0;
  for (int y = 0; y < on[2].rows; ++y) {
    // The primary line: the row's brightest red difference without the bounce.
    int line = 0;
    for (int x = 0; x < on[2].cols; ++x) {
      if (plain[2].at<uint8_t>(y, x) - off[2].at<uint8_t>(y, x) > plain[2].at<uint8_t>(y, line) - off[2].at<uint8_t>(y, line)) line = x;
    }
    const int line_peak = plain[2].at<uint8_t>(y, line) - off[2].at<uint8_t>(y, line);
    if (line_peak < 60) continue;  // no line in this row
    // The bounce: what it adds, at its strongest away from the line (> 20 px: past the line's width).
    int bounce = 0, where = -1;
    for (int x = 0; x < on[2].cols; ++x) {
      const int added = on[2].at<uint8_t>(y, x) - plain[2].at<uint8_t>(y, x);
      darker += added < 0;
      if (std::abs(x - line) > 20 && added > bounce) bounce = added, where = x;
    }
    ++rows;
    if (where < 0) continue;
    ++apart;
    min_bounce = std::min(min_bounce, bounce);
    sum_bounce += bounce;
    sum_ratio += static_cast<double>(bounce) / line_peak;
    if (y == on[2].rows / 2) {
      std::printf("row %d: line at %d (difference %d DN), bounce strongest at %d (+%d DN); red difference with "
                  "the bounce every 4 px from the line:", y, line, line_peak, where, bounce);
      for (int x = std::min(line, where) - 8; x <= std::max(line, where) + 8; x += 4)
        std::printf(" %d", on[2].at<uint8_t>(y, x) - off[2].at<uint8_t>(y, x));
      std::printf("\n");
    }
  }
  std::printf("rows with a line: %d, with a bounce > 20 px from it: %d, bounce min %d DN, mean %.1f DN, "
              "mean bounce / line %.3f; pixels made darker: %d\n",
              rows, apart, min_bounce, sum_bounce / std::max(1, apart), sum_ratio / std::max(1, apart), darker);
  EXPECT_GT(rows, 250);
  EXPECT_EQ(apart, rows);  // a second line in every row of the corner...
  EXPECT_GE(min_bounce, 3);
  EXPECT_LT(sum_ratio / apart, 0.5);  // ...weaker than the first
  // Light is only added, except in a few pixels where the raw red is clipped and the bounce's green
  // (response 0.12) lowers the red output through the color matrix's negative term, as in a real camera.
  EXPECT_LT(darker, rows / 4);
}

// DESIGN.md "What real laser frames look like": a bq Ciclop's C270 (1280x960, MJPEG) on a white plaster
// bust. The webcam preset on a matte white object (a plaster-white sphere, albedo 0.9) must give the same
// statistics, each within a stated tolerance of the real figure: in the rows with a line, the red channel
// of the laser-on frame saturated in about three quarters of them, the peak red difference about 160 DN,
// the off frame's red under the line about 80, the line 7 to 16 px wide at half maximum (median 12), the
// green channel dropping by about 50 DN under it, and the difference image's background noise about 1.4 DN.
struct FrameStatistics {
  int rows = 0;
  double saturated = 0, peak = 0, off_red = 0, width = 0, green_drop = 0, noise = 0;
};

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

FrameStatistics WebcamLineStatistics(const Scene& scene, int steps) {
  auto renderer = Renderer::Create(scene);
  EXPECT_TRUE(renderer.ok());
  FrameStatistics out;
  std::vector<double> peaks, off_reds, widths, drops, background;
  int saturated = 0;
  for (int step = 0; step < steps; ++step) {
    const double angle = step * 2 * kPi / steps;
    const RenderedStep frames = (*renderer)->RenderStep(angle, FrameSeed(scene.seed, 0, step, 0), {true, true, true, false});
    cv::Mat off[3];
    cv::split(frames.frames[2], off);
    for (int k = 0; k < 2; ++k) {
      cv::Mat on[3];
      cv::split(frames.frames[k], on);
      for (int y = 0; y < on[2].rows; ++y) {
        const uint8_t* r_on = on[2].ptr<uint8_t>(y);
        const uint8_t* r_off = off[2].ptr<uint8_t>(y);
        int peak = 0, at = 0;
        for (int x = 0; x < on[2].cols; ++x) {
          const int d = r_on[x] - r_off[x];
          if (d > peak) peak = d, at = x;
        }
        if (peak < 40) continue;  // no line in this row
        if (y % 8 == 0) {  // the background: the lit surface more than 40 px from the line
          for (int x = 0; x < on[2].cols; x += 4) {
            if (std::abs(x - at) > 40 && r_off[x] > 20) background.push_back(r_on[x] - r_off[x]);
          }
        }
        ++out.rows;
        peaks.push_back(peak);
        off_reds.push_back(r_off[at]);
        drops.push_back(off[1].at<uint8_t>(y, at) - on[1].at<uint8_t>(y, at));
        int first = at, last = at;
        while (first > 0 && r_on[first - 1] - r_off[first - 1] >= peak / 2) --first;
        while (last + 1 < on[2].cols && r_on[last + 1] - r_off[last + 1] >= peak / 2) ++last;
        widths.push_back(last - first + 1);
        bool any = false;
        for (int x = first; x <= last; ++x) any = any || r_on[x] == 255;
        saturated += any;
      }
    }
  }
  out.saturated = out.rows > 0 ? static_cast<double>(saturated) / out.rows : 0;
  out.peak = Median(peaks);
  out.off_red = Median(off_reds);
  out.width = Median(widths);
  out.green_drop = Median(drops);
  // The difference's noise: the standard deviation of the background, leaving out the few values more
  // than 12 DN from its median (edges of the object that the on and off frames' ambient light shifts).
  const double centre = Median(background);
  double sum = 0, sum2 = 0;
  int n = 0;
  for (double b : background) {
    if (std::abs(b - centre) > 12) continue;
    sum += b, sum2 += b * b, ++n;
  }
  out.noise = n > 1 ? std::sqrt(std::max(0.0, (sum2 - sum * sum / n) / (n - 1))) : 0;
  return out;
}

TEST(RealCameraTest, WebcamPresetMatchesRealFrameStatistics) {
  auto scene = ParseScene(R"({"preset": "webcam", "objects": [{"type": "sphere", "radius_mm": 35, "segments": 96, "color": [0.9, 0.9, 0.9]}]})",
                          rotoscan::testing::DataPath("."), "plaster");
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  const FrameStatistics s = WebcamLineStatistics(*scene, 2);
  std::printf("webcam preset on a white sphere (real C270 in brackets): rows with a line %d, saturated %.1f %% (75), "
              "peak difference %.0f DN (160), off red %.0f DN (80), width at half maximum %.0f px (12), green "
              "drop %.0f DN (50), background noise %.2f DN (1.4)\n",
              s.rows, 100 * s.saturated, s.peak, s.off_red, s.width, s.green_drop, s.noise);
  EXPECT_GT(s.rows, 500);
  EXPECT_NEAR(s.saturated, 0.75, 0.10);
  EXPECT_NEAR(s.peak, 160, 25);
  EXPECT_NEAR(s.off_red, 80, 20);
  EXPECT_GE(s.width, 7);
  EXPECT_LE(s.width, 16);
  EXPECT_NEAR(s.green_drop, 50, 20);
  EXPECT_NEAR(s.noise, 1.4, 0.5);
}

TEST(RealCameraTest, BadFieldsAreRefused) {
  for (const char* bad : {R"({"camera": {"jpeg_quality": 101}})", R"({"camera": {"jpeg_quality": 80, "bit_depth": 12}})",
                          R"({"lasers": {"left": {"f_number": 0.2}}})", R"({"light": {"ambient_flicker": 2}})",
                          R"({"light": {"interreflection": 1}})",
                          R"({"objects": [{"type": "sphere", "specular": -1}]})",
                          R"({"objects": [{"type": "sphere", "checker_mm": "3"}]})"}) {
    auto scene = ParseScene(bad, ".", "bad");
    EXPECT_FALSE(scene.ok()) << bad;
  }
}

}  // namespace
}  // namespace rotoscan::sim
